"""Two ``make demo`` runs compared episode by episode: ``python -m benchmarks.demo_compare
RUN_A RUN_B`` (each a ``--out`` directory with its ``summary.json``).

The lockstep demo's claim (issue #39) is that its table does not depend on the host: the
same episode run on an idle machine and beside CPU hogs gives the same trial. This matches
the episodes the two runs share (task, method, object, trial, pivot arm) and counts those
whose outcome is identical: success, stopping error, tracking RMSE, angle turned, the
number of estimates, the stop reason. It prints the count, every episode that differs, and
both runs' conditions; exit 0 when every shared episode is identical, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

#: The outcome of an episode: what the table is made of.
OUTCOME = ("success", "stopping_error_m", "pose_rmse_m", "angle_deg", "n_slip_msgs",
           "controller_reason", "onset_to_stop_s", "ended")


def load(run: str | Path) -> dict:
    """A run's ``summary.json``."""
    return json.loads((Path(run) / "summary.json").read_text())


def key(ep: dict) -> tuple:
    """What identifies an episode across runs."""
    return (ep["task"], ep["method"], ep["object"], ep["trial"], ep.get("arm", ""))


def compare(a: dict, b: dict) -> dict:
    """Shared episodes, identical ones, and the differences ``(key, field, a, b)``."""
    ea = {key(e): e for e in a["episodes"] if "error" not in e}
    eb = {key(e): e for e in b["episodes"] if "error" not in e}
    shared = sorted(set(ea) & set(eb))
    diffs = [(k, f, ea[k].get(f), eb[k].get(f)) for k in shared for f in OUTCOME
             if ea[k].get(f) != eb[k].get(f)]
    differing = {d[0] for d in diffs}
    return {"shared": len(shared), "identical": len(shared) - len(differing),
            "diffs": diffs}


def conditions(summary: dict) -> str:
    """How a run was made, in one line."""
    m = summary["meta"]
    return (f"mode {m.get('mode', 'realtime')}, {m.get('hogs', 0)} hogs, {m['workers']} "
            f"workers, load {m.get('load_start')} -> {m.get('load_end')}, "
            f"{m.get('wall_s', float('nan')):.0f} s, reruns {m.get('reruns', 0)}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run_a")
    p.add_argument("run_b")
    args = p.parse_args(argv)
    a, b = load(args.run_a), load(args.run_b)
    res = compare(a, b)
    print(f"A: {args.run_a}: {conditions(a)}")
    print(f"B: {args.run_b}: {conditions(b)}")
    print(f"{res['identical']}/{res['shared']} shared episodes identical")
    for k, f, va, vb in res["diffs"]:
        print(f"  {'-'.join(map(str, k))}: {f} {va!r} != {vb!r}")
    return 0 if res["shared"] and res["identical"] == res["shared"] else 1


if __name__ == "__main__":
    sys.exit(main())
