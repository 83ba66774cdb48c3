"""Where does slip-track lose its millimetres? ``python -m benchmarks.track_reversals RUN``
(a ``make demo`` ``--out`` directory with the slip-track traces in ``episodes/``).

The slip-track RMSE of every method has a long tail (docs/results.md, Table III: the
default's median 4.8 mm, its p90 15 mm). This reads each slip-track trace and asks, of
every published estimate while the object really slips (``|v_rel| > SLIPPING_M_S`` and
the estimate at least ``ESTIMATED_M_S``), whether it points backwards: more than 90 deg
from the true slip ``LAG_S`` earlier (the estimate's window ends at its stamp and
averages the slip over it, so it is compared with the slip half a window back). Per
method it gives:

- the share of backward estimates, over all episodes and over the episodes whose RMSE is
  above ``TAIL_MM``;
- the episodes with a sustained reversal (backward for ``SUSTAINED_S`` or more without a
  forward estimate between) and their share of the summed squared error;
- the Pearson correlation, over episodes, of the backward share with the RMSE;
- of the backward estimates, the share that point along the arm's own motion in the grasp
  plane (the arm's velocity from the TCP trace, mapped into the plane by the least-squares
  fit of ``object - tcp`` to ``rel``).

A backward estimate moves the arm away from the object it should follow, and the slip
that follows is larger, which is why a sustained one sends the arm to its speed limit.
Prints a markdown table; ``--json`` writes the figures.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from aslip_ros.util import write_json

#: The object slips [m/s] when its true relative speed is above this.
SLIPPING_M_S = 0.005
#: An estimate says slip [m/s] when its speed is at least this.
ESTIMATED_M_S = 0.002
#: The estimate is compared with the true slip this much earlier [s] (half a 200 ms window).
LAG_S = 0.1
#: Backward this long [s] without a forward estimate between: a sustained reversal.
SUSTAINED_S = 0.3
#: An episode in the tail has an RMSE above this [mm].
TAIL_MM = 10.0
#: The arm counts as moving [m/s] when its in-plane speed is above this.
MOVING_M_S = 0.005


def plane_of(trace) -> np.ndarray:
    """The (3, 2) map from grasp-plane (x, z) to the world: ``object - tcp = rel @ P.T``,
    fitted by least squares over the trace."""
    rel = np.asarray(trace["rel"], float)
    diff = np.asarray(trace["object"], float) - np.asarray(trace["tcp"], float)
    sol, *_ = np.linalg.lstsq(rel, diff, rcond=None)
    return sol.T


def _rmse_mm(trace) -> float:
    rel = np.asarray(trace["rel"], float)
    return float(np.sqrt(np.mean(np.sum((rel - rel[0]) ** 2, axis=1)))) * 1e3


def episode_figures(trace, rmse_mm: float | None = None, lag_s: float = LAG_S) -> dict | None:
    """The figures of one slip-track trace (``t``, ``tcp``, ``object``, ``rel``, ``v_rel``,
    ``pred_t``, ``pred_v``); None when no estimate was made while the object slipped.
    ``rmse_mm``: the episode's scored RMSE (default: of ``rel`` about its start)."""
    t = np.asarray(trace["t"], float)
    v = np.asarray(trace["v_rel"], float)
    pt, pv = np.asarray(trace["pred_t"], float), np.asarray(trace["pred_v"], float)
    true = np.stack([np.interp(pt - lag_s, t, v[:, k]) for k in range(2)], axis=1)
    arm_world = np.gradient(np.asarray(trace["tcp"], float), t, axis=0)
    arm_plane = arm_world @ plane_of(trace)
    arm = np.stack([np.interp(pt - lag_s, t, arm_plane[:, k]) for k in range(2)], axis=1)
    st, sp, sa = (np.linalg.norm(x, axis=1) for x in (true, pv, arm))
    valid = (st > SLIPPING_M_S) & (sp >= ESTIMATED_M_S)
    if not valid.any():
        return None
    backward = valid & ((true * pv).sum(1) < 0)
    along_arm = backward & (sa > MOVING_M_S) & ((arm * pv).sum(1) > 0)
    # The longest run of backward estimates with no forward one between.
    longest, start = 0.0, None
    for i in np.flatnonzero(valid):
        if backward[i]:
            start = pt[i] if start is None else start
            longest = max(longest, pt[i] - start)
        else:
            start = None
    n_back = int(backward.sum())
    return {"rmse_mm": float(_rmse_mm(trace) if rmse_mm is None else rmse_mm),
            "estimates": int(valid.sum()), "backward": n_back,
            "backward_share": n_back / int(valid.sum()),
            "backward_along_arm": int(along_arm.sum()),
            "longest_backward_s": float(longest)}


