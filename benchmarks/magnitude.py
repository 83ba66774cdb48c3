"""Why the package CNN's magnitude and detection trail a plain CNN: one candidate at a time.

Each *variant* trains the package CNN (``learn.models.aslip_cnn_fit.train_cnn``, stage
``scratch``, no per-grasp calibration, the same seed and split) with exactly one candidate
cause changed from the package recipe (``recipe``): the no-slip reweighting, the
augmentation, the Huber scale, the loss weights, early stopping. The plain CNN and the
plain SVM of ``learn.baselines`` are trained on the same training windows. Every model is
then scored on a *held-out scene*: all trials of another exported dataset that no model saw
(a user's recording; at least 20 trials), with 95 % trial-bootstrap intervals, and each
variant's difference from ``recipe`` with a paired trial bootstrap (same resamples for
both; an interval that excludes 0 is a measured effect).

A *cell* ``TRAIN:TEST`` names two datasets under ``--data`` (default: where ``make transfer``
exports the scenes of the current scene version): ``default:mocap`` trains on the
default scene and tests on the motion-capture variant (100 Hz labels with dropouts, noise
and latency), ``mocap:coupling`` trains on motion-capture labels and tests on per-grasp
coupling. Trained models and per-window predictions are cached under ``--out/cache``
(git-ignored), so a run resumes and a variant is trained once.

Each cell's report ends with *where the speed error is* (``benchmarks.magnitude_where``):
every model's slip-speed RMSE and bias by object, by true-speed tercile and by trial-loudness
tercile, its overall scale and the RMSE at an oracle (test-fitted) scale, so that one sees
where the package CNN loses to the direct SVR.

    python -m benchmarks.magnitude --out results/magnitude        (make magnitude)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from aslip_ros.learn.models.per_output import blend, combine, role_outputs
from aslip_ros.util import write_json, write_text

from .common import scene_cache
from .magnitude_where import cell_breakdown, where_markdown
from .transfer import KEYS, format_ci, metrics_cell

#: name -> (what changes, TrainConfig overrides, LossWeights overrides). ``recipe`` is the
#: package default every other row is compared with.
VARIANTS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "recipe": ("package recipe (balanced epochs, random gain, Huber 1) with the paper's "
               "loss weights (magnitude 0.5)", {}, {}),
    "natural_prior": ("every no-slip window each epoch (no class rebalancing)",
                      {"noslip_ratio": 1000.0}, {}),
    "no_gain": ("no random gain augmentation (whole-window and per-microphone)",
                {"gain_db": 0.0, "channel_gain_db": 0.0}, {}),
    "specaugment": ("SpecAugment frequency (n_mels // 8) and time (3 frames) masks, the "
                    "default until this study", {"freq_mask": -1, "time_mask": 3}, {}),
    "huber_0.25": ("Huber delta 0.25 speed scales (L1-like beyond a quarter of it)",
                   {}, {"huber_delta": 0.25}),
    "mag_x4": ("magnitude weight 2.0 instead of the paper's 0.5", {}, {"mag": 2.0}),
    "patience_5": ("early stopping after 5 epochs without a better validation loss",
                   {"patience": 5}, {}),
}
#: Every variant's loss weights unless it changes them: the paper's (the package's at the time).
REFERENCE_WEIGHTS = {"slip": 1.0, "mag": 0.5, "dir": 2.0, "smooth": 0.1}
BASELINES = ("plain_cnn", "plain_svm")
#: Models that are the mean of two of the above, as ``aslip train``'s per-output choice can
#: write them (a ``per_output`` blend, learn/models/per_output.py): scored from the parts'
#: predictions, nothing trained. A blend is reported where both its parts ran.
BLENDS = (("recipe", "plain_svm"),)
#: The by-trial split of the training scene (train / validation for early stopping); fixed
#: so that training seeds change only the training run.
SPLIT_SEED = 0
#: TrainConfig fields that do not change what a training run produces.
_IGNORED = ("threads", "progress")


def default_data() -> Path:
    """Where ``make transfer`` exports the scenes of the current scene version."""
    return scene_cache(Path("data/transfer")) / "datasets"


@dataclass
class MagnitudeConfig:
    out: Path = Path("results/magnitude")
    data: Path = field(default_factory=lambda: default_data())
    cells: tuple[tuple[str, str], ...] = (("default", "mocap"), ("mocap", "coupling"))
    variants: tuple[str, ...] = tuple(VARIANTS)
    baselines: tuple[str, ...] = BASELINES
    #: The package CNN's epoch cap. The recipe's own (300, patience 30) runs ~140 epochs on
    #: these sets; 60 (about 60 000 training windows, the plain CNN's 25 epochs see about
    #: 50 000) keeps a variant to a minute of CPU (``--epochs 300`` for the full budget).
    epochs: int = 60
    patience: int = 30
    time_budget_s: float = 600.0   # a wall-clock cap that only a loaded machine reaches
    plain_epochs: int = 25
    threads: int = 1
    seeds: tuple[int, ...] = (0,)   # training seeds; the split is always seed 0's
    n_boot: int = 500
    min_test_trials: int = 20
    progress: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def cache(self) -> Path:
        return Path(self.out) / "cache"


def _train_config(cfg: MagnitudeConfig, variant: str, seed: int, neg_per_pos: float):
    """The variant's TrainConfig. A variant that draws more no-slip windows per epoch gets
    proportionally fewer epochs (and patience), so that every variant takes about the same
    number of optimiser steps: otherwise it would also be a longer training."""
    from aslip_ros.learn.training.config import TrainConfig
    base = TrainConfig(stage="scratch", epochs=cfg.epochs, patience=cfg.patience,
                       time_budget_s=cfg.time_budget_s, threads=cfg.threads, seed=seed,
                       split_seed=SPLIT_SEED,
                       progress=cfg.progress, calibration="off")
    over = dict(VARIANTS[variant][1])
    if "noslip_ratio" in over:
        per_epoch = (1.0 + min(over["noslip_ratio"], neg_per_pos)) / \
            (1.0 + min(base.noslip_ratio, neg_per_pos))
        over.setdefault("epochs", max(1, round(base.epochs / per_epoch)))
        over.setdefault("patience", max(1, round(over.get("patience", base.patience)
                                                 / per_epoch)))
    return dataclasses.replace(base, **over)


def _neg_per_pos(ds) -> float:
    """No-slip windows per slip window in the training scene's training split."""
    from aslip_ros.learn.data_io import select_windows
    slip = ds.slip(select_windows(ds, "train", seed=SPLIT_SEED))
    return float((~slip).sum() / max(int(slip.sum()), 1))


