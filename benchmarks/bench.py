"""Speed against accuracy: ``make bench`` (``python -m benchmarks.bench``).

For every method (the SVM and CNNs of several sizes) the CPU latency of one window
(features + model, ``Predictor.predict``, one torch thread, after warm-up; p50 and p99) and
the accuracy on the externally induced test split. Two sweeps:

- model size (width, depth, temporal channels) at the default features, marking the
  smallest model whose direction MAE is within 1 degree of the best;
- feature setting (feature sample rate, n_fft, hop, n_mels), one knob at a time around the
  default, naming the cheapest setting that loses no accuracy.

Every sweep point is trained with the same recipe as the ablation's default row (pretrain on
the robot-induced set, finetune the heads on the externally induced set), and checkpoints of
the ablation (``results/ablation/cache``) are reused when they exist.

Also in ``bench.json``: the scene's generation speed (x real time, peak memory;
``scene.bench.measure``), the export speed (``data.export.measure_export_speed``) and the
live node's latency (``node_bench``). The chart and the markdown table:
``bench_report.py``. Lag against accuracy (the streaming estimator against window models):
``python -m benchmarks.lag`` (docs/streaming.md).

Latency is wall time on whatever machine runs this; on a shared machine other processes
inflate p99, so ``bench.json`` records the load average beside the numbers.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from aslip_ros.scene.layouts import DEFAULT_LAYOUT
from aslip_ros.util import write_json, write_text

from .bench_report import bench_markdown, plot_pareto
from .common import (DataPlan, Log, Recipe, add_plan_arguments, plan_from_args, evaluate_cached,
                     fmt_num, paper_units, recipe_changes, configured, train_named)

#: Model-size sweep: name -> ModelConfig overrides (the default is width 16, depth 3, 64).
MODEL_SIZES: dict[str, dict[str, int]] = {
    "cnn_xs": {"width": 4, "depth": 2, "temporal_channels": 16, "head_hidden": 16},
    "cnn_s": {"width": 8, "depth": 2, "temporal_channels": 32, "head_hidden": 16},
    "cnn_m": {"width": 8, "depth": 3, "temporal_channels": 32, "head_hidden": 32},
    "cnn_default": {},
    "cnn_l": {"width": 32, "depth": 3, "temporal_channels": 128, "head_hidden": 64},
}

#: Feature sweep, one knob at a time around the default (16 kHz, 512, 160, 40 mels).
FEATURE_SWEEP: dict[str, dict[str, float]] = {
    "fs8k": {"sample_rate": 8000.0, "n_fft": 256, "hop": 80},
    "fs24k": {"sample_rate": 24000.0, "n_fft": 768, "hop": 240},
    "nfft256": {"n_fft": 256},
    "nfft1024": {"n_fft": 1024},
    "hop80": {"hop": 80},
    "hop320": {"hop": 320},
    "mels20": {"n_mels": 20},
    "mels64": {"n_mels": 64},
}
#: Run by default: the settings cheaper than the default, the candidates for "the smallest
#: setting that loses no accuracy". The costlier ones show whether the default loses any.
DEFAULT_FEATURES = ("fs8k", "nfft256", "hop320", "mels20")


@dataclass
class BenchConfig:
    out: Path = Path("results/bench")
    data: DataPlan = field(default_factory=DataPlan)
    recipe: Recipe = field(default_factory=Recipe)
    ablation_cache: Path | None = Path("results/ablation/cache")
    layout: str = DEFAULT_LAYOUT
    sizes: tuple[str, ...] = tuple(MODEL_SIZES)
    features: tuple[str, ...] = DEFAULT_FEATURES
    svm: bool = True
    n_iter: int = 300
    n_warmup: int = 30
    system: bool = True            # scene / export / node speed
    scene_seconds: float = 20.0
    export_seconds: float = 60.0
    force: bool = False

    @property
    def cache(self) -> Path:
        return Path(self.out) / "cache"


# --- selection logic (pure, tested on hand-made points) -----------------------------------

def pareto_front(points: Sequence[dict[str, Any]], x: str, y: str,
                 maximize_y: bool = False) -> list[str]:
    """Names of the points no other point beats on both ``x`` (lower) and ``y``."""
    def better(a: dict, b: dict) -> bool:  # a dominates b
        ya, yb = (-a[y], -b[y]) if maximize_y else (a[y], b[y])
        return a[x] <= b[x] and ya <= yb and (a[x] < b[x] or ya < yb)
    ok = [p for p in points if p.get(x) is not None and p.get(y) is not None]
    return [p["name"] for p in ok if not any(better(q, p) for q in ok if q is not p)]


def smallest_within(points: Sequence[dict[str, Any]], tol_deg: float = 1.0,
                    metric: str = "dir_mae_deg", size: str = "n_params") -> str | None:
    """The smallest point (fewest parameters, then lowest latency) whose ``metric`` is at
    most ``tol_deg`` above the best one's."""
    ok = [p for p in points if p.get(metric) is not None and p.get(size) is not None]
    if not ok:
        return None
    best = min(p[metric] for p in ok)
    cands = [p for p in ok if p[metric] <= best + tol_deg]
    return min(cands, key=lambda p: (p[size], p.get("latency_p50_ms") or 0.0))["name"]