def method_of(path: Path) -> str:
    """``slip_track-<method>-<object>-<trial>.npz`` -> method."""
    return path.stem.split("-")[1]


def _scored_rmse(run: Path) -> dict:
    """``{trace file stem: pose RMSE mm}`` from the run's summary.json, where there is one."""
    import json
    f = run / "summary.json"
    if not f.exists():
        return {}
    eps = json.loads(f.read_text()).get("episodes", [])
    return {f"slip_track-{e['method']}-{e['object']}-{e['trial']:02d}": e["pose_rmse_m"] * 1e3
            for e in eps if e.get("task") == "slip_track" and e.get("pose_rmse_m") is not None}


def summarize(run: str | Path, lag_s: float = LAG_S) -> dict:
    """Per method: the figures of the module docstring."""
    run = Path(run)
    scored = _scored_rmse(run)
    per: dict[str, list[dict]] = {}
    for f in sorted((run / "episodes").glob("slip_track-*.npz")):
        with np.load(f) as trace:
            got = episode_figures(trace, scored.get(f.stem), lag_s)
        if got is not None:
            per.setdefault(method_of(f), []).append(got)
    out = {}
    for method, rows in per.items():
        rmse = np.array([r["rmse_mm"] for r in rows])
        share = np.array([r["backward_share"] for r in rows])
        tail = rmse > TAIL_MM
        sustained = np.array([r["longest_backward_s"] >= SUSTAINED_S for r in rows])
        sq = rmse ** 2
        back = sum(r["backward"] for r in rows)
        out[method] = {
            "episodes": len(rows), "rmse_mean_mm": float(rmse.mean()),
            "backward_share": float(back / sum(r["estimates"] for r in rows)),
            "backward_share_tail": float(share[tail].mean()) if tail.any() else None,
            "backward_share_rest": float(share[~tail].mean()) if (~tail).any() else None,
            "tail_episodes": int(tail.sum()),
            "sustained_episodes": int(sustained.sum()),
            "sustained_share_of_squared_error": float(sq[sustained].sum() / sq.sum())
            if sq.sum() > 0 else 0.0,
            "rmse_mean_without_sustained_mm": float(rmse[~sustained].mean())
            if (~sustained).any() else None,
            "corr_backward_share_rmse": float(np.corrcoef(share, rmse)[0, 1])
            if len(rows) > 2 and share.std() > 0 and rmse.std() > 0 else None,
            "backward_along_arm_share": float(sum(r["backward_along_arm"] for r in rows)
                                              / back) if back else None}
    return out


def _f(x, fmt: str = ".2f") -> str:
    return "-" if x is None else format(x, fmt)


def table(summary: dict, lag_s: float = LAG_S) -> str:
    lines = [f"Slip-track estimates pointing backwards (> 90 deg from the true slip {lag_s:g} s "
             "earlier), per method:", "",
             "| method | episodes | RMSE mm | backward share: all, RMSE > "
             f"{TAIL_MM:g} mm, rest | corr. with RMSE | sustained (>= {SUSTAINED_S:g} s) "
             "episodes, share of squared error | RMSE without them mm | backward ones along "
             "the arm's motion |",
             "|---|---|---|---|---|---|---|---|"]
    for m, s in sorted(summary.items(), key=lambda kv: kv[1]["rmse_mean_mm"]):
        lines.append(
            f"| {m} | {s['episodes']} | {s['rmse_mean_mm']:.1f} | {_f(s['backward_share'])}, "
            f"{_f(s['backward_share_tail'])} ({s['tail_episodes']}), "
            f"{_f(s['backward_share_rest'])} | {_f(s['corr_backward_share_rmse'])} | "
            f"{s['sustained_episodes']}, {_f(s['sustained_share_of_squared_error'])} | "
            f"{_f(s['rmse_mean_without_sustained_mm'], '.1f')} | "
            f"{_f(s['backward_along_arm_share'])} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.track_reversals",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a make demo --out directory with slip-track traces")
    ap.add_argument("--lag", type=float, default=LAG_S,
                    help=f"compare with the true slip this much earlier [s] ({LAG_S:g})")
    ap.add_argument("--json", default=None, help="write the figures here")
    args = ap.parse_args(argv)
    summary = summarize(args.run, args.lag)
    if not summary:
        print(f"no slip-track traces in {args.run}/episodes", file=sys.stderr)
        return 1
    print(table(summary, args.lag), end="")
    if args.json:
        write_json(args.json, {"run": str(args.run), "lag_s": args.lag, "methods": summary})
    return 0


if __name__ == "__main__":
    sys.exit(main())