def _weights(variant: str):
    from aslip_ros.learn.models.aslip_cnn_loss import LossWeights
    return LossWeights(**{**REFERENCE_WEIGHTS, **VARIANTS[variant][2]})


def _predictions(path: Path) -> dict[str, np.ndarray] | None:
    if not path.is_file():
        return None
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def _save_predictions(path: Path, p: dict[str, Any]) -> None:
    keys = ("prob", "raw_velocity", "true_velocity", "slip", "trial", "window_s")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **{k: np.asarray(p[k]) for k in keys})
    tmp.replace(path)


def predict_variant(cfg: MagnitudeConfig, variant: str, seed: int, train_ds: Path,
                    test_ds: Path, log: Callable[[str], None]
                    ) -> tuple[dict[str, np.ndarray], dict]:
    """Train (or reuse) the package CNN of ``variant``; its predictions on all of
    ``test_ds`` and its training summary."""
    from aslip_ros.learn.checkpoint import load_checkpoint
    from aslip_ros.learn.data_io import open_dataset
    from aslip_ros.learn.evaluate import predict_split
    from aslip_ros.learn.models.aslip_cnn_fit import train_cnn
    cache = cfg.cache / train_ds.name / f"seed{seed}"
    ckpt = cache / f"{variant}.pt"
    ds = open_dataset(train_ds)
    tc, w = _train_config(cfg, variant, seed, _neg_per_pos(ds)), _weights(variant)
    if ckpt.is_file():
        meta = load_checkpoint(ckpt).meta
        old = {k: v for k, v in meta.get("train_config", {}).items() if k not in _IGNORED}
        new = {k: v for k, v in tc.to_dict().items() if k not in _IGNORED}
        if old != new or meta.get("loss_weights") != w.to_dict():
            log(f"  {variant}: cached checkpoint has another recipe; retraining")
            ckpt.unlink()
    if not ckpt.is_file():
        t0 = time.perf_counter()
        res = train_cnn(ds, tc, weights=w, log=log)
        cache.mkdir(parents=True, exist_ok=True)
        res.save(ckpt)
        log(f"  {variant}: trained in {time.perf_counter() - t0:.0f} s")
    out = cache / f"{variant}.pred-{test_ds.name}.npz"
    pred = _predictions(out)
    if pred is None or out.stat().st_mtime < ckpt.stat().st_mtime:
        pred = predict_split(ckpt, test_ds, "all", split_seed=SPLIT_SEED)
        _save_predictions(out, pred)
        pred = _predictions(out)
    tr = load_checkpoint(ckpt).meta["provenance"]["training"]
    summary = {k: tr.get(k) for k in ("epochs_run", "best_epoch", "stop_reason",
                                      "train_time_s", "n_train_windows")}
    return pred, summary