def lossless_features(points: Sequence[dict[str, Any]], reference: str,
                      tol_deg: float = 1.0, tol_det_pct: float = 1.0) -> str | None:
    """The cheapest feature setting (lowest feature cost) that is no worse than
    ``reference`` by more than ``tol_deg`` direction MAE or ``tol_det_pct`` detection."""
    ref = next((p for p in points if p["name"] == reference), None)
    if ref is None or ref.get("dir_mae_deg") is None:
        return None
    ok = [p for p in points if p.get("dir_mae_deg") is not None
          and p["dir_mae_deg"] <= ref["dir_mae_deg"] + tol_deg
          and p["det_pct"] >= ref["det_pct"] - tol_det_pct]
    # Ties in input size (e.g. 8 kHz with half the FFT) go to the cheaper feature path.
    return min(ok, key=lambda p: (p["feature_cost"], p.get("features_p50_ms") or 0.0))["name"]


# --- measurement --------------------------------------------------------------------------

def _timed(fn, n_iter: int, n_warmup: int) -> np.ndarray:
    for _ in range(n_warmup):
        fn()
    t = np.empty(n_iter)
    for i in range(n_iter):
        t0 = time.perf_counter()
        fn()
        t[i] = time.perf_counter() - t0
    return t


def measure_latency(ckpt: Path, n_iter: int, n_warmup: int) -> dict[str, float]:
    """Percentiles of ``Predictor.predict`` (features + model) on one thread, and of the
    features alone. p5 is kept beside p50/p99: on a shared machine it is the closest
    reading of the uncontended cost, while p99 mostly measures the other processes."""
    import torch

    from aslip_ros.learn.inference.predictor import Predictor
    torch.set_num_threads(1)
    pred = Predictor.from_checkpoint(ckpt)
    w = (0.01 * np.random.default_rng(1).standard_normal(
        (pred.window_samples, pred.n_channels))).astype(np.float32)
    t = _timed(lambda: pred.predict(w), n_iter, n_warmup) * 1e3
    f = _timed(lambda: pred.logmel(w[None]), n_iter, n_warmup) * 1e3
    return {"latency_p5_ms": float(np.percentile(t, 5)),
            "latency_p50_ms": float(np.percentile(t, 50)),
            "latency_p99_ms": float(np.percentile(t, 99)), "latency_mean_ms": float(t.mean()),
            "features_p50_ms": float(np.percentile(f, 50)),
            "features_p99_ms": float(np.percentile(f, 99))}


def count_params(ckpt: Path) -> int:
    from aslip_ros.learn.checkpoint import load_checkpoint
    c = load_checkpoint(ckpt)
    # Buffers (normalisation, batch-norm statistics) are not parameters; SVM: support
    # vectors times features plus the dual coefficients.
    return int(sum(v.numel() for k, v in c.tensors.items()
                   if not any(s in k for s in ("running_", "num_batches", "feat_mean",
                                               "feat_std"))))


