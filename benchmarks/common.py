"""Shared plumbing of the experiment pipelines: datasets, cached training, evaluation, tables.

Everything expensive is cached on disk and keyed by path, so an interrupted ``make ablation``
resumes where it stopped: a checkpoint is retrained only when it is missing (or ``force``),
and metrics are recomputed only when older than their checkpoint.

Datasets come from the scene (``scene.presets.build_default_datasets`` for the 200 ms
sets, ``data.export.export`` of the same bags for other window lengths). ``synthetic=True``
swaps them for ``learn.synthetic`` datasets with the scene's channel names: seconds instead
of minutes, for the pipelines' own tests only (it says nothing about the scene).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from aslip_ros.util import read_json, write_json

STAGES = ("pretrain", "finetune")
#: Finetuning-set size of the experiments (trials per object and condition, 10 s each): 50
#: trials, 7 of them in the test split with every object represented. The default preset
#: (3 / 1 / 2) leaves two of the five objects without a test trial.
EXTERNAL_TRIALS = {"robot_stationary": 5, "robot_moving": 2, "robot_off": 3}


class Log:
    """Progress lines with the elapsed time, to stderr (stdout stays for results)."""

    def __init__(self, prefix: str = "", stream=None) -> None:
        self.t0 = time.perf_counter()
        self.prefix = prefix
        self.stream = stream or sys.stderr

    def __call__(self, msg: str) -> None:
        dt = time.perf_counter() - self.t0
        print(f"[{self.prefix} {dt / 60:6.1f} min] {msg}", file=self.stream, flush=True)


# --- datasets -----------------------------------------------------------------------------

def scene_cache(root: Path) -> Path:
    """Where a benchmark keeps what it simulated, exported and trained under ``root``: one
    directory per scene version and label setting (``scene-v4-labels150ms``), so a scene
    whose defaults changed or an export that labels otherwise starts afresh, never mixing
    old models with new datasets."""
    from aslip_ros.data.labels import DEFAULT_LABEL_SMOOTHING_S
    from aslip_ros.scene.physics import SCENE_VERSION
    ms = round(DEFAULT_LABEL_SMOOTHING_S * 1e3)
    return Path(root) / (f"scene-v{SCENE_VERSION}" + (f"-labels{ms}ms" if ms else ""))


@dataclass
class DataPlan:
    """Where the datasets of an experiment live and how to build the missing ones.

    ``root`` is the data directory (``data/``, git-ignored). The default scale uses exactly
    the paths of ``make datasets`` so the two share their work; other scales get a
    sub-directory of their own.
    """

    root: Path = Path("data")
    scale: str = "default"
    synthetic: bool = False
    hop_s: float = 0.1
    progress: bool = True
    #: Externally induced trials per object and condition for the finetuning sets. ``None``
    #: takes the preset's own finetuning set; a dict builds a larger one of this package's
    #: (the default preset leaves some objects without a test trial).
    external: dict[str, int] | None = None
    duration_s: float = 10.0
    synthetic_s: float = 3.0           # seconds per synthetic trial (tests: shorter)
    log: Callable[[str], None] = field(default=lambda m: print(m, file=sys.stderr))

    @property
    def base(self) -> Path:
        if self.synthetic:
            return Path(self.root) / "synthetic"
        return Path(self.root) if self.scale == "default" else Path(self.root) / self.scale

    def _own(self, stage: str) -> bool:
        return stage == "finetune" and self.external is not None and not self.synthetic

    def bags(self, layout: str, stage: str) -> Path:
        if self._own(stage):
            return self.base / "experiments" / "bags" / layout / "external"
        kind = "robot" if stage == "pretrain" else "external"
        return self.base / "bags" / layout / kind

    def path(self, layout: str, stage: str, window_ms: int = 200) -> Path:
        name = layout if window_ms == 200 else f"{layout}_w{window_ms}"
        if self._own(stage):
            return self.base / "experiments" / "datasets" / name / stage
        return self.base / "datasets" / name / stage

    def dataset(self, layout: str, stage: str, window_ms: int = 200) -> Path:
        """Path of the dataset, building it (and its bags) first when missing."""
        if stage not in STAGES:
            raise ValueError(f"stage must be one of {STAGES}, got {stage!r}")
        out = self.path(layout, stage, window_ms)
        if (out / "manifest.json").is_file():
            return out if self.synthetic else self._relabelled(layout, stage, out)
        if self.synthetic:
            return self._synthetic(layout, stage, window_ms, out)
        if self._own(stage):
            return self._own_finetune(layout, window_ms, out)
        base200 = self.path(layout, stage, 200)
        if not (base200 / "manifest.json").is_file():
            from aslip_ros.scene.presets import build_default_datasets
            self.log(f"building the {self.scale} datasets for {layout} (simulate + export)")
            build_default_datasets(self.base, self.scale, layouts=(layout,),
                                   progress=self.progress)
        if window_ms != 200:
            from aslip_ros.data.export import ExportConfig, export
            self.log(f"exporting {layout}/{stage} with {window_ms} ms windows")
            export([self.bags(layout, stage)], out,
                   ExportConfig(window_s=window_ms / 1000.0, hop_s=self.hop_s,
                                progress=self.progress))
        return out

    def _relabelled(self, layout: str, stage: str, out: Path) -> Path:
        """A kept scene dataset, exported again from its bags (its own windows, hop and
        label rule) where its labels were read with another pose smoothing than the
        export's now (one from before the smoothing has raw-pose labels and no field)."""
        from aslip_ros.data.export import ExportConfig, export, labelled_as
        from aslip_ros.data.labels import DEFAULT_LABEL_SMOOTHING_S
        if labelled_as(out, ExportConfig()):
            return out
        man = read_json(out / "manifest.json")
        was = man.get("label_smoothing_s", 0.0)
        bags = self.bags(layout, stage)
        if not bags.is_dir():
            self.log(f"{out}: labels from poses smoothed over {was} s, not the export's "
                     f"{DEFAULT_LABEL_SMOOTHING_S} s, and no bags at {bags} to export "
                     "again: kept as it is (delete it to rebuild)")
            return out
        self.log(f"exporting {out} again: its labels were read from poses smoothed over "
                 f"{was} s, the export's are now {DEFAULT_LABEL_SMOOTHING_S} s")
        kept = ("window_s", "hop_s", "epsilon_m_s", "max_gap_s", "label_source")
        export([bags], out, ExportConfig(**{k: man[k] for k in kept if k in man},
                                         overwrite=True, progress=self.progress))
        return out

    def _own_finetune(self, layout: str, window_ms: int, out: Path) -> Path:
        from aslip_ros.data.export import ExportConfig, export
        from aslip_ros.scene.presets import PAPER_OBJECTS
        from aslip_ros.scene.simulate import simulate
        bags = self.bags(layout, "finetune")
        self.log(f"simulating the finetuning bags of {layout} ({self.external} per object)")
        for cond, n in self.external.items():
            # simulate() keeps existing bags, so this resumes and costs nothing when done.
            simulate(bags, "external", objects=list(PAPER_OBJECTS), conditions=[cond],
                     trials=n, duration_s=self.duration_s, layout=layout, pad="textured",
                     progress=self.progress)
        self.log(f"exporting {out} ({window_ms} ms windows)")
        export([bags], out, ExportConfig(window_s=window_ms / 1000.0, hop_s=self.hop_s,
                                         progress=self.progress))
        return out

    def _synthetic(self, layout: str, stage: str, window_ms: int, out: Path) -> Path:
        from aslip_ros.learn.synthetic import make_synthetic_dataset
        from aslip_ros.scene.layouts import get_layout
        names = get_layout(layout).channel_names
        robot = stage == "pretrain"
        return make_synthetic_dataset(
            out, n_trials=8 if robot else 12, duration_s=self.synthetic_s, sample_rate=16000.0,
            channel_names=names, window_s=window_ms / 1000.0, hop_s=self.hop_s,
            objects=("pla_rod",) if robot else ("pla_rod", "chips_can"),
            induced="robot" if robot else "external", layout=layout,
            seed=(7 if robot else 11) + len(names))


