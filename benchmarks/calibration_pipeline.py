"""Per-grasp calibration through the user's pipeline: simulate -> export -> train -> evaluate.

    python -m benchmarks.calibration_pipeline --work /tmp/calbench \\
        --out results/calibration --variant coupling --models svm,cnn --cnn-budget 240

For one scene variant (``aslip simulate --variant``), it records 5 objects x ``--trials``
external-induced grasps of 30 s, exports them, trains every model with ``--calibration
background`` and ``--calibration off`` (the ``aslip train`` and ``aslip evaluate`` command
lines, run as subprocesses) and writes ``<out>/<variant>.json``: each model's test metrics
from ``aslip evaluate``, 95 % intervals from resampling test trials, and the paired
difference of direction MAE (background - off). ``--chart`` also renders fresh grasps of
the variant with known gains and plots the RMS error of the background estimate against
the time since the grasp started (``<out>/convergence.png`` and ``.json``).

``--frames-table --checkpoint models/aslip_stream.pt`` measures what the state's two
constants cost (``prior_frames``, ``converge_frames``): on held-out scene grasps (five objects,
the arm moving and still, known gains), the RMS and 90th-percentile gain error after a given
number of accepted frames, for several priors (``<out>/frames.json`` and ``frames.md``).
The package's defaults come from this table.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

OBJECTS = "pla_rod,glass_cleaner,chips_can,mustard_container,cracker_box"
CALIBRATIONS = ("background", "off")


def _cli(*args: str, log=print) -> None:
    cmd = [sys.executable, "-m", "aslip_ros.cli", *args]
    log("$ aslip " + " ".join(args))
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    log(f"  ({time.perf_counter() - t0:.0f} s)")


def make_dataset(work: Path, variant: str, trials: int) -> Path:
    bags, ds = work / f"bags_{variant}", work / f"ds_{variant}"
    if not (ds / "manifest.json").is_file():
        _cli("simulate", "--kind", "external", "--conditions", "robot_stationary",
             "--objects", OBJECTS, "--trials", str(trials), "--duration", "30",
             "--variant", variant, "-o", str(bags), "--no-progress")
        _cli("export", str(bags), "-o", str(ds), "--no-progress", "--overwrite")
    return ds


def per_window(ckpt: Path, ds_path: Path) -> dict[str, np.ndarray]:
    """Test-split predictions the way ``aslip evaluate`` makes them, for the intervals."""
    from aslip_ros.learn.evaluate import predict_split
    r = predict_split(ckpt, ds_path, "test")
    return {"p": r["prob"], "vel": r["raw_velocity"], "v": r["true_velocity"],
            "slip": r["slip"], "trial": r["trial"], "window_s": r["window_s"]}


def run_variant(args: argparse.Namespace) -> dict:
    from aslip_ros.learn import stats
    work, out = Path(args.work), Path(args.out)
    ds = make_dataset(work, args.variant, args.trials)
    res: dict = {"variant": args.variant, "dataset": str(ds), "models": {}}
    for model in args.models.split(","):
        z = {}
        for cal in CALIBRATIONS:
            ck = work / f"{model}_{args.variant}_{cal}.pt"
            train = ["train", "--dataset", str(ds), "--out", str(ck), "--calibration", cal,
                     "--no-progress", "--threads", "1"]
            train += ["--stage", "svm"] if model == "svm" else \
                ["--stage", "scratch", "--time-budget", str(args.cnn_budget)]
            _cli(*train)
            ev = work / f"{model}_{args.variant}_{cal}.eval.json"
            _cli("evaluate", "--checkpoint", str(ck), "--dataset", str(ds), "--split", "test",
                 "--json", str(ev), "--threads", "1")
            z[cal] = per_window(ck, ds)
            w = z[cal]
            boot = stats.bootstrap_metrics(w["trial"], w["p"], w["vel"], w["v"], w["slip"],
                                           w["window_s"], n_boot=500)
            res["models"][f"{model}_{cal}"] = {
                "evaluate": json.loads(ev.read_text())["overall"],
                "bootstrap": {k: boot[k] for k in boot if k.endswith("_ci")},
                "train_command": "aslip " + " ".join(train)}

        def mae(w):
            return lambda i: stats.compute_metrics(w["p"][i], w["vel"][i], w["v"][i],
                                                   w["slip"][i], w["window_s"]
                                                   )["direction_mae_deg"]
        est, lo, hi = stats.paired_difference(z["background"]["trial"], mae(z["background"]),
                                              mae(z["off"]), n_boot=500)
        res["models"][f"{model}_direction_mae_background_minus_off"] = [est, lo, hi]
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{args.variant}.json").write_text(json.dumps(res, indent=2, default=float))
    return res


def convergence(args: argparse.Namespace) -> None:
    """RMS gain error of the background estimate [dB] vs seconds since the grasp started."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aslip_ros.learn.calibration.grasp import (CalibrationConstants, offsets_at,
                                                   relative_log_gain)
    from aslip_ros.learn.calibration.frames import FrameCutter
    from aslip_ros.learn.checkpoint import load_checkpoint
    from aslip_ros.learn.features import FeatureConfig
    from aslip_ros.scene import OBJECTS as SCENE_OBJECTS
    from aslip_ros.scene import World
    from aslip_ros.scene import scenarios as sc
    times = np.array([0.5, 1, 2, 3, 5, 7.5, 10, 15, 20, 30])
    curves = {}
    for variant in ("coupling", "one_sided"):
        meta = load_checkpoint(Path(args.work) / f"svm_{variant}_background.pt").meta
        k = CalibrationConstants.from_dict(meta["calibration"])
        cutter = FrameCutter(FeatureConfig.from_dict(meta["feature_config"]), 48000.0)
        err, spread = [], []
        for i in range(args.chart_grasps):
            scn = sc.external_induced(seed=90000 + i, object=list(SCENE_OBJECTS)[i % 5],
                                      duration_s=30.0, sample_rate=48000.0,
                                      condition="robot_stationary")
            world = World(sc.VARIANTS[variant](scn))
            audio = np.concatenate([c.audio for c in world.stream(block_frames=4800)])
            est = offsets_at(cutter.frames(audio), cutter.count(times * 48000), k)
            truth = relative_log_gain(world.synth.gain)
            err.append(np.sqrt(np.mean((est - truth) ** 2, axis=1)) * 10 / np.log(10))
            spread.append(np.mean(truth ** 2))
        e = np.array(err)
        truth_spread = float(np.sqrt(np.mean(spread)) * 10 / np.log(10))
        curves[variant] = {"t_s": times.tolist(), "rms_db": np.sqrt((e ** 2).mean(0)).tolist(),
                           "p90_db": np.percentile(e, 90, axis=0).tolist(),
                           "uncalibrated_rms_db": truth_spread,
                           "convergence_s": k.convergence_s, "grasps": args.chart_grasps}
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for variant, cv in curves.items():
        ax.plot(cv["t_s"], cv["rms_db"], marker="o", label=f"{variant}: RMS")
        ax.plot(cv["t_s"], cv["p90_db"], ls="--", label=f"{variant}: 90th percentile")
    ax.axhline(curves["coupling"]["uncalibrated_rms_db"], color="grey", lw=0.8,
               label="no calibration (equal gains assumed)")
    ax.set_xscale("log")
    ax.set_xlabel("time since the grasp started [s]")
    ax.set_ylabel("relative gain error [dB]")
    ax.set_title("background calibration, held-out grasps")
    ax.legend(fontsize=7)
    fig.tight_layout()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "convergence.png", dpi=120)
    (out / "convergence.json").write_text(json.dumps(curves, indent=2))