def feature_cost(fcfg: dict[str, Any], window_s: float) -> float:
    """Input size the network sees per channel (mel bins x frames): what the CNN's cost
    scales with, and a fair size order for feature settings."""
    from aslip_ros.learn.features import FeatureConfig
    f = FeatureConfig.from_dict(fcfg)
    return float(f.n_mels * f.n_frames(window_s))


def system_speed(cfg: BenchConfig, log: Log,
                 checkpoint: Path | None = None) -> dict[str, Any]:
    """Scene generation and export speed, and the node latency hook."""
    out: dict[str, Any] = {}
    try:
        from aslip_ros.scene.bench import measure
        log(f"scene generation speed ({cfg.scene_seconds:g} s of 4-mic audio)")
        speed = measure(cfg.scene_seconds, trace_memory=False)
        mem = measure(min(cfg.scene_seconds, 10.0), trace_memory=True)
        out["scene_generation"] = {
            "x_real_time_cpu": round(speed["x_real_time"], 1),
            "x_real_time_wall": round(speed["x_real_time_wall"], 1),
            "peak_traced_mib": round(mem["peak_mib"], 1), "sim_s": speed["sim_s"],
            "source": "aslip_ros.scene.bench.measure (external_induced, robot_moving, 4mic)"}
    except Exception as exc:  # report it, do not abort the benchmark
        out["scene_generation"] = {"error": f"{type(exc).__name__}: {exc}"}
    try:
        from aslip_ros.data.export import measure_export_speed
        log(f"export speed ({cfg.export_seconds:g} s synthetic bag)")
        out["export"] = measure_export_speed(cfg.export_seconds)
        out["export"]["source"] = "aslip_ros.data.export.measure_export_speed"
    except Exception as exc:
        out["export"] = {"error": f"{type(exc).__name__}: {exc}"}
    log("node latency")
    out["node_latency"] = node_latency(checkpoint)
    return out


def node_latency(checkpoint: Path | None = None) -> dict[str, Any]:
    """The node benchmarks of :mod:`benchmarks.node_bench` (slip_inference latency, the
    audio_capture stream). They need rclpy and the colcon build sourced, as ``make bench``
    does; without them, or when they fail, the result says why and holds no number."""
    if checkpoint is None:
        return {"error": "no CNN checkpoint to measure the inference node with"}
    try:
        from benchmarks import node_bench
    except ImportError as exc:  # rclpy or the generated messages are missing
        return {"error": f"node benchmark unavailable: {exc}"}
    try:
        return {"source": "benchmarks.node_bench.measure", "checkpoint": str(checkpoint),
                "result": node_bench.measure(checkpoint=str(checkpoint))}
    except Exception as exc:  # noqa: BLE001 - report it beside the other figures
        return {"source": "benchmarks.node_bench.measure",
                "error": f"{type(exc).__name__}: {exc}"}


# --- the benchmark ------------------------------------------------------------------------