def predict_baseline(cfg: MagnitudeConfig, kind: str, seed: int, train_ds: Path,
                     test_ds: Path, log: Callable[[str], None]
                     ) -> tuple[dict[str, np.ndarray], dict]:
    """A plain baseline trained on ``train_ds``'s training split (the package CNN's split)
    and its predictions on all of ``test_ds`` (cached)."""
    from aslip_ros.learn import baselines
    from aslip_ros.learn.data_io import open_dataset, select_windows
    from aslip_ros.learn.training.data import feature_cache
    out = cfg.cache / train_ds.name / f"seed{seed}" / \
        f"{kind}-e{cfg.plain_epochs}.pred-{test_ds.name}.npz"
    pred = _predictions(out)
    if pred is not None:
        return pred, {"cached": True}
    ds = open_dataset(train_ds)
    tr = select_windows(ds, "train", seed=SPLIT_SEED)
    x = np.asarray(feature_cache(ds, baselines.baseline_features(ds.sample_rate),
                                 ds.channel_names)[tr], dtype=np.float32)
    t0 = time.perf_counter()
    if kind == "plain_cnn":
        model = baselines.fit_plain_cnn(x, ds.velocity(tr), ds.slip(tr),
                                        epochs=cfg.plain_epochs, seed=seed)
    elif kind == "plain_svm":
        model = baselines.fit_plain_svm(x, ds.velocity(tr), ds.slip(tr), seed=seed)
    else:
        raise ValueError(f"unknown baseline {kind!r}; choose from {BASELINES}")
    log(f"  {kind}: trained in {time.perf_counter() - t0:.0f} s")
    te_ds = open_dataset(test_ds)
    te = select_windows(te_ds, "all", seed=SPLIT_SEED)
    feats = feature_cache(te_ds, baselines.baseline_features(te_ds.sample_rate),
                          te_ds.channel_names)
    prob, vel = model.predict(np.asarray(feats[te], dtype=np.float32))
    _save_predictions(out, {"prob": prob, "raw_velocity": vel,
                            "true_velocity": te_ds.velocity(te), "slip": te_ds.slip(te),
                            "trial": np.asarray(te_ds.windows["trial"][te]),
                            "window_s": te_ds.window_s})
    return _predictions(out), {"cached": False}


# --- scoring ------------------------------------------------------------------------------

