"""Would another rotation rule stop pivot-stop on the quiet objects without stopping slip-stop
early? ``python -m benchmarks.rotation_rule RUN [RUN ...]`` (``make demo`` and
``make demo-variants`` ``--out`` directories, with their traces in ``episodes/``).

Until the arm's first stop the loop is open: in the lockstep demo the arm's motion before it
does not depend on the estimates. A recorded trace therefore says exactly when the
slip-stop controller would first have stopped under another ``rotation_threshold_rad_s`` or
``debounce_count``: this feeds the trace's estimates, from the start of its approach, to
the controller itself (:class:`aslip_ros.control.slip_stop.SlipStop`) and reads when it
stops. Per rule:

- pivot-stop: of the traces of the arm that ignores rotation (which turn as far as the
  travel limit lets them), those where the rule stops after the object starts turning,
  per object;
- slip-stop: of every slip-stop trace of the method (the default scene and each variant),
  those where the rule stops before the object meets the wall (a failure: nothing slipped).

What it cannot say: a trace records ``p(slip)``, not the published decision, so an estimate
counts as slipping at ``p >= threshold`` (the checkpoint's). A hybrid's ``latched`` decision
may keep a slip the stream part started a hop longer, so the replay may stop a hop later than
the loop; the shipped rule's replay is printed beside the loop's count to show the gap.
Prints a markdown table; ``--json`` writes the figures.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from aslip_ros.control.slip_stop import SlipStop, SlipStopConfig, State
from aslip_ros.util import write_json

#: A relative speed [m/s] or rate [rad/s] above these means the object moves in the grasp:
#: it met the wall (slip-stop) or started to turn (pivot-stop).
MOVING_M_S = 0.005
TURNING_RAD_S = 0.05
#: The rules replayed: (rotation threshold rad/s, consecutive estimates).
DEFAULT_RULES = ((0.5, 2), (0.3, 2), (0.25, 2), (0.2, 2), (0.15, 2), (0.2, 4), (0.15, 8))
PIVOT_ARM = "ignores_rotation"


@dataclass(frozen=True)
class Trace:
    """What a rule is replayed on: the estimates (times [s], p(slip), rate [rad/s]), when
    the approach starts and when the object starts moving in the grasp (inf: never)."""

    t: np.ndarray
    p: np.ndarray
    w: np.ndarray
    approach_s: float
    moves_s: float


def approach_start(t: np.ndarray, tcp: np.ndarray, direction: np.ndarray) -> float:
    """The first time the arm moves along ``direction`` after its last move back (the
    retract): the approach."""
    x = np.asarray(tcp, float) @ np.asarray(direction, float)
    v = np.gradient(x, t)
    back = np.flatnonzero(v < -MOVING_M_S)
    start = back[-1] + 1 if back.size else 0
    fwd = np.flatnonzero(v[start:] > MOVING_M_S)
    return float(t[start + fwd[0]]) if fwd.size else math.inf


def trace_of(rec) -> Trace:
    """A demo episode's arrays (``t``, ``tcp``, ``push_dir``, ``v_rel``, ``w_rel``,
    ``pred_t``, ``pred_p``, ``pred_w``) as a :class:`Trace`."""
    t = np.asarray(rec["t"], float)
    moving = (np.linalg.norm(np.asarray(rec["v_rel"], float), axis=1) > MOVING_M_S) \
        | (np.abs(np.asarray(rec["w_rel"], float)) > TURNING_RAD_S)
    return Trace(np.asarray(rec["pred_t"], float), np.asarray(rec["pred_p"], float),
                 np.asarray(rec["pred_w"], float),
                 approach_start(t, rec["tcp"], rec["push_dir"]),
                 float(t[moving][0]) if moving.any() else math.inf)


def first_stop(trace: Trace, threshold: float, rotation_rad_s: float, debounce: int) -> float:
    """When the slip-stop controller, in its approach from ``trace.approach_s``, stops on
    the trace's estimates under this rule [s] (inf: it does not)."""
    cfg = SlipStopConfig(direction=(1.0, 0.0, 0.0), debounce_count=debounce,
                         rotation_threshold_rad_s=rotation_rad_s, stop_on_rotation=True,
                         settle_s=0.1, retract_distance_m=0.01)
    task = SlipStop(cfg)
    t0 = trace.approach_s - 2.0 * cfg.settle_s      # settled with time to spare
    home, back = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0), (-0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    task.on_tcp_pose(home, now=t0)
    task.start(now=t0)
    for t in (t0, trace.approach_s):          # retracted at once, settled, then approaching
        task.on_tcp_pose(back, now=t)
        task.on_slip(False, now=t)
        task.step(now=t)
    assert task.state is State.APPROACHING, task.state
    for t, p, w in zip(trace.t, trace.p, trace.w):
        if t < trace.approach_s:
            continue
        task.on_slip(bool(p >= threshold), now=float(t), angular_velocity=float(w))
        if task.state is State.STOPPED:
            return float(t)
    return math.inf


def _traces(runs: Iterable[Path], pattern: str) -> list[tuple[str, Trace]]:
    out = []
    for run in runs:
        for f in sorted((Path(run) / "episodes").glob(pattern)):
            with np.load(f) as rec:
                if "pred_w" in rec.files and len(rec["pred_t"]):
                    out.append((f.stem, trace_of(rec)))
    return out


def evaluate(runs: Sequence[Path], method: str, threshold: float,
             rules: Sequence[tuple[float, int]] = DEFAULT_RULES) -> dict:
    """Per rule: pivot-stops after the turn starts (overall and per object) and slip-stops
    before the wall (overall and per scene: ``default`` or the variant's name)."""
    pivot = _traces(runs, f"pivot_stop-{method}-{PIVOT_ARM}-*.npz")
    slip = _traces(runs, f"slip_stop-{method}-*.npz")
    out = {"method": method, "threshold": threshold, "pivot_traces": len(pivot),
           "slip_traces": len(slip), "rules": []}
    for rate, n in rules:
        per_obj: dict[str, list[int]] = {}
        for name, tr in pivot:
            obj = name[len(f"pivot_stop-{method}-{PIVOT_ARM}-"):].rsplit("-", 1)[0]
            s = first_stop(tr, threshold, rate, n)
            cell = per_obj.setdefault(obj, [0, 0])
            cell[0] += int(tr.moves_s < s < math.inf)
            cell[1] += 1
        per_scene: dict[str, list[int]] = {}
        for name, tr in slip:
            parts = name.split("-")
            scene = parts[-1] if not parts[-1].isdigit() else "default"
            cell = per_scene.setdefault(scene, [0, 0])
            cell[0] += int(first_stop(tr, threshold, rate, n) < tr.moves_s)
            cell[1] += 1
        out["rules"].append({
            "rotation_threshold_rad_s": rate, "debounce_count": n,
            "pivot_stopped": sum(c[0] for c in per_obj.values()),
            "pivot_per_object": {k: v[0] for k, v in sorted(per_obj.items())},
            "slip_stop_early": sum(c[0] for c in per_scene.values()),
            "slip_stop_early_per_scene": {k: f"{v[0]}/{v[1]}"
                                          for k, v in sorted(per_scene.items())}})
    return out


def table(res: dict) -> str:
    objs = sorted({o for r in res["rules"] for o in r["pivot_per_object"]})
    lines = [f"Rotation rules replayed on `{res['method']}`'s traces (p(slip) at "
             f"{res['threshold']:g}): {res['pivot_traces']} pivot-stop traces of the arm that "
             f"ignores rotation, {res['slip_traces']} slip-stop traces.", "",
             "| rotation rad/s, consecutive | pivot-stop after the turn | "
             + " | ".join(objs) + " | slip-stop before the wall | per scene |",
             "|---|---|" + "---|" * len(objs) + "---|---|"]
    for r in res["rules"]:
        scenes = ", ".join(f"{k} {v}" for k, v in r["slip_stop_early_per_scene"].items()
                           if not v.startswith("0/"))
        lines.append(f"| {r['rotation_threshold_rad_s']:g}, {r['debounce_count']} | "
                     f"{r['pivot_stopped']}/{res['pivot_traces']} | "
                     + " | ".join(str(r["pivot_per_object"].get(o, 0)) for o in objs)
                     + f" | {r['slip_stop_early']}/{res['slip_traces']} | {scenes or '-'} |")
    return "\n".join(lines) + "\n"


def _rule(text: str) -> tuple[float, int]:
    rate, _, n = text.partition(",")
    return float(rate), int(n or SlipStopConfig.debounce_count)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.rotation_rule",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="make demo / make demo-variants --out directories")
    ap.add_argument("--method", default="aslip")
    ap.add_argument("--checkpoint", default="models/aslip.pt",
                    help="whose decision threshold turns p(slip) into slipping")
    ap.add_argument("--rules", nargs="+", type=_rule, default=list(DEFAULT_RULES),
                    metavar="RATE[,N]", help="rotation threshold rad/s and consecutive count")
    ap.add_argument("--json", default=None, help="write the figures here")
    args = ap.parse_args(argv)
    from aslip_ros.learn.checkpoint import load_checkpoint
    try:
        threshold = float(load_checkpoint(args.checkpoint).meta["threshold"])
    except (OSError, ValueError, KeyError) as exc:
        print(f"cannot read the threshold of {args.checkpoint}: {exc}", file=sys.stderr)
        return 2
    res = evaluate([Path(r) for r in args.runs], args.method, threshold, args.rules)
    if not res["pivot_traces"] and not res["slip_traces"]:
        print(f"no {args.method} traces under {args.runs}", file=sys.stderr)
        return 2
    print(table(res), end="")
    if args.json:
        write_json(args.json, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
