"""Training: the paper's two-stage recipe and the SVM baseline (``aslip train``).

Stages:
  pretrain  all weights on (robot-induced) data          -> a checkpoint to finetune from
  finetune  from ``--init``: encoder frozen, heads only  (externally-induced data)
  scratch   all weights, no initialisation               (e.g. "single mic, no pretrain")
  svm       the handcrafted-feature SVM baseline

Per-grasp calibration (``--calibration``, default ``background`` on the command line): the
constants are fitted on the training trials and every window is read with its own trial's
causal calibration removed (``calibration_frames``); the constants go into the checkpoint
under ``calibration``. ``off`` trains on raw features as before.

Log-mel features of every dataset window are computed once per (dataset, feature config,
channels) with the shared ``features.LogMel`` and cached as a float16 ``.npy`` beside the
dataset, memory-mapped on later runs; epochs then cost only the network.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import datetime as _dt
import hashlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from aslip_ros.util import atomic_path

from .calibration import METHODS
from .calibration_frames import remove_from_audio, training_calibration
from .checkpoint import Checkpoint, load_checkpoint, save_checkpoint, git_revision
from .data_io import WindowSet, open_dataset, select_windows
from .evaluate import compute_metrics
from .features import FeatureConfig, LogMel, normalization_stats
from .losses import LossWeights, slip_loss
from .network import ModelConfig, SlipNet
from .svm import SvmConfig, SvmFeaturizer, fit_svm

STAGES = ("pretrain", "finetune", "scratch", "svm", "stream")
CALIBRATIONS = ("off",) + METHODS
_DB_TO_LOG_POWER = math.log(10.0) / 10.0  # +1 dB amplitude-power gain in natural-log power


@dataclass
class TrainConfig:
    """Recipe hyper-parameters (paper: Adam 1e-3, wd 1e-4, SpecAugment, random gain)."""

    stage: str = "scratch"
    epochs: int = 300
    batch_size: int = 128
    lr: float = 1e-3
    weight_decay: float = 1e-4
    patience: int = 30             # epochs; one epoch is only a few dozen batches
    seed: int = 0
    split_seed: int = 0
    noslip_ratio: float = 1.0      # no-slip windows drawn per slip window, each epoch
    gain_db: float = 6.0           # random gain, whole window, +/- dB
    channel_gain_db: float = 1.0   # extra per-microphone gain, +/- dB
    freq_mask: int = -1            # max SpecAugment frequency-mask width; -1: n_mels // 8
    time_mask: int = 3             # max SpecAugment time-mask width (frames)
    time_budget_s: float = 1140.0  # stop (keeping the best epoch) after this much training
    threads: int = 2
    progress: bool = True
    # Library default off (the experiment tables were measured so); ``aslip train``
    # defaults to background.
    calibration: str = "off"
    induced: str | None = None
    objects: tuple[str, ...] | None = None
    conditions: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if self.stage not in STAGES:
            raise ValueError(f"stage must be one of {STAGES}, got {self.stage!r}")
        if self.epochs < 1 or self.batch_size < 2 or self.patience < 1:
            raise ValueError("epochs >= 1, batch_size >= 2 and patience >= 1 are required")
        if self.calibration not in CALIBRATIONS:
            raise ValueError(f"calibration must be one of {CALIBRATIONS}, "
                             f"got {self.calibration!r}")
        if self.noslip_ratio <= 0:
            raise ValueError("noslip_ratio must be positive")
        if not (self.gain_db >= 0 and self.channel_gain_db >= 0):
            raise ValueError("gain_db and channel_gain_db must be >= 0")

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for k in ("objects", "conditions"):
            d[k] = list(d[k]) if d[k] else None
        return d


@dataclass
class TrainResult:
    meta: dict[str, Any]
    tensors: dict[str, torch.Tensor]
    history: list[dict[str, float]]
    model: Any = None

    def save(self, path: str | os.PathLike) -> Path:
        return save_checkpoint(path, self.meta, self.tensors)

    def checkpoint(self) -> Checkpoint:
        return Checkpoint(meta=self.meta, tensors=self.tensors)


# --- feature cache ------------------------------------------------------------------------

def _cache_key(ds: WindowSet, fcfg: FeatureConfig, channels: Sequence[str]) -> str:
    doc = json.dumps({"ds": ds.fingerprint(), "f": fcfg.to_dict(), "c": list(channels),
                      "n": ds.window_samples, "v": 1}, sort_keys=True)
    return hashlib.sha1(doc.encode()).hexdigest()[:16]


def feature_cache(ds: WindowSet, fcfg: FeatureConfig, channels: Sequence[str],
                  cache_dir: str | os.PathLike | None = None, progress: bool = False,
                  chunk: int = 256) -> np.ndarray:
    """Log-mel features of every window, ``(n_windows, C, M, T)`` float16, memory-mapped.

    float16 halves memory and disk; log-mel values are O(10) and their float16 rounding
    (~0.01) is far below the augmentation noise.
    """
    cols = ds.channel_indices(channels)
    root = Path(cache_dir) if cache_dir else ds.root / ".feature_cache"
    path = root / f"logmel-{_cache_key(ds, fcfg, channels)}.npy"
    if path.is_file():
        return np.load(path, mmap_mode="r")
    logmel = LogMel(fcfg, ds.sample_rate)
    shape = (len(ds), len(cols), fcfg.n_mels, logmel.n_frames(ds.window_samples))
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError:
        root = Path.home() / ".cache" / "aslip_ros" / "features"
        root.mkdir(parents=True, exist_ok=True)
        path = root / path.name
    with atomic_path(path) as tmp:
        out = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float16, shape=shape)
        starts = range(0, len(ds), chunk)
        if progress:
            from tqdm import tqdm
            starts = tqdm(starts, desc="features", unit="chunk", leave=False)
        for s in starts:
            out[s:s + chunk] = logmel(ds.window_audio(np.arange(s, min(s + chunk, len(ds))),
                                                      cols))
        out.flush()
        del out
    return np.load(path, mmap_mode="r")


# --- helpers ------------------------------------------------------------------------------

def _seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed % (2 ** 32))


def _augment(x: np.ndarray, mean: np.ndarray, rng: np.random.Generator,
             cfg: TrainConfig) -> np.ndarray:
    """Random gain (log-domain offset) and SpecAugment masks filled with the bin means."""
    b, c, m, t = x.shape
    gain = rng.uniform(-cfg.gain_db, cfg.gain_db, (b, 1)) + rng.uniform(
        -cfg.channel_gain_db, cfg.channel_gain_db, (b, c))
    x = x + (gain * _DB_TO_LOG_POWER)[:, :, None, None].astype(np.float32)
    fmax = m // 8 if cfg.freq_mask < 0 else cfg.freq_mask
    fill = np.broadcast_to(mean[None, None, :, None], x.shape)
    if fmax > 0:
        w = rng.integers(0, fmax + 1, b)
        f0 = rng.integers(0, m - w + 1)
        fr = np.arange(m)
        mask = (fr >= f0[:, None]) & (fr < (f0 + w)[:, None])
        x = np.where(mask[:, None, :, None], fill, x)
    if cfg.time_mask > 0 and t > cfg.time_mask:
        w = rng.integers(0, cfg.time_mask + 1, b)
        t0 = rng.integers(0, t - w + 1)
        tr = np.arange(t)
        mask = (tr >= t0[:, None]) & (tr < (t0 + w)[:, None])
        x = np.where(mask[:, None, None, :], fill, x)
    return np.ascontiguousarray(x, dtype=np.float32)


def _epoch_indices(idx: np.ndarray, slip: np.ndarray, ratio: float,
                   rng: np.random.Generator) -> np.ndarray:
    """All slip windows plus at most ``ratio`` no-slip windows per slip window, shuffled."""
    pos, neg = idx[slip[idx]], idx[~slip[idx]]
    if pos.size == 0:
        chosen = neg
    else:
        n_neg = min(neg.size, int(round(ratio * pos.size)))
        chosen = np.concatenate([pos, rng.choice(neg, n_neg, replace=False)])
    return rng.permutation(chosen)


class _Batches:
    """Tensors for index batches from the feature cache and labels."""

    def __init__(self, feats: np.ndarray, ds: WindowSet,
                 offsets: np.ndarray | None = None) -> None:
        self.feats = feats
        self.offsets = offsets          # (n_windows, C) per-grasp calibration, or None
        all_idx = np.arange(len(ds))
        self.v = ds.velocity(all_idx)
        self.slip = ds.slip(all_idx)
        self.prev = ds.previous_index()

    def labels(self, b: np.ndarray) -> dict[str, torch.Tensor]:
        prev = self.prev[b]
        valid = prev >= 0
        pv = np.where(valid[:, None], self.v[np.maximum(prev, 0)], 0.0).astype(np.float32)
        valid &= self.slip[np.maximum(prev, 0)]
        return {"v_true": torch.from_numpy(self.v[b]),
                "slip": torch.from_numpy(self.slip[b]),
                "prev_v_true": torch.from_numpy(pv),
                "prev_valid": torch.from_numpy(valid)}

    def x(self, b: np.ndarray) -> np.ndarray:
        # Sorted reads are much faster on a memory map; restore the batch order after.
        order = np.argsort(b)
        out = np.empty((b.size,) + self.feats.shape[1:], dtype=np.float32)
        out[order] = self.feats[b[order]]
        if self.offsets is not None:
            out -= self.offsets[b][:, :, None, None]
        return out


def _evaluate_loss(model: SlipNet, data: _Batches, idx: np.ndarray,
                   weights: LossWeights, bs: int = 1024) -> tuple[float, dict[str, np.ndarray]]:
    model.eval()
    total, n = 0.0, 0
    probs, vels = [], []
    with torch.inference_mode():
        for s in range(0, idx.size, bs):
            b = idx[s:s + bs]
            out = model(torch.from_numpy(data.x(b)))
            loss, _ = slip_loss(out, speed_scale=model.cfg.speed_scale, weights=weights,
                                **data.labels(b))
            total += float(loss) * b.size
            n += b.size
            d = out.direction / out.direction.norm(dim=1, keepdim=True).clamp(min=1e-8)
            probs.append(torch.sigmoid(out.logit).numpy())
            vels.append((d * out.magnitude[:, None]).numpy())
    pred = {"prob": np.concatenate(probs) if probs else np.zeros(0),
            "v": np.concatenate(vels) if vels else np.zeros((0, 2))}
    return total / max(n, 1), pred


def _split(ds: WindowSet, cfg: TrainConfig, log: Callable[[str], None]
           ) -> tuple[np.ndarray, np.ndarray]:
    kw = dict(induced=cfg.induced, objects=cfg.objects, conditions=cfg.conditions,
              seed=cfg.split_seed)
    tr = select_windows(ds, "train", **kw)
    va = select_windows(ds, "val", **kw)
    if tr.size == 0:
        raise ValueError(f"no training windows in {ds.root} with these filters")
    if va.size == 0:
        # Validating on the training set would report training numbers as "val".
        from aslip_ros.data.dataset import split_summary
        raise ValueError(
            f"no validation trials in {ds.root} with these filters: the split by trial gives "
            f"{split_summary(ds.trials, cfg.split_seed)}; validation needs trials that are "
            "not trained on: record and export more trials (of one object and condition, 3 "
            "give a validation trial, 5 a test trial too) or loosen the filters")
    return tr, va


def _provenance(ds: WindowSet, cfg: TrainConfig, init: str | None) -> dict[str, Any]:
    return {"dataset": str(Path(ds.root).resolve()), "dataset_fingerprint": ds.fingerprint(),
            "git_revision": git_revision(), "seed": cfg.seed, "split_seed": cfg.split_seed,
            "stage": cfg.stage, "init": init, "torch_version": torch.__version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "filters": {"induced": cfg.induced, "objects": cfg.to_dict()["objects"],
                        "conditions": cfg.to_dict()["conditions"]}}


def _layout(ds: WindowSet, channels: Sequence[str]) -> str | None:
    if list(channels) == ds.channel_names:
        return ds.layout
    return f"{ds.layout}:{'+'.join(channels)}"


# --- CNN ----------------------------------------------------------------------------------

def train_cnn(ds: WindowSet, cfg: TrainConfig, *, feature_config: FeatureConfig | None = None,
              model_options: dict[str, Any] | None = None,
              channels: Sequence[str] | None = None, init: str | os.PathLike | None = None,
              weights: LossWeights = LossWeights(), cache_dir: str | os.PathLike | None = None,
              log: Callable[[str], None] = print) -> TrainResult:
    """Train (pretrain / scratch) or finetune (``init`` given, encoder frozen) the CNN."""
    torch.set_num_threads(max(1, cfg.threads))
    _seed_everything(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    init_ckpt = load_checkpoint(init) if init else None
    if cfg.stage == "finetune" and init_ckpt is None:
        raise ValueError("--stage finetune needs --init <checkpoint>")
    if init_ckpt is not None:
        if init_ckpt.model_type != "aslip_cnn":
            raise ValueError("--init must be a CNN checkpoint")
        channels = init_ckpt.channel_names
        init_ckpt.check_compatible(ds.sample_rate, [ds.channel_names[c]
                                                    for c in ds.channel_indices(channels)])
        if int(init_ckpt.meta["window_samples"]) != ds.window_samples:
            raise ValueError("the --init checkpoint was trained on another window length")
        feature_config = FeatureConfig.from_dict(init_ckpt.meta["feature_config"])
    channels = list(channels or ds.channel_names)
    fcfg = feature_config or FeatureConfig()

    t0 = time.perf_counter()
    feats = feature_cache(ds, fcfg, channels, cache_dir, progress=cfg.progress)
    tr, va = _split(ds, cfg, log)
    reuse = None if init_ckpt is None else init_ckpt.meta.get("calibration")
    cal, offsets = training_calibration(ds, cfg.calibration, channels, fcfg, tr, va, reuse,
                                        log)
    t_feat = time.perf_counter() - t0
    data = _Batches(feats, ds, offsets)

    if init_ckpt is not None:
        mcfg = ModelConfig.from_dict(init_ckpt.meta["model_config"])
        model = SlipNet(mcfg)
        model.load_state_dict(init_ckpt.tensors)
    else:
        mean, std = normalization_stats(feats[np.sort(tr)] if tr.size <= 20000 else
                                        feats[np.sort(rng.choice(tr, 20000, replace=False))])
        slip_speed = ds.speed(tr)[ds.slip(tr)]
        scale = float(np.median(slip_speed)) if slip_speed.size else 0.02
        opts = dict(model_options or {})
        mcfg = ModelConfig(n_channels=len(channels), n_mels=fcfg.n_mels,
                           speed_scale=max(scale, 1e-4), **opts)
        model = SlipNet(mcfg)
        model.set_normalization(mean, std)
    if cfg.stage == "finetune":
        model.freeze_encoder()
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    feat_mean = model.feat_mean.numpy().copy()

    best = (math.inf, -1, copy.deepcopy(model.state_dict()))
    history: list[dict[str, float]] = []
    t_start = time.perf_counter()
    stop_reason = "max_epochs"
    for epoch in range(cfg.epochs):
        model.train()
        order = _epoch_indices(tr, data.slip, cfg.noslip_ratio, rng)
        n_batches = max(1, order.size // cfg.batch_size)  # drop the ragged tail (BN stability)
        batches = range(n_batches)
        if cfg.progress:
            from tqdm import tqdm
            batches = tqdm(batches, desc=f"epoch {epoch}", unit="batch", leave=False)
        run_loss = 0.0
        for i in batches:
            b = order[i * cfg.batch_size:(i + 1) * cfg.batch_size]
            x = torch.from_numpy(_augment(data.x(b), feat_mean, rng, cfg))
            out = model(x)
            loss, _ = slip_loss(out, speed_scale=mcfg.speed_scale, weights=weights,
                                **data.labels(b))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            run_loss += float(loss.detach())
        val_loss, _ = _evaluate_loss(model, data, va, weights)
        history.append({"epoch": epoch, "train_loss": run_loss / n_batches,
                        "val_loss": val_loss, "time_s": time.perf_counter() - t_start})
        if cfg.progress:
            log(f"epoch {epoch:3d}  train {run_loss / n_batches:.4f}  val {val_loss:.4f}")
        if val_loss < best[0]:
            best = (val_loss, epoch, copy.deepcopy(model.state_dict()))
        elif epoch - best[1] >= cfg.patience:
            stop_reason = "early_stopping"
            break
        if time.perf_counter() - t_start > cfg.time_budget_s:
            stop_reason = "time_budget"
            break
    model.load_state_dict(best[2])
    t_train = time.perf_counter() - t_start

    _, pred = _evaluate_loss(model, data, va, weights)
    val_metrics = compute_metrics(pred["prob"], pred["v"], data.v[va], data.slip[va],
                                  ds.window_s)
    prov = _provenance(ds, cfg, str(init) if init else None)
    if init_ckpt is not None:
        prov["init_provenance"] = {k: init_ckpt.meta.get("provenance", {}).get(k)
                                   for k in ("dataset", "stage", "seed", "git_revision")}
    prov.update(metrics={"val": val_metrics, "best_val_loss": best[0]},
                training={"best_epoch": best[1], "epochs_run": len(history),
                          "stop_reason": stop_reason, "train_time_s": t_train,
                          "feature_time_s": t_feat, "n_train_windows": int(tr.size),
                          "n_val_windows": int(va.size)})
    meta = {
        "model_type": "aslip_cnn", "model_config": mcfg.to_dict(),
        "feature_config": fcfg.to_dict(),
        "normalization": {"mean": model.feat_mean.tolist(), "std": model.feat_std.tolist(),
                          "scope": "per mel bin over training windows, channels and frames"},
        "channel_names": channels, "layout": _layout(ds, channels),
        "sample_rate": ds.sample_rate, "window_s": ds.window_s,
        "window_samples": ds.window_samples, "epsilon_m_s": ds.epsilon, "threshold": 0.5,
        "loss_weights": weights.to_dict(), "train_config": cfg.to_dict(), "provenance": prov,
    }
    if cal is not None:
        meta["calibration"] = cal.to_dict()
    model.eval()
    tensors = {k: v.detach().clone() for k, v in model.state_dict().items()}
    return TrainResult(meta=meta, tensors=tensors, history=history, model=model)


# --- SVM ----------------------------------------------------------------------------------

def train_svm(ds: WindowSet, cfg: TrainConfig, *, feature_config: FeatureConfig | None = None,
              svm_config: SvmConfig = SvmConfig(), channels: Sequence[str] | None = None,
              log: Callable[[str], None] = print) -> TrainResult:
    """Fit the SVM baseline on (at most ``svm_config.max_train``) training windows."""
    rng = np.random.default_rng(cfg.seed)
    channels = list(channels or ds.channel_names)
    cols = ds.channel_indices(channels)
    fcfg = feature_config or FeatureConfig()
    tr, va = _split(ds, cfg, log)
    cal, offsets = training_calibration(ds, cfg.calibration, channels, fcfg, tr, va, None,
                                        log)
    slip_all = ds.slip(np.arange(len(ds)))
    if tr.size > svm_config.max_train:
        # Balanced subsample: SVC cost grows quadratically with the training set.
        pos, neg = tr[slip_all[tr]], tr[~slip_all[tr]]
        n_pos = min(pos.size, svm_config.max_train // 2)
        n_neg = min(neg.size, svm_config.max_train - n_pos)
        tr = np.sort(np.concatenate([rng.choice(pos, n_pos, replace=False),
                                     rng.choice(neg, n_neg, replace=False)]))
    featurizer = SvmFeaturizer(fcfg, ds.sample_rate, svm_config.n_bands)

    def audio(idx: np.ndarray) -> np.ndarray:
        a = ds.window_audio(idx, cols)
        return a if offsets is None else remove_from_audio(a, offsets[idx])

    def feats(idx: np.ndarray) -> np.ndarray:
        return np.concatenate([featurizer(audio(idx[s:s + 512]))
                               for s in range(0, idx.size, 512)])

    t0 = time.perf_counter()
    arrays, _ = fit_svm(feats(tr), ds.slip(tr), ds.velocity(tr), svm_config)
    prob, v = arrays.predict(feats(va))
    val_metrics = compute_metrics(prob, v, ds.velocity(va), ds.slip(va), ds.window_s)
    prov = _provenance(ds, cfg, None)
    prov.update(metrics={"val": val_metrics},
                training={"train_time_s": time.perf_counter() - t0,
                          "n_train_windows": int(tr.size), "n_val_windows": int(va.size)})
    meta = {
        "model_type": "svm", "model_config": svm_config.to_dict(),
        "feature_config": fcfg.to_dict(),
        "normalization": {"mean": arrays.mean.tolist(), "std": arrays.std.tolist(),
                          "scope": "per handcrafted feature over training windows"},
        "channel_names": channels, "layout": _layout(ds, channels),
        "sample_rate": ds.sample_rate, "window_s": ds.window_s,
        "window_samples": ds.window_samples, "epsilon_m_s": ds.epsilon, "threshold": 0.5,
        "train_config": cfg.to_dict(), "provenance": prov,
    }
    if cal is not None:
        meta["calibration"] = cal.to_dict()
    return TrainResult(meta=meta, tensors=arrays.to_tensors(), history=[], model=arrays)


# --- CLI ----------------------------------------------------------------------------------

def _csv(s: str | None) -> list[str] | None:
    return [x for x in s.split(",") if x] if s else None


def add_arguments(p: argparse.ArgumentParser) -> None:
    d, m, f = TrainConfig(), ModelConfig(), FeatureConfig()
    p.add_argument("--dataset", required=True, help="dataset directory (aslip export)")
    p.add_argument("--stage", choices=STAGES, default="scratch",
                   help="pretrain: the CNN on robot-induced data; finetune: the heads on "
                        "another set from --init (the paper's frozen encoder); scratch: "
                        "every weight on this dataset; svm: the paper's SVM baseline; "
                        "stream: the causal streaming estimator (docs/streaming.md)")
    p.add_argument("--init", default=None, help="checkpoint to finetune (--stage finetune)")
    p.add_argument("--out", required=True, help="checkpoint file to write")
    p.add_argument("--seed", type=int, default=d.seed, help="training seed")
    p.add_argument("--split-seed", type=int, default=d.split_seed,
                   help="seed of the by-trial split (keep fixed across training seeds)")
    p.add_argument("--epochs", type=int, default=d.epochs, help="maximum epochs")
    p.add_argument("--patience", type=int, default=d.patience, help="early-stopping epochs")
    p.add_argument("--time-budget", type=float, default=d.time_budget_s,
                   help="seconds of training after which the best epoch is kept")
    p.add_argument("--batch-size", type=int, default=d.batch_size)
    p.add_argument("--lr", type=float, default=d.lr)
    p.add_argument("--weight-decay", type=float, default=d.weight_decay)
    p.add_argument("--noslip-ratio", type=float, default=d.noslip_ratio,
                   help="no-slip windows per slip window drawn each epoch")
    p.add_argument("--threads", type=int, default=d.threads, help="torch.set_num_threads")
    p.add_argument("--gain-db", type=float, default=d.gain_db,
                   help="random whole-window gain augmentation, +/- dB")
    p.add_argument("--channel-gain-db", type=float, default=d.channel_gain_db,
                   help="extra random per-microphone gain augmentation, +/- dB")
    p.add_argument("--window", type=float, default=None,
                   help="window length in s; must equal the dataset's (checked)")
    p.add_argument("--channels", default=None, help="comma-separated channel names to use")
    p.add_argument("--induced", default=None, help="only trials with this 'induced' value")
    p.add_argument("--objects", default=None, help="comma-separated objects to keep")
    p.add_argument("--conditions", default=None, help="comma-separated conditions to keep")
    p.add_argument("--calibration", choices=CALIBRATIONS, default="background",
                   help="per-grasp microphone calibration fitted on the training trials and "
                        "stored in the checkpoint (docs/model.md); off: raw features "
                        "(default %(default)s; a finetune keeps its --init's)")
    p.add_argument("--cache-dir", default=None,
                   help="feature cache directory (default <dataset>/.feature_cache)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    g = p.add_argument_group("features")
    g.add_argument("--feature-rate", type=float, default=f.sample_rate)
    g.add_argument("--n-fft", type=int, default=f.n_fft)
    g.add_argument("--hop", type=int, default=f.hop)
    g.add_argument("--n-mels", type=int, default=f.n_mels)
    g.add_argument("--fmin", type=float, default=f.fmin)
    g.add_argument("--fmax", type=float, default=None)
    g = p.add_argument_group("model size")
    g.add_argument("--width", type=int, default=m.width)
    g.add_argument("--depth", type=int, default=m.depth)
    g.add_argument("--temporal-channels", type=int, default=m.temporal_channels)
    g.add_argument("--temporal-layers", type=int, default=m.temporal_layers)
    g.add_argument("--head-hidden", type=int, default=m.head_hidden)
    g.add_argument("--dropout", type=float, default=m.dropout)
    g.add_argument("--gate", choices=["softmax", "sigmoid"], default=m.gate)
    g = p.add_argument_group("svm")
    g.add_argument("--svm-c", type=float, default=SvmConfig.C)
    g.add_argument("--svm-max-train", type=int, default=SvmConfig.max_train)


def run(args: argparse.Namespace) -> int:
    if args.stage == "stream":     # the causal streaming estimator (learn/train_stream.py)
        from .train_stream import run_from_args
        return run_from_args(args)
    try:
        ds = open_dataset(args.dataset)
        if args.window is not None and abs(args.window - ds.window_s) > 1e-9:
            raise ValueError(f"--window {args.window} s but the dataset has "
                             f"{ds.window_s} s windows; export it with that window")
        cfg = TrainConfig(stage=args.stage, epochs=args.epochs, batch_size=args.batch_size,
                          lr=args.lr, weight_decay=args.weight_decay, patience=args.patience,
                          seed=args.seed, split_seed=args.split_seed,
                          noslip_ratio=args.noslip_ratio, time_budget_s=args.time_budget,
                          gain_db=args.gain_db, channel_gain_db=args.channel_gain_db,
                          threads=args.threads, progress=not args.no_progress,
                          calibration=args.calibration,
                          induced=args.induced, objects=tuple(_csv(args.objects) or ()) or None,
                          conditions=tuple(_csv(args.conditions) or ()) or None)
        fcfg = FeatureConfig(sample_rate=args.feature_rate, n_fft=args.n_fft, hop=args.hop,
                             n_mels=args.n_mels, fmin=args.fmin, fmax=args.fmax)
        if args.stage == "svm":
            res = train_svm(ds, cfg, feature_config=fcfg, channels=_csv(args.channels),
                            svm_config=SvmConfig(C=args.svm_c, max_train=args.svm_max_train))
        else:
            model_options = dict(width=args.width, depth=args.depth,
                                 temporal_channels=args.temporal_channels,
                                 temporal_layers=args.temporal_layers,
                                 head_hidden=args.head_hidden, dropout=args.dropout,
                                 gate=args.gate)
            res = train_cnn(ds, cfg, feature_config=fcfg, model_options=model_options,
                            channels=_csv(args.channels), init=args.init,
                            cache_dir=args.cache_dir)
    except (ValueError, FileNotFoundError) as exc:
        print(f"aslip train: error: {exc}", file=sys.stderr)
        return 1
    res.save(args.out)
    val = res.meta["provenance"]["metrics"]["val"]
    print(f"wrote {args.out}: val detection {val.get('detection_accuracy', float('nan')):.3f}, "
          f"direction MAE {val.get('direction_mae_deg', float('nan')):.1f} deg, "
          f"magnitude RMSE {val.get('magnitude_rmse_mm', float('nan')):.2f} mm")
    return 0
