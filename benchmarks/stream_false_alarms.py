"""How often a streaming checkpoint's slip decision fires without slip, on audio it never
saw: ``python -m benchmarks.stream_false_alarms --checkpoint models/aslip_stream.pt``.

The streaming model's trainer chooses its p(slip) threshold as the lowest one whose false
alarms stay within ``fa_per_min`` a minute on the validation trials (learn/training/
stream.py, ``select_threshold``). How far that rate holds depends on how much validation
audio without slip the choice rested on. This simulates a fresh draw of the streaming
part's training set (``benchmarks.demo_models.simulate_arm_drawn``, once the demo set's
trials, at ``--seed``, which the demo models are not trained on), exports it with the demo
recipe's windows, hop and labels, runs the checkpoint over every trial as the trainer's
validation does (whole trials from a zero state, with the checkpoint's per-grasp
calibration) and gives:

- the same sweep as the trainer's, on this audio: false alarms, their rate a minute and the
  frame recall of slip at each threshold, and the threshold the trainer's rule would choose
  here;
- the rate at the checkpoint's own threshold with a 95 % bootstrap interval over trials,
  for all trials and per condition (the arm moving or still), beside the rate its
  validation trials gave.

A false alarm is a rising edge of ``p >= threshold`` with no labelled slip in the 0.35 s
before (``false_alarms_per_min``). A hybrid checkpoint (``aslip``) is read through its
streaming part, which decides when a slip starts.

- what stops the arm: the slip-stop controller stops on ``debounce_count`` consecutive
  estimates that slip (``p >= threshold``) or turn (``|wy| >=
  rotation_threshold_rad_s``, the controller's defaults, ``SlipStopConfig``). Its stops
  a minute on the same audio, with no labelled slip or turn in the 0.35 s before
  (``controller_stops``), for the two together and for each alone, so that a rate shows
  which of the two decisions fires where nothing slips.

``--json`` writes the figures.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from aslip_ros.util import write_json

#: The fresh draw's default seed: not the demo recipe's (0).
DEFAULT_SEED = 1


def simulate_set(data: Path, seed: int, progress: bool = False) -> Path:
    """The fresh draw's dataset under ``data/seed-<seed>`` (bags and export reused when
    there)."""
    from aslip_ros.data.export import ExportConfig, export
    from aslip_ros.scene.layouts import DEFAULT_LAYOUT
    from benchmarks import demo_models as dm

    r = dm.RECIPE
    root = Path(data) / f"scene-{dm.scene_version()}" / f"seed-{seed}"
    ds = root / "dataset"
    if (ds / "manifest.json").exists():
        return ds
    common = dict(objects=list(dm.OBJECTS), duration_s=r["duration_s"], seed=seed,
                  layout=DEFAULT_LAYOUT, progress=progress)
    bags = dm.simulate_arm_drawn(root, common, factor=1)
    export(bags, ds, ExportConfig(window_s=r["window_s"], hop_s=r["hop_s"],
                                  label_smoothing_s=r["label_smoothing_s"], overwrite=True,
                                  progress=progress))
    return ds


def stream_part(path: str | Path):
    """The streaming checkpoint at ``path``, or a hybrid's streaming part."""
    from aslip_ros.learn.checkpoint import load_checkpoint
    from aslip_ros.learn.models.aslip_hybrid import STREAM, HybridBackend
    from aslip_ros.learn.models.aslip_stream import StreamBackend

    ck = load_checkpoint(path)
    if ck.model_type == HybridBackend.model_type:
        ck = HybridBackend.from_checkpoint(ck).parts[STREAM]
    if ck.model_type != StreamBackend.model_type:
        raise ValueError(f"{path}: a {ck.model_type} checkpoint; this reads a streaming "
                         f"one ({StreamBackend.model_type}) or a hybrid's streaming part")
    return ck