def score(cfg: MagnitudeConfig, p: dict[str, np.ndarray]) -> dict[str, Any]:
    from aslip_ros.learn.stats import bootstrap_metrics
    res = bootstrap_metrics(p["trial"], p["prob"], p["raw_velocity"], p["true_velocity"],
                            p["slip"], float(p["window_s"]), n_boot=cfg.n_boot, seed=0)
    res["n_trials"] = int(np.unique(p["trial"]).size)
    return res


def paired(cfg: MagnitudeConfig, a: dict[str, np.ndarray], b: dict[str, np.ndarray]
           ) -> dict[str, tuple[float, float, float]]:
    """``a - b`` per metric over the same trial resamples (both predict the same windows)."""
    from aslip_ros.learn.metrics import compute_metrics
    from aslip_ros.learn.stats import paired_difference
    if not (np.array_equal(a["trial"], b["trial"]) and np.array_equal(a["slip"], b["slip"])):
        raise ValueError("a paired difference needs predictions of the same windows")
    w = float(a["window_s"])

    def metric(p: dict[str, np.ndarray], key: str) -> Callable[[np.ndarray], float]:
        def f(idx: np.ndarray) -> float:
            m = compute_metrics(p["prob"][idx], p["raw_velocity"][idx],
                                p["true_velocity"][idx], p["slip"][idx], w)
            return float(m.get(key, np.nan))
        return f
    out = {}
    for key, _, scale in KEYS:
        est, lo, hi = paired_difference(a["trial"], metric(a, key), metric(b, key),
                                        n_boot=cfg.n_boot, seed=0)
        out[key] = (est * scale, lo * scale, hi * scale)
    return out


def blended(preds: dict[str, dict[str, np.ndarray]], parts: tuple[str, ...]
            ) -> dict[str, np.ndarray]:
    """The predictions of the blend of ``parts`` (every output their mean, as a
    ``per_output`` model averages it) on the windows they share."""
    first = preds[parts[0]]
    if any(not np.array_equal(preds[n]["trial"], first["trial"]) for n in parts):
        raise ValueError(f"{parts}: predictions of different windows")
    outs = {n: (preds[n]["prob"], preds[n]["raw_velocity"]) for n in parts}
    prob, v, _ = combine(role_outputs(
        {r: blend(list(parts)) for r in ("detection", "speed", "direction")}, outs))
    return dict(first, prob=prob, raw_velocity=v)


def run_cell(cfg: MagnitudeConfig, train: str, test: str, seed: int,
             log: Callable[[str], None]) -> dict[str, Any]:
    """Every variant and baseline trained on ``train`` with ``seed``, scored on ``test``."""
    train_ds, test_ds = Path(cfg.data) / train, Path(cfg.data) / test
    for d in (train_ds, test_ds):
        if not (d / "manifest.json").is_file():
            raise FileNotFoundError(f"{d}: no exported dataset (make transfer exports them)")
    preds: dict[str, dict[str, np.ndarray]] = {}
    rows: dict[str, Any] = {}
    for name in cfg.variants:
        preds[name], info = predict_variant(cfg, name, seed, train_ds, test_ds, log)
        rows[name] = {"what": VARIANTS[name][0], "training": info}
    for kind in cfg.baselines:
        preds[kind], info = predict_baseline(cfg, kind, seed, train_ds, test_ds, log)
        rows[kind] = {"what": "learn.baselines", "training": info}
    for parts in BLENDS:
        if all(n in preds for n in parts):
            name = blend(list(parts))
            preds[name] = blended(preds, parts)
            rows[name] = {"what": "the mean of " + " and ".join(parts) + " (per_output blend)"}
    n_trials = int(np.unique(next(iter(preds.values()))["trial"]).size)
    if n_trials < cfg.min_test_trials:
        raise ValueError(f"{test}: {n_trials} held-out trials, fewer than "
                         f"{cfg.min_test_trials}")
    for name, p in preds.items():
        rows[name]["metrics"] = score(cfg, p)
        if name != "recipe" and "recipe" in preds:
            rows[name]["minus_recipe"] = paired(cfg, p, preds["recipe"])
        log(f"  {name}: {metrics_cell(rows[name]['metrics'])}")
    return {"train": train, "test": test, "seed": seed, "n_trials": n_trials, "rows": rows,
            "where": cell_breakdown(preds, test_ds, n_boot=cfg.n_boot)}