FRAME_COUNTS = (10, 20, 30, 40, 60, 80, 100, 150, 200, 300)
PRIORS = (0.0, 10.0, 25.0, 50.0)


def frames_table(args: argparse.Namespace) -> dict:
    """Gain error [dB] against accepted frames and prior, on fresh scene grasps."""
    from aslip_ros.learn.calibration.frames import FrameCutter
    from aslip_ros.learn.calibration.grasp import (CalibrationConstants, frame_stats,
                                                   frame_weights, relative_log_gain)
    from aslip_ros.learn.checkpoint import load_checkpoint
    from aslip_ros.learn.features import FeatureConfig
    from aslip_ros.scene import OBJECTS as SCENE_OBJECTS
    from aslip_ros.scene import World
    from aslip_ros.scene import scenarios as sc
    meta = load_checkpoint(args.checkpoint).meta
    k = CalibrationConstants.from_dict(meta["calibration"])
    cutter = FrameCutter(FeatureConfig.from_dict(meta["feature_config"]), 48000.0)
    db = 10.0 / np.log(10.0)
    grasps = []
    for i in range(args.chart_grasps):
        scn = sc.external_induced(seed=70000 + i, object=list(SCENE_OBJECTS)[i % 5],
                                  duration_s=12.0, sample_rate=48000.0,
                                  condition=("robot_moving", "robot_stationary")[i % 2])
        world = World(scn)
        audio = np.concatenate([c.audio for c in world.stream(block_frames=4800)])
        dev, p, active = frame_stats(cutter.frames(audio), k)
        w = frame_weights(p, active, k)
        centred = (dev - np.asarray(k.ref_offset)[:, None]) * w
        grasps.append((np.cumsum(w), np.cumsum(centred.T, axis=0),
                       relative_log_gain(world.synth.gain)))
    rows = []
    for prior in PRIORS:
        for n in FRAME_COUNTS:
            errs = [np.sqrt(np.mean((cs[j] / (cw[j] + prior) - truth) ** 2)) * db
                    for cw, cs, truth in grasps
                    for j in [int(np.searchsorted(cw, n))] if j < cw.size]
            rows.append({"prior_frames": prior, "accepted_frames": n, "grasps": len(errs),
                         "rms_db": float(np.sqrt(np.mean(np.square(errs)))),
                         "p90_db": float(np.percentile(errs, 90))})
    raw = float(np.sqrt(np.mean([np.mean(g[2] ** 2) for g in grasps])) * db)
    res = {"checkpoint": str(args.checkpoint), "grasps": len(grasps),
           "uncalibrated_rms_db": raw, "rows": rows}
    lines = [f"Gain error after n accepted frames (RMS / p90 dB over {len(grasps)} held-out "
             f"grasps; uncorrected {raw:.2f} dB)", "",
             "| prior frames | " + " | ".join(str(n) for n in FRAME_COUNTS) + " |",
             "|---|" + "---|" * len(FRAME_COUNTS)]
    for prior in PRIORS:
        cells = [f"{r['rms_db']:.2f} / {r['p90_db']:.2f}" for r in rows
                 if r["prior_frames"] == prior]
        lines.append(f"| {prior:g} | " + " | ".join(cells) + " |")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "frames.json").write_text(json.dumps(res, indent=1))
    (out / "frames.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.calibration_pipeline")
    p.add_argument("--work", help="bags, datasets and checkpoints go here")
    p.add_argument("--out", default="results/calibration")
    p.add_argument("--variant", choices=("coupling", "one_sided"), default="coupling")
    p.add_argument("--trials", type=int, default=8, help="grasps per object")
    p.add_argument("--models", default="svm,cnn")
    p.add_argument("--cnn-budget", type=float, default=240.0, help="seconds per CNN")
    p.add_argument("--chart", action="store_true", help="only the convergence chart")
    p.add_argument("--chart-grasps", type=int, default=10)
    p.add_argument("--frames-table", action="store_true",
                   help="only the gain error against accepted frames and prior")
    p.add_argument("--checkpoint", default="models/aslip_stream.pt",
                   help="--frames-table: whose calibration constants (gate, floor)")
    args = p.parse_args(argv)
    if args.frames_table:
        frames_table(args)
        return 0
    if not args.work:
        p.error("--work is required (except with --frames-table)")
    import torch
    torch.set_num_threads(1)
    if args.chart:
        convergence(args)
    else:
        res = run_variant(args)
        print(json.dumps(res["models"], indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