def sweep(checkpoint: str | Path, dataset: str | Path) -> dict:
    """The figures of the module docstring for one checkpoint on one dataset."""
    from aslip_ros.learn.calibration.grasp import CalibrationConstants
    from aslip_ros.learn.data_io import open_dataset
    from aslip_ros.learn.features import FeatureConfig
    from aslip_ros.learn.models.aslip_stream import StreamBackend
    from aslip_ros.learn.training.stream import (StreamTrainConfig, false_alarms_per_min,
                                                 pooled_rate, select_threshold,
                                                 trial_sequences)

    ck = stream_part(checkpoint)
    meta = ck.meta
    model = StreamBackend.from_checkpoint(ck)
    fcfg = FeatureConfig.from_dict(meta["feature_config"])
    cal = meta.get("calibration")
    cal = None if cal is None else CalibrationConstants.from_dict(cal)
    ds = open_dataset(dataset)
    seqs = trial_sequences(ds, range(len(ds.trials)), meta["channel_names"], fcfg,
                           calibration=cal)
    if not seqs.trials:
        raise ValueError(f"{dataset}: no trial without audio gaps to run")
    outs = [model.offline(x) for x in seqs.frames]
    p = [o[0] for o in outs]
    hop_s = fcfg.hop / fcfg.sample_rate
    chosen = meta.get("threshold_selection") or {}
    target = float(chosen.get("fa_per_min_target", StreamTrainConfig.fa_per_min))
    rule, table, minutes = select_threshold(p, seqs.slip, hop_s, target)
    own = float(meta["threshold"])
    by_condition: dict[str, list[tuple[int, float]]] = {}
    per_trial = [false_alarms_per_min(a, s, own, hop_s) for a, s in zip(p, seqs.slip)]
    stops = controller_stops(p, [o[2] for o in outs], seqs, own, hop_s)
    for k, got in zip(seqs.trials, per_trial):
        by_condition.setdefault(str(ds.trials[k].get("condition")), []).append(got)
    val = next((r for r in chosen.get("sweep", []) if abs(r["threshold"] - own) < 1e-9), None)
    overall = pooled_rate(per_trial)
    return {"checkpoint": str(checkpoint), "dataset": str(dataset), "trials": len(seqs.trials),
            "quiet_minutes": round(minutes, 3), "fa_per_min_target": target,
            "sweep": table, "rule_threshold": rule, "threshold": own,
            "validation_quiet_minutes": chosen.get("quiet_minutes"),
            "validation_fa_per_min": None if val is None else val["fa_per_min"],
            "fa_per_min": overall["fa_per_min"],
            "fa_per_min_ci": overall["fa_per_min_interval"],
            "controller_stops": stops,
            "at_threshold": {c: {"false_alarms": sum(n for n, _ in v),
                                 "quiet_minutes": round(sum(m for _, m in v), 3),
                                 **pooled_rate(v)}
                             for c, v in sorted(by_condition.items())}}


def debounced(flags: np.ndarray, count: int) -> np.ndarray:
    """Where ``flags`` has held for ``count`` consecutive hops (the controller's debounce)."""
    idx = np.arange(flags.size)
    last_off = np.maximum.accumulate(np.where(flags, -1, idx))
    return idx - last_off >= count


def controller_stops(p: list[np.ndarray], wy: list[np.ndarray | None], seqs, threshold: float,
                     hop_s: float) -> dict:
    """The slip-stop controller's stops where nothing slips or turns (the module docstring):
    for ``either`` decision (what the controller does), ``slip`` alone and ``rotation``
    alone, the pooled rate a minute with its trial interval; ``rotation`` is None for a
    checkpoint without the rotational output."""
    from aslip_ros.control.slip_stop import SlipStopConfig
    from aslip_ros.learn.training.stream import false_alarms_per_min, pooled_rate
    from aslip_ros.slip import ROTATION_EPSILON_RAD_S

    cfg = SlipStopConfig()
    k, w_thr = cfg.debounce_count, cfg.rotation_threshold_rad_s
    counts: dict[str, list] = {"either": [], "slip": [], "rotation": []}
    for a, w, slip, w_true in zip(p, wy, seqs.slip, seqs.w):
        moving = slip | (np.nan_to_num(np.abs(w_true)) > ROTATION_EPSILON_RAD_S)
        sl = a >= threshold
        rot = np.zeros_like(sl) if w is None else np.abs(w) >= w_thr
        for name, flags in (("either", sl | rot), ("slip", sl), ("rotation", rot)):
            stop = debounced(flags, k).astype(np.float32)
            counts[name].append(false_alarms_per_min(stop, moving, 0.5, hop_s))
    rot_model = any(w is not None for w in wy)
    return {"debounce_count": k, "rotation_threshold_rad_s": w_thr,
            **{n: pooled_rate(c) if (n != "rotation" or rot_model) else None
               for n, c in counts.items()}}