class Bench:
    def __init__(self, cfg: BenchConfig, log: Log | None = None) -> None:
        self.cfg = cfg
        self.log = log or Log("bench")
        cfg.data.log = self.log
        self._retrained: set[Path] = set()    # --force retrains each checkpoint once a run

    def _reuse(self, name: str, stage: str) -> Path | None:
        """The ablation's checkpoint ``name`` when it exists and has this run's recipe."""
        from aslip_ros.learn.checkpoint import load_checkpoint
        c = self.cfg.ablation_cache
        p = Path(c) / f"{name}.pt" if c else None
        if p is None or not p.is_file() or self.cfg.force:
            return None
        old = load_checkpoint(p).meta.get("train_config", {})
        if recipe_changes(old, self.cfg.recipe.train_config(stage).to_dict()):
            self.log(f"not reusing {p}: trained with another recipe")
            return None
        return p

    def _train(self, name: str, dataset: Path, stage: str, **kw: Any) -> Path:
        return train_named(self.cfg.cache, name, dataset, stage, self.cfg.recipe,
                           force=self.cfg.force, trained=self._retrained, log=self.log,
                           **kw)[0]

    def two_stage(self, name: str, model_options: dict | None = None,
                  feature_config=None) -> Path:
        lay = self.cfg.layout
        pre = self._reuse(f"pre_{lay}_w200", "pretrain") if name == "cnn_default" else None
        ft = self._reuse(f"ft_{lay}_w200", "finetune") if name == "cnn_default" else None
        if ft is not None:
            return ft
        pre = pre or self._train(f"pre_{name}", self.cfg.data.dataset(lay, "pretrain"),
                                 "pretrain", model_options=model_options,
                                 feature_config=feature_config)
        return self._train(f"ft_{name}", self.cfg.data.dataset(lay, "finetune"), "finetune",
                           init=pre)

    def point(self, name: str, method: str, ckpt: Path, sweep: str,
              params: dict[str, Any]) -> dict[str, Any]:
        from aslip_ros.learn.checkpoint import load_checkpoint
        ds = self.cfg.data.dataset(self.cfg.layout, "finetune")
        res = evaluate_cached(ckpt, ds, "test", split_seed=self.cfg.recipe.split_seed)
        lat = measure_latency(ckpt, self.cfg.n_iter, self.cfg.n_warmup)
        meta = load_checkpoint(ckpt).meta
        p = {"name": name, "method": method, "sweep": sweep, "params": params,
             "checkpoint": str(ckpt), "n_params": count_params(ckpt),
             "feature_config": meta["feature_config"],
             "feature_cost": feature_cost(meta["feature_config"], float(meta["window_s"])),
             **{k: round(v, 4) for k, v in lat.items()}, **paper_units(res["overall"])}
        self.log(f"  {name}: p50 {p['latency_p50_ms']:.2f} ms, p99 "
                 f"{p['latency_p99_ms']:.2f} ms, det {fmt_num(p['det_pct'])} %, dir "
                 f"{fmt_num(p['dir_mae_deg'])} deg")
        return p

    def run(self) -> dict[str, Any]:
        from aslip_ros.learn.features import FeatureConfig
        cfg = self.cfg
        t0 = time.perf_counter()
        points: list[dict[str, Any]] = []
        # Sweep points first; the default model and the SVM last, since they usually come
        # from the ablation's cache, which a concurrent ``make ablation`` may still be filling.
        sizes = sorted(cfg.sizes, key=lambda n: n == "cnn_default")
        for name in sizes:
            self.log(f"model size {name} {MODEL_SIZES[name]}")
            ckpt = self.two_stage(name, model_options=dict(MODEL_SIZES[name]))
            points.append(self.point(name, "cnn", ckpt, "size", MODEL_SIZES[name]))
        for name in cfg.features:
            self.log(f"features {name} {FEATURE_SWEEP[name]}")
            fcfg = FeatureConfig(**FEATURE_SWEEP[name])
            ckpt = self.two_stage(f"feat_{name}", feature_config=fcfg)
            points.append(self.point(f"feat_{name}", "cnn", ckpt, "features",
                                     FEATURE_SWEEP[name]))
        if cfg.svm:
            self.log("SVM")
            ckpt = self._reuse(f"svm_{cfg.layout}_w200", "svm") or self._train(
                "svm", cfg.data.dataset(cfg.layout, "finetune"), "svm")
            points.append(self.point("svm", "svm", ckpt, "method", {}))
        order = {"method": 0, "size": 1, "features": 2}
        points.sort(key=lambda p: order[p["sweep"]])
        default_pt = next((p for p in points if p["name"] == "cnn_default"), None)
        cnn_sizes = [p for p in points if p["sweep"] == "size"]
        feats = [p for p in points if p["sweep"] == "features"]
        if default_pt is not None:
            feats = [dict(default_pt, name="feat_default")] + feats
        result = {
            "points": points,
            "smallest_within_1deg": smallest_within(cnn_sizes, 1.0),
            "best_dir_mae_deg": min((p["dir_mae_deg"] for p in cnn_sizes
                                     if p["dir_mae_deg"] is not None), default=None),
            "pareto_latency_dir": pareto_front(points, "latency_p99_ms", "dir_mae_deg"),
            "pareto_latency_det": pareto_front(points, "latency_p99_ms", "det_pct",
                                               maximize_y=True),
            "feature_sweep": {"reference": "feat_default", "tolerance": {"dir_deg": 1.0,
                                                                         "det_pct": 1.0},
                              "cheapest_lossless": lossless_features(feats, "feat_default")
                              if default_pt else None},
            "target_p99_ms": 3.0,
            "threads": 1,
            "load_average": list(os.getloadavg()),
            "cpu_count": os.cpu_count(),
        }
        self.log("plotting")
        write_json(cfg.out / "pareto.json", result)
        plot_pareto(result, cfg.out / "pareto.png")
        bench = {"pareto": "pareto.json", "methods": points,
                 "smallest_within_1deg": result["smallest_within_1deg"],
                 "feature_sweep": result["feature_sweep"]}
        if cfg.system:
            cnn = default_pt or next((p for p in points if p["method"] == "cnn"), None)
            bench["system"] = system_speed(cfg, self.log,
                                           Path(cnn["checkpoint"]) if cnn else None)
        bench["elapsed_s"] = round(time.perf_counter() - t0, 1)
        bench["load_average"] = list(os.getloadavg())
        write_json(cfg.out / "bench.json", bench)
        write_text(cfg.out / "bench.md", bench_markdown(result, bench))
        self.log(f"wrote {cfg.out} ({bench['elapsed_s'] / 60:.1f} min)")
        return bench