# --- cached training and evaluation -------------------------------------------------------

@dataclass
class Recipe:
    """Training budget shared by the rows of an experiment (the recipe itself is learn's)."""

    epochs: int = 300
    patience: int = 30
    time_budget_s: float = 1140.0
    finetune_epochs: int | None = None   # None: same as epochs
    finetune_time_budget_s: float | None = None  # None: same as time_budget_s
    threads: int = 2
    seed: int = 0
    split_seed: int = 0
    progress: bool = True
    svm_max_train: int = 4000
    #: No-slip windows drawn per slip window each epoch. learn's default (1.0) balances the
    #: classes, which calibrates p(slip) for a 50 % prior; the externally induced sets hold
    #: about 4 no-slip windows per slip window, and at the paper's fixed 0.5 threshold the
    #: balanced model fires on many no-slip windows (validation precision ~0.5). 3.0 keeps
    #: the "subsample" of the paper while staying near the data's own prior.
    noslip_ratio: float = 3.0

    def train_config(self, stage: str, **kw: Any):
        from aslip_ros.learn.training.config import TrainConfig
        epochs, budget = self.epochs, self.time_budget_s
        if stage == "finetune":
            # Heads only: fewer parameters to fit, so a smaller budget is enough.
            epochs = self.finetune_epochs or epochs
            budget = self.finetune_time_budget_s or budget
        return TrainConfig(stage=stage, epochs=epochs, patience=self.patience,
                           time_budget_s=budget, threads=self.threads,
                           seed=kw.pop("seed", self.seed), split_seed=self.split_seed,
                           progress=self.progress, noslip_ratio=self.noslip_ratio, **kw)


