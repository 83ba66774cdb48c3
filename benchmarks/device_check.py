"""``aslip train --device``: does a GPU give the CPU's results, and how much faster?

The same scratch CNN recipe is trained on one synthetic 48 kHz, 4-microphone dataset
(``learn.synthetic``, coupled per grasp) for a fixed number of epochs (no time budget, no
early stopping, so both devices run the same optimiser steps), once per seed on each
device. It reports each device's validation figures over the seeds (the seed spread is
the yardstick: a GPU's results "match" when its mean lies within the CPU's seeds' range
widened by the spread) and the training seconds per epoch (features excluded: they are
computed once, on the CPU, and cached).

Needs only numpy, scipy, scikit-learn and torch, so it runs on a GPU machine without ROS:

    python -m benchmarks.device_check --out results/device      (a CUDA GPU: cpu and cuda)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from aslip_ros.learn.stats import KEYS


def train_once(ds_path: Path, device: str, seed: int, epochs: int, threads: int
               ) -> dict[str, Any]:
    from aslip_ros.learn.data_io import open_dataset
    from aslip_ros.learn.training.config import TrainConfig
    from aslip_ros.learn.models.aslip_cnn_fit import scratch
    ds = open_dataset(ds_path)
    cfg = TrainConfig(stage="scratch", epochs=epochs, patience=epochs, seed=seed,
                      threads=threads, progress=False, device=device,
                      calibration="background", time_budget_s=1e9)
    job = scratch(ds, cfg, log=lambda m: None)
    t0 = time.perf_counter()
    job.advance(1e9)
    if device == "cuda":
        import torch
        torch.cuda.synchronize()
    train_s = time.perf_counter() - t0
    res = job.result()
    val = res.meta["provenance"]["metrics"]["val"]
    return {"device": device, "seed": seed, "epochs": len(res.history),
            "train_s": round(train_s, 2), "s_per_epoch": round(train_s / len(res.history), 3),
            **{k: val.get(k) for k in KEYS}}


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for dev in sorted({r["device"] for r in runs}):
        rs = [r for r in runs if r["device"] == dev]
        out[dev] = {"s_per_epoch": float(np.median([r["s_per_epoch"] for r in rs]))}
        for k in KEYS:
            v = np.array([r[k] for r in rs], float)
            out[dev][k] = {"mean": float(v.mean()), "min": float(v.min()),
                           "max": float(v.max())}
    if "cpu" in out and "cuda" in out:
        c, g = out["cpu"], out["cuda"]
        out["speed_up"] = c["s_per_epoch"] / g["s_per_epoch"]
        match = {}
        for k in KEYS:
            spread = max(c[k]["max"] - c[k]["min"], g[k]["max"] - g[k]["min"]) + 1e-9
            match[k] = bool(c[k]["min"] - spread <= g[k]["mean"] <= c[k]["max"] + spread)
        out["within_seed_spread"] = match
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.device_check",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="results/device")
    p.add_argument("--data", default=None, help="dataset directory (default <out>/data)")
    p.add_argument("--trials", type=int, default=30)
    p.add_argument("--duration", type=float, default=20.0)
    p.add_argument("--epochs", type=int, default=15)
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--devices", default="cpu,cuda")
    p.add_argument("--threads", type=int, default=0, help="CPU torch threads (0: all cores)")
    a = p.parse_args(argv)
    import os
    import torch
    devices = [d for d in a.devices.split(",") if d]
    if "cuda" in devices and not torch.cuda.is_available():
        print("device_check: no CUDA GPU here (torch.cuda.is_available() is False); run it "
              "on a machine with one, or --devices cpu", file=sys.stderr)
        return 1
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    ds_path = Path(a.data) if a.data else out / "data"
    if not (ds_path / "manifest.json").is_file():
        from aslip_ros.learn.synthetic import make_synthetic_dataset
        make_synthetic_dataset(ds_path, n_trials=a.trials, duration_s=a.duration,
                               sample_rate=48000.0, coupling_db=3.0, background=0.02, seed=7)
    threads = a.threads or os.cpu_count() or 1
    runs = []
    for dev in devices:
        for s in (int(x) for x in a.seeds.split(",") if x.strip()):
            runs.append(train_once(ds_path, dev, s, a.epochs, threads))
            print(json.dumps(runs[-1]), file=sys.stderr, flush=True)
    info = {"torch": torch.__version__, "threads": threads,
            "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
            "config": vars(a), "runs": runs, "summary": summarise(runs)}
    (out / "device_check.json").write_text(json.dumps(info, indent=1))
    print(json.dumps(info["summary"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