# --- CLI ----------------------------------------------------------------------------------

def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("results/bench"))
    p.add_argument("--data", type=Path, default=Path("data"))
    p.add_argument("--scale", default="default", choices=["tiny", "default", "paper"])
    p.add_argument("--preset-finetune", action="store_true",
                   help="use the preset's finetuning set instead of the ablation's larger one")
    p.add_argument("--ablation-cache", type=Path, default=Path("results/ablation/cache"),
                   help="reuse the ablation's checkpoints from here ('' to never)")
    p.add_argument("--sizes", default=",".join(MODEL_SIZES),
                   help="comma-separated model sizes")
    p.add_argument("--features", default=",".join(DEFAULT_FEATURES),
                   help=f"comma-separated feature settings ('' for none) of "
                        f"{list(FEATURE_SWEEP)}")
    p.add_argument("--no-svm", action="store_true")
    p.add_argument("--no-system", action="store_true",
                   help="skip scene, export and node speed")
    p.add_argument("--iters", type=int, default=300, help="timed windows per method")
    add_plan_arguments(p, "tiny scale, 2 sizes, 1 feature")


def config_from_args(args: argparse.Namespace) -> BenchConfig:
    quick = args.quick
    data, recipe = plan_from_args(args)
    sizes = tuple(x for x in args.sizes.split(",") if x)
    feats = tuple(x for x in args.features.split(",") if x)
    if quick:
        sizes, feats = ("cnn_xs", "cnn_default"), ("mels20",)
    bad = (set(sizes) - set(MODEL_SIZES)) | (set(feats) - set(FEATURE_SWEEP))
    if bad:
        raise ValueError(f"unknown sweep points {sorted(bad)}")
    cache = args.ablation_cache if str(args.ablation_cache) else None
    return BenchConfig(out=args.out, data=data, recipe=recipe, ablation_cache=cache,
                       sizes=sizes, features=feats, svm=not args.no_svm,
                       n_iter=50 if quick else args.iters, n_warmup=10 if quick else 30,
                       system=not args.no_system, scene_seconds=2.0 if quick else 20.0,
                       export_seconds=5.0 if quick else 60.0, force=args.force)


def run(args: argparse.Namespace) -> int:
    cfg = configured("bench", args, config_from_args)
    if cfg is None:
        return 2
    Bench(cfg).run()
    print((cfg.out / "bench.md").read_text())
    return 0


if __name__ == "__main__":
    from benchmarks.cli import main
    sys.exit(main("bench"))