def train_cached(ckpt: Path, dataset: Path, stage: str, recipe: Recipe, *,
                 init: Path | None = None, channels: Sequence[str] | None = None,
                 objects: Sequence[str] | None = None,
                 model_options: dict[str, Any] | None = None, feature_config=None,
                 seed: int | None = None, force: bool = False,
                 trained: set[Path] | None = None,
                 log: Callable[[str], None] = print) -> dict[str, Any]:
    """Train one model unless its checkpoint exists; returns its training summary.

    ``trained``, a runner's set of checkpoints it has (re)trained, makes ``force`` retrain
    each checkpoint once per run rather than every time a row asks for it (rows share their
    pretrained encoders); the set is updated here.

    The summary (time, epochs, stop reason, validation metrics) is read back from the
    checkpoint's provenance, so a cached row reports the numbers of the run that made it.
    """
    from aslip_ros.learn.checkpoint import load_checkpoint
    from aslip_ros.learn.data_io import open_dataset
    from aslip_ros.learn.models.aslip_cnn_fit import train_cnn
    from aslip_ros.learn.training.train import train_svm

    ckpt = Path(ckpt)
    kw: dict[str, Any] = {}
    if objects:
        kw["objects"] = tuple(objects)
    if seed is not None:
        kw["seed"] = seed
    cfg = recipe.train_config(stage, **kw)
    ds = open_dataset(dataset)
    if ckpt.is_file() and (not force or (trained is not None and ckpt.resolve() in trained)):
        meta = load_checkpoint(ckpt).meta
        changed = recipe_changes(meta.get("train_config", {}), cfg.to_dict())
        if meta.get("provenance", {}).get("dataset_fingerprint") != ds.fingerprint():
            changed.append("its dataset, exported again since")
        if not changed:
            return _train_summary(meta, cached=True)
        log(f"cached {ckpt.name} was trained with another recipe ({', '.join(changed)}); "
            "retraining")
    t0 = time.perf_counter()
    if stage == "svm":
        from aslip_ros.learn.models.svm import SvmConfig
        res = train_svm(ds, cfg, feature_config=feature_config, channels=channels,
                        svm_config=SvmConfig(max_train=recipe.svm_max_train), log=log)
    else:
        res = train_cnn(ds, cfg, feature_config=feature_config, model_options=model_options,
                        channels=channels, init=init, log=log)
    wall = time.perf_counter() - t0
    res.meta["provenance"].setdefault("training", {})["wall_s_incl_features"] = wall
    ckpt.parent.mkdir(parents=True, exist_ok=True)
    res.save(ckpt)
    if trained is not None:
        trained.add(ckpt.resolve())
    if res.history:
        write_json(ckpt.with_suffix(".history.json"), res.history)
    return _train_summary(res.meta, cached=False)


def train_named(cache: Path, name: str, dataset: Path, stage: str, recipe: Recipe, *,
                force: bool, trained: set[Path], log: Callable[[str], None],
                **kw: Any) -> tuple[Path, dict[str, Any]]:
    """``train_cached`` for an experiment runner: checkpoint ``<cache>/<name>.pt``, progress
    lines through ``log``, ``force`` once per run through the runner's ``trained`` set."""
    ckpt = Path(cache) / f"{name}.pt"
    if not ckpt.is_file() or (force and ckpt.resolve() not in trained):
        log(f"train {name} ({stage}) on {dataset}")
    info = train_cached(ckpt, dataset, stage, recipe, force=force, trained=trained,
                        log=lambda m: log(f"  {name}: {m}"), **kw)
    if not info["cached"]:
        log(f"  {name}: done in {info['wall_s_incl_features']:.0f} s "
            f"({info['epochs_run']} epochs, {info['stop_reason']})")
    return ckpt, info


#: TrainConfig fields that do not change what a training run produces.
_RECIPE_IGNORED = ("threads", "progress")


