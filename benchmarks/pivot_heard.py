"""Does the estimator hear the turn in pivot-stop? ``python -m benchmarks.pivot_heard RUN``
(a ``make demo`` ``--out`` directory with the pivot-stop traces in ``episodes/``).

Pivot-stop stops on the estimated rotation (``rotation_threshold_rad_s``, 0.7 rad/s) and
misses on the quiet objects (docs/results.md). This reads the traces of the arm that ignores
rotation, so every trial turns as far as its travel limit lets it, and gives per object:

- the true rate while it turns (``|w_rel|`` over ``TURNING_RAD_S``, the scene's truth);
- the estimated rate over the same time, from ``HEARD_AFTER_S`` after the turn starts:
  median and maximum of ``|pred_w|``;
- the estimate's floor before the turn (its p99 over the ``FLOOR_S`` before, the arm
  already moving): what the estimate says when nothing turns;
- the median p(slip) while it turns.

An object whose estimate during the turn stays at its floor is not heard at all: no
threshold separates its turn from the arm's noise, and the fix is in what the model hears
(training data, features), not in the controller. Prints a markdown table; ``--json``
writes the figures.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from aslip_ros.util import write_json

#: A true rate above this counts as turning [rad/s].
TURNING_RAD_S = 0.5
#: The estimate is read from this long after the turn starts (a window's worth) [s].
HEARD_AFTER_S = 0.05
#: The floor is read over this long before the turn starts, ending 0.1 s before it [s].
FLOOR_S = 1.4
ARM = "ignores_rotation"


def episode_figures(trace) -> dict | None:
    """The figures of one trace (a mapping with ``t``, ``w_rel``, ``pred_t``, ``pred_w``,
    ``pred_p``), None when the object never turned or nothing was estimated meanwhile."""
    t, w = np.asarray(trace["t"], float), np.asarray(trace["w_rel"], float)
    pt, pw = np.asarray(trace["pred_t"], float), np.asarray(trace["pred_w"], float)
    pp = np.asarray(trace["pred_p"], float)
    turning = np.abs(w) > TURNING_RAD_S
    if not turning.any():
        return None
    t0, t1 = t[turning][0], t[turning][-1]
    during = (pt >= t0 + HEARD_AFTER_S) & (pt <= t1)
    before = (pt < t0 - 0.1) & (pt >= t0 - 0.1 - FLOOR_S)
    if not during.any():
        return None
    return {"true_rad_s": float(np.median(np.abs(np.interp(pt[during], t, w)))),
            "estimated_median_rad_s": float(np.median(np.abs(pw[during]))),
            "estimated_max_rad_s": float(np.max(np.abs(pw[during]))),
            "floor_p99_rad_s": (float(np.percentile(np.abs(pw[before]), 99))
                                if before.any() else float("nan")),
            "p_slip_median": float(np.median(pp[during]))}


def object_of(path: Path, method: str) -> str:
    """``pivot_stop-<method>-<arm>-<object>-<trial>.npz`` -> object."""
    return path.stem[len(f"pivot_stop-{method}-{ARM}-"):].rsplit("-", 1)[0]


def summarize(run: str | Path, method: str) -> dict:
    """Per object: the episodes read and the mean of each figure over them."""
    per: dict[str, list[dict]] = {}
    for f in sorted((Path(run) / "episodes").glob(f"pivot_stop-{method}-{ARM}-*.npz")):
        with np.load(f) as trace:
            got = episode_figures(trace)
        if got is not None:
            per.setdefault(object_of(f, method), []).append(got)
    return {obj: {"episodes": len(rows),
                  **{k: float(np.nanmean([r[k] for r in rows])) for k in rows[0]}}
            for obj, rows in per.items()}


def table(summary: dict, method: str) -> str:
    lines = [f"Pivot-stop, `{method}`, the arm that ignores rotation (means over episodes):",
             "",
             "| object | episodes | true rate rad/s | estimated: median, max | floor before "
             "the turn (p99) | p(slip) while turning |",
             "|---|---|---|---|---|---|"]
    for obj, s in sorted(summary.items(), key=lambda kv: -kv[1]["estimated_median_rad_s"]):
        lines.append(f"| {obj} | {s['episodes']} | {s['true_rad_s']:.2f} | "
                     f"{s['estimated_median_rad_s']:.2f}, {s['estimated_max_rad_s']:.2f} | "
                     f"{s['floor_p99_rad_s']:.2f} | {s['p_slip_median']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.pivot_heard",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a make demo --out directory with pivot-stop traces")
    ap.add_argument("--method", default="aslip", help="the pivot-stop method to read")
    ap.add_argument("--json", default=None, help="write the figures here")
    args = ap.parse_args(argv)
    summary = summarize(args.run, args.method)
    if not summary:
        print(f"no pivot-stop traces of {args.method} ({ARM}) in {args.run}/episodes",
              file=sys.stderr)
        return 1
    print(table(summary, args.method), end="")
    if args.json:
        write_json(args.json, {"run": str(args.run), "method": args.method,
                               "objects": summary})
    return 0


if __name__ == "__main__":
    sys.exit(main())