def report(res: dict) -> str:
    lines = [f"`{res['checkpoint']}` on {res['trials']} fresh trials, {res['quiet_minutes']:.1f} "
             f"min without slip:", "",
             "| threshold | false alarms | a minute | frame recall |", "|---|---|---|---|"]
    for r in res["sweep"]:
        mark = " (the checkpoint's)" if abs(r["threshold"] - res["threshold"]) < 1e-9 else ""
        recall = "-" if r["frame_recall"] is None else f"{r['frame_recall']:.3f}"
        lines.append(f"| {r['threshold']:.2f}{mark} | {r['false_alarms']} | "
                     f"{r['fa_per_min']:.2f} | {recall} |")
    val, ci = res["validation_fa_per_min"], res["fa_per_min_ci"]
    lines += ["", f"At the checkpoint's threshold: {res['fa_per_min']:.2f} a minute"
              + ("." if ci is None else f", 95 % interval over trials [{ci[0]:.2f}, "
                                        f"{ci[1]:.2f}].")]
    lines += ["", f"The trainer's rule (at most {res['fa_per_min_target']:g} a minute) would "
              f"choose {res['rule_threshold']:.2f} here; the checkpoint holds "
              f"{res['threshold']:.2f}"
              + ("." if val is None else
                 f", chosen at {val:.2f} a minute on {res['validation_quiet_minutes']} min of "
                 f"its validation trials."),
              "", "At the checkpoint's threshold, per condition: " + "; ".join(
                  f"{c} {v['fa_per_min']:.2f} a minute ({v['false_alarms']} in "
                  f"{v['quiet_minutes']:.1f} min)" for c, v in res["at_threshold"].items())
              + "."]
    st = res["controller_stops"]
    lines += ["", f"The slip-stop controller's stops without slip or turn "
              f"({st['debounce_count']} consecutive estimates that slip or turn at "
              f"|wy| >= {st['rotation_threshold_rad_s']:g} rad/s), a minute: " + "; ".join(
                  f"{n} {_rate(st[n])}" for n in ("either", "slip", "rotation")) + "."]
    return "\n".join(lines) + "\n"


def _rate(r: dict | None) -> str:
    if r is None:
        return "- (no rotational output)"
    ci = r["fa_per_min_interval"]
    return f"{r['fa_per_min']:.2f}" + ("" if ci is None else f" [{ci[0]:.2f}, {ci[1]:.2f}]")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.stream_false_alarms",
                                 description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--checkpoint", action="append", default=None,
                    help="a streaming or hybrid checkpoint (repeat to compare; default "
                         "models/aslip_stream.pt)")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED, help="the fresh draw's seed")
    ap.add_argument("--data", default="data/stream_false_alarms", help="scratch data")
    ap.add_argument("--dataset", default=None,
                    help="an exported dataset to read instead of the fresh draw")
    ap.add_argument("--json", default=None, help="write the figures here")
    args = ap.parse_args(argv)
    try:
        ds = Path(args.dataset) if args.dataset else simulate_set(Path(args.data), args.seed)
        results = [sweep(c, ds) for c in args.checkpoint or ["models/aslip_stream.pt"]]
    except (OSError, ValueError) as exc:
        print(f"benchmarks.stream_false_alarms: error: {exc}", file=sys.stderr)
        return 1
    for res in results:
        print(report(res))
    if args.json:
        write_json(args.json, {"seed": None if args.dataset else args.seed,
                               "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