def recipe_changes(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """Names of the recipe fields in which a cached checkpoint's train_config differs."""
    return sorted(k for k in new if k not in _RECIPE_IGNORED and old.get(k) != new[k])


def _train_summary(meta: dict[str, Any], cached: bool) -> dict[str, Any]:
    prov = meta.get("provenance", {})
    tr = prov.get("training", {})
    return {"cached": cached, "stage": prov.get("stage"), "seed": prov.get("seed"),
            "train_time_s": tr.get("train_time_s"),
            "wall_s_incl_features": tr.get("wall_s_incl_features"),
            "epochs_run": tr.get("epochs_run"), "best_epoch": tr.get("best_epoch"),
            "stop_reason": tr.get("stop_reason"),
            "n_train_windows": tr.get("n_train_windows"),
            "val": prov.get("metrics", {}).get("val")}


def evaluate_cached(ckpt: Path, dataset: Path, name: str, *, split: str = "test",
                    objects: Sequence[str] | None = None, split_seed: int = 0,
                    force: bool = False) -> dict[str, Any]:
    """``learn.evaluate.evaluate_checkpoint`` with its result stored beside the checkpoint."""
    from aslip_ros.learn.evaluate import evaluate_checkpoint

    ckpt = Path(ckpt)
    out = ckpt.with_name(f"{ckpt.stem}.eval-{name}.json")
    # Kept while newer than both the checkpoint and the dataset's last export.
    made = max(ckpt.stat().st_mtime, (Path(dataset) / "manifest.json").stat().st_mtime)
    if out.is_file() and not force and out.stat().st_mtime >= made:
        return read_json(out)
    res = evaluate_checkpoint(ckpt, dataset, split, objects=objects, split_seed=split_seed)
    write_json(out, res)
    return res


# --- reporting ----------------------------------------------------------------------------

def paper_units(m: dict[str, Any] | None) -> dict[str, Any]:
    """The paper's columns from ``compute_metrics`` output (percent, degrees, millimetres)."""
    if not m:
        return {}

    def g(k: str, scale: float = 1.0) -> float | None:
        v = m.get(k)
        return None if v is None or not np.isfinite(v) else round(float(v) * scale, 3)
    return {"det_pct": g("detection_accuracy", 100.0), "dir_mae_deg": g("direction_mae_deg"),
            "dir_std_deg": g("direction_std_deg"), "mag_rmse_mm": g("magnitude_rmse_mm"),
            "mag_std_mm": g("magnitude_std_mm"), "n_windows": m.get("n_windows"),
            "n_slip": m.get("n_slip")}


def fmt_pm(mean: float | None, std: float | None, nd: int = 1) -> str:
    if mean is None:
        return "–"
    if std is None:
        return f"{mean:.{nd}f}"
    return f"{mean:.{nd}f} ± {std:.{nd}f}"


def fmt_num(v: float | None, nd: int = 1) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def configured(name: str, args: Any, config_from_args: Any) -> Any:
    """A study's config from its command line, with its torch threads set; None (after one
    error line naming ``benchmarks.<name>``) when the arguments are refused."""
    try:
        cfg = config_from_args(args)
    except ValueError as exc:
        print(f"benchmarks.{name}: error: {exc}", file=sys.stderr)
        return None
    set_threads(cfg.recipe.threads)
    return cfg


def set_threads(n: int) -> None:
    """torch threads (and BLAS through the environment for child processes)."""
    import torch
    torch.set_num_threads(max(1, int(n)))
    os.environ.setdefault("OMP_NUM_THREADS", str(n))


def dump(obj: Any) -> str:
    return json.dumps(obj, indent=2)


def add_plan_arguments(p: argparse.ArgumentParser, quick_help: str) -> None:
    """The training-recipe and run-control arguments that bench and stability share."""
    p.add_argument("--epochs", type=int, default=300)
    p.add_argument("--patience", type=int, default=30,
                   help="early-stopping epochs (an epoch is only a few dozen batches)")
    p.add_argument("--time-budget", type=float, default=300.0)
    p.add_argument("--finetune-time-budget", type=float, default=240.0,
                   help="seconds of training per finetuning (heads only)")
    p.add_argument("--noslip-ratio", type=float, default=3.0,
                   help="no-slip windows per slip window drawn each epoch")
    p.add_argument("--threads", type=int, default=2, help="training threads")
    p.add_argument("--quick", action="store_true", help=quick_help)
    p.add_argument("--force", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--synthetic", action="store_true", help=argparse.SUPPRESS)


def plan_from_args(args: argparse.Namespace, **recipe: Any) -> tuple[DataPlan, Recipe]:
    """DataPlan and Recipe from the arguments of ``add_plan_arguments`` (plus ``--data``,
    ``--scale`` and ``--preset-finetune``); ``recipe`` overrides Recipe fields."""
    progress = not args.no_progress
    quick = args.quick
    external = None if (args.preset_finetune or quick or args.synthetic) \
        else dict(EXTERNAL_TRIALS)
    data = DataPlan(root=args.data, scale="tiny" if quick else args.scale,
                    synthetic=args.synthetic, progress=progress, external=external)
    rec = Recipe(epochs=2 if quick else args.epochs, patience=args.patience,
                 time_budget_s=args.time_budget,
                 finetune_time_budget_s=args.finetune_time_budget,
                 noslip_ratio=args.noslip_ratio, threads=args.threads, progress=progress,
                 **recipe)
    return data, rec