def verdicts(cells: dict[str, Any]) -> dict[str, dict[str, dict[str, int]]]:
    """Per variant and metric: in how many cells it is better / worse than ``recipe`` with
    the paired interval excluding 0, and in how many cells it was measured."""
    out: dict[str, dict[str, dict[str, int]]] = {}
    for e in cells.values():
        for name, r in e["rows"].items():
            for key, _, _ in KEYS:
                d = (r.get("minus_recipe") or {}).get(key)
                if d is None:
                    continue
                v = out.setdefault(name, {}).setdefault(key, {"better": 0, "worse": 0,
                                                              "cells": 0})
                v["cells"] += 1
                est, lo, hi = d
                if lo > 0 or hi < 0:
                    good = est > 0 if key == "detection_accuracy" else est < 0
                    v["better" if good else "worse"] += 1
    return out


def run(cfg: MagnitudeConfig, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Every cell and seed; ``magnitude.json`` and ``.md`` are rewritten after each cell,
    so an interrupted run leaves the cells it finished."""
    cells: dict[str, Any] = {}
    result: dict[str, Any] = {}
    for train, test in cfg.cells:
        for seed in cfg.seeds:
            log(f"cell {train} -> {test}, seed {seed}")
            cells[f"{train} -> {test}, seed {seed}"] = run_cell(cfg, train, test, seed, log)
            result = {"format": "aslip-magnitude", "version": 1,
                      "config": {k: (str(v) if isinstance(v, Path) else v)
                                 for k, v in dataclasses.asdict(cfg).items()},
                      "cells": cells, "verdicts": verdicts(cells)}
            write_json(Path(cfg.out) / "magnitude.json", result)
            write_text(Path(cfg.out) / "magnitude.md", markdown(result))
    return result


# --- report -------------------------------------------------------------------------------

def _diff(d: tuple[float, float, float] | None, key: str) -> str:
    if d is None:
        return ""
    est, lo, hi = d
    if not np.isfinite(est):
        return "n/a"
    better = est > 0 if key == "detection_accuracy" else est < 0
    sep = lo > 0 or hi < 0
    s = f"{est:+.2f} [{lo:+.2f}, {hi:+.2f}]"
    return f"**{s}**" if sep and better else f"*{s}*" if sep else s


def markdown(result: dict[str, Any]) -> str:
    c = result["config"]
    lines = ["# The package CNN against the plain baselines, one candidate cause at a time", "",
             f"Package CNN: stage scratch, calibration off, at most {c['epochs']} epochs and "
             f"{c['time_budget_s']:.0f} s, patience {c['patience']}, seeds {c['seeds']}; "
             f"plain CNN {c['plain_epochs']} epochs. Test: every trial of a scene no model "
             "saw. Cells: value [95 % trial-bootstrap interval]; *variant - recipe*: paired "
             "trial bootstrap, "
             "**bold** = better than recipe with the interval excluding 0, *italic* = worse "
             "with the interval excluding 0.", ""]
    for cell, e in result["cells"].items():
        lines += [f"## {cell} ({e['n_trials']} test trials)", "",
                  "| variant | " + " | ".join(h for _, h, _ in KEYS) + " | "
                  + " | ".join(f"{h} - recipe" for _, h, _ in KEYS) + " | epochs (best) |",
                  "|---|" + "---|" * (2 * len(KEYS) + 1)]
        for name, r in e["rows"].items():
            m, d, t = r["metrics"], r.get("minus_recipe") or {}, r.get("training") or {}
            ep = "" if t.get("epochs_run") is None else \
                f"{t['epochs_run']} ({t['best_epoch']}, {t['stop_reason']})"
            lines.append(f"| {name} | " + " | ".join(format_ci(m, k, s) for k, _, s in KEYS)
                         + " | " + " | ".join(_diff(d.get(k), k) for k, _, _ in KEYS)
                         + f" | {ep} |")
        lines.append("")
        if e.get("where"):
            lines += where_markdown(e["where"])
    lines += ["## Variants against recipe over all cells", "",
              "Cells in which the paired interval excludes 0, better / worse (of cells "
              "measured).", "",
              "| variant | " + " | ".join(h for _, h, _ in KEYS) + " |",
              "|---|" + "---|" * len(KEYS)]
    for name, v in result.get("verdicts", {}).items():
        lines.append(f"| {name} | " + " | ".join(
            f"{v[k]['better']} / {v[k]['worse']} (of {v[k]['cells']})" if k in v else ""
            for k, _, _ in KEYS) + " |")
    lines += ["", "Variants:", ""] + [f"- `{k}`: {v[0]}" for k, v in VARIANTS.items()] + [""]
    return "\n".join(lines)


# --- CLI ----------------------------------------------------------------------------------

def add_arguments(p: argparse.ArgumentParser) -> None:
    d = MagnitudeConfig()
    p.add_argument("--out", default=str(d.out))
    p.add_argument("--data", default=str(d.data),
                   help="directory of exported datasets (make transfer exports them)")
    p.add_argument("--cells", default=",".join(f"{a}:{b}" for a, b in d.cells),
                   help="comma-separated TRAIN:TEST dataset names under --data")
    p.add_argument("--variants", default=",".join(d.variants),
                   help=f"comma-separated subset of {tuple(VARIANTS)}")
    p.add_argument("--baselines", default=",".join(d.baselines))
    p.add_argument("--epochs", type=int, default=d.epochs)
    p.add_argument("--patience", type=int, default=d.patience)
    p.add_argument("--time-budget", type=float, default=d.time_budget_s)
    p.add_argument("--plain-epochs", type=int, default=d.plain_epochs)
    p.add_argument("--threads", type=int, default=d.threads)
    p.add_argument("--seeds", default=",".join(map(str, d.seeds)),
                   help="comma-separated training seeds")
    p.add_argument("--n-boot", type=int, default=d.n_boot)
    p.add_argument("--min-test-trials", type=int, default=d.min_test_trials)


def config_from_args(args: argparse.Namespace) -> MagnitudeConfig:
    def names(s: str, allowed: tuple[str, ...], what: str) -> tuple[str, ...]:
        out = tuple(x for x in s.split(",") if x)
        bad = [x for x in out if x not in allowed]
        if bad:
            raise ValueError(f"unknown {what} {bad}; choose from {allowed}")
        return out
    cells = []
    for c in (x for x in args.cells.split(",") if x):
        train, sep, test = c.partition(":")
        if not (sep and train and test) or train == test:
            raise ValueError(f"a cell is TRAIN:TEST with two different datasets, got {c!r}")
        cells.append((train, test))
    if not cells:
        raise ValueError("no cells given")
    return MagnitudeConfig(out=Path(args.out), data=Path(args.data), cells=tuple(cells),
                           variants=names(args.variants, tuple(VARIANTS), "variants"),
                           baselines=names(args.baselines, BASELINES, "baselines"),
                           epochs=args.epochs, time_budget_s=args.time_budget,
                           plain_epochs=args.plain_epochs, threads=args.threads,
                           seeds=tuple(int(x) for x in args.seeds.split(",") if x),
                           patience=args.patience, n_boot=args.n_boot,
                           min_test_trials=args.min_test_trials)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.magnitude",
                                description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_arguments(p)
    try:
        cfg = config_from_args(p.parse_args(argv))
    except ValueError as exc:
        print(f"magnitude: {exc}", file=sys.stderr)
        return 2
    from .common import Log, set_threads
    set_threads(cfg.threads)
    try:
        run(cfg, Log("magnitude"))
    except (ValueError, FileNotFoundError) as exc:
        print(f"magnitude: {exc}", file=sys.stderr)
        return 1
    print((Path(cfg.out) / "magnitude.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
