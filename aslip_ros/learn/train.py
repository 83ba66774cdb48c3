"""Training: the recipe chosen on the user's data, the paper's two-stage recipe and the SVM
baseline (``aslip train``).

Stages:
  auto      (default) train the candidate recipes within a time budget and keep the one
            best on the validation trials (learn/recipes.py, docs/model.md)
  pretrain  all weights on (robot-induced) data          -> a checkpoint to finetune from
  finetune  from ``--init``: encoder frozen, heads only  (externally-induced data)
  scratch   all weights, no initialisation               (e.g. "single mic, no pretrain")
  svm       the handcrafted-feature SVM baseline

``--device`` (default cpu; auto: a CUDA GPU where torch sees one) moves the network and its
batches; checkpoints always hold CPU tensors.

Per-grasp calibration (``--calibration``, default ``background`` on the command line): the
constants are fitted on the training trials and every window is read with its own trial's
causal calibration removed (``calibration_frames``); the constants go into the checkpoint
under ``calibration``. ``off`` trains on raw features as before.

Log-mel features of every dataset window are cached once beside the dataset
(learn/train_data.py); the CNN's epoch loop is learn/train_loop.py; every trainer writes
its checkpoint document with ``checkpoint.checkpoint_meta``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from .backends import CNN, SvmBackend
from .calibration import METHODS
from .calibration_frames import remove_from_audio, training_calibration
from .checkpoint import (Checkpoint, checkpoint_meta, git_revision, load_checkpoint,
                         save_checkpoint)
from .data_io import WindowSet, open_dataset
from .evaluate import compute_metrics
from .features import FeatureConfig, normalization_stats
from .losses import LossWeights
from .network import ModelConfig, SlipNet
from .output_calibration import checkpoint_fields
from .svm import SvmConfig, SvmFeaturizer, fit_svm
from .train_data import Batches, feature_cache, split_windows
from .train_loop import DEVICES, evaluate_loss, resolve_device, run_epochs

STAGES = ("auto", "pretrain", "finetune", "scratch", "svm", "stream")
CALIBRATIONS = ("off",) + METHODS


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
    device: str = "cpu"            # auto | cpu | cuda (train_loop.resolve_device)
    encoder_lr_scale: float = 1.0  # learning rate of trainable encoder weights, times lr
    # Encoder parts a finetune trains (network.ENCODER_PARTS); () is the paper's frozen one.
    finetune_trainable: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.stage not in STAGES:
            raise ValueError(f"stage must be one of {STAGES}, got {self.stage!r}")
        if self.device not in DEVICES:
            raise ValueError(f"device must be one of {DEVICES}, got {self.device!r}")
        if not self.encoder_lr_scale > 0:
            raise ValueError("encoder_lr_scale must be positive")
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
        d["finetune_trainable"] = list(self.finetune_trainable)
        return d


@dataclass
class TrainResult:
    meta: dict[str, Any]
    tensors: dict[str, torch.Tensor]
    history: list[dict[str, float]]
    model: Any = None
    # --stage auto: every candidate that finished, by name (the winner among them).
    candidates: dict[str, "TrainResult"] | None = None

    def save(self, path: str | os.PathLike) -> Path:
        return save_checkpoint(path, self.meta, self.tensors)

    def checkpoint(self) -> Checkpoint:
        return Checkpoint(meta=self.meta, tensors=self.tensors)


# --- steps -------------------------------------------------------------------------------

def _seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed % (2 ** 32))


def _provenance(ds: WindowSet, cfg: TrainConfig, init: str | None) -> dict[str, Any]:
    return {"dataset": str(Path(ds.root).resolve()), "dataset_fingerprint": ds.fingerprint(),
            "git_revision": git_revision(), "seed": cfg.seed, "split_seed": cfg.split_seed,
            "stage": cfg.stage, "init": init, "torch_version": torch.__version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "filters": {"induced": cfg.induced, "objects": cfg.to_dict()["objects"],
                        "conditions": cfg.to_dict()["conditions"]}}


# --- CNN ----------------------------------------------------------------------------------

def _init_name(init: str | os.PathLike | Checkpoint | None) -> str | None:
    if isinstance(init, Checkpoint):
        return "in memory, pretrained on " + str(init.meta.get("provenance", {}).get("dataset"))
    return str(init) if init else None


def _open_init(ds: WindowSet, cfg: TrainConfig, init: str | os.PathLike | Checkpoint | None
               ) -> Checkpoint | None:
    """The checkpoint to finetune from, checked against the dataset (None without one)."""
    init_ckpt = init if isinstance(init, Checkpoint) else load_checkpoint(init) if init else None
    if cfg.stage == "finetune" and init_ckpt is None:
        raise ValueError("--stage finetune needs --init <checkpoint>")
    if init_ckpt is None:
        return None
    if init_ckpt.model_type != CNN:
        raise ValueError("--init must be a CNN checkpoint")
    init_ckpt.check_compatible(ds.sample_rate, [ds.channel_names[c] for c in
                                                ds.channel_indices(init_ckpt.channel_names)])
    if int(init_ckpt.meta["window_samples"]) != ds.window_samples:
        raise ValueError("the --init checkpoint was trained on another window length")
    return init_ckpt


def _build_model(ds: WindowSet, init_ckpt: Checkpoint | None, feats: np.ndarray,
                 tr: np.ndarray, channels: list[str], fcfg: FeatureConfig,
                 model_options: dict[str, Any] | None, rng: np.random.Generator) -> SlipNet:
    """The init checkpoint's network, or a new one normalised on the training windows with
    the median training slip speed as its speed scale."""
    if init_ckpt is not None:
        model = SlipNet(ModelConfig.from_dict(init_ckpt.meta["model_config"]))
        model.load_state_dict(init_ckpt.tensors)
        return model
    mean, std = normalization_stats(feats[np.sort(tr)] if tr.size <= 20000 else
                                    feats[np.sort(rng.choice(tr, 20000, replace=False))])
    slip_speed = ds.speed(tr)[ds.slip(tr)]
    scale = float(np.median(slip_speed)) if slip_speed.size else 0.02
    mcfg = ModelConfig(n_channels=len(channels), n_mels=fcfg.n_mels,
                       speed_scale=max(scale, 1e-4), **dict(model_options or {}))
    model = SlipNet(mcfg)
    model.set_normalization(mean, std)
    return model


def _cnn_meta(ds: WindowSet, cfg: TrainConfig, model: SlipNet, fcfg: FeatureConfig,
              channels: list[str], weights: LossWeights, cal: Any, prov: dict[str, Any]
              ) -> dict[str, Any]:
    return checkpoint_meta(
        CNN, model.cfg, fcfg, ds, channels, provenance=prov, calibration=cal,
        normalization={"mean": model.feat_mean.tolist(), "std": model.feat_std.tolist(),
                       "scope": "per mel bin over training windows, channels and frames"},
        loss_weights=weights.to_dict(), train_config=cfg.to_dict())


def train_cnn(ds: WindowSet, cfg: TrainConfig, *, feature_config: FeatureConfig | None = None,
              model_options: dict[str, Any] | None = None,
              channels: Sequence[str] | None = None,
              init: str | os.PathLike | Checkpoint | None = None,
              weights: LossWeights = LossWeights(), cache_dir: str | os.PathLike | None = None,
              log: Callable[[str], None] = print) -> TrainResult:
    """Train (pretrain / scratch) or finetune (``init`` given, a path or a loaded checkpoint;
    encoder frozen but for ``cfg.finetune_trainable``) the CNN on ``cfg.device``."""
    torch.set_num_threads(max(1, cfg.threads))
    device = resolve_device(cfg.device)
    _seed_everything(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    init_ckpt = _open_init(ds, cfg, init)
    if init_ckpt is not None:     # the init's channels and features: its weights read those
        channels = init_ckpt.channel_names
        feature_config = FeatureConfig.from_dict(init_ckpt.meta["feature_config"])
    channels = list(channels or ds.channel_names)
    fcfg = feature_config or FeatureConfig()

    t0 = time.perf_counter()
    feats = feature_cache(ds, fcfg, channels, cache_dir, progress=cfg.progress)
    tr, va = split_windows(ds, cfg)
    reuse = None if init_ckpt is None else init_ckpt.meta.get("calibration")
    cal, offsets = training_calibration(ds, cfg.calibration, channels, fcfg, tr, va, reuse,
                                        log)
    t_feat = time.perf_counter() - t0
    data = Batches(feats, ds, offsets)

    model = _build_model(ds, init_ckpt, feats, tr, channels, fcfg, model_options, rng)
    if cfg.stage == "finetune":
        model.freeze_encoder(cfg.finetune_trainable)
    model.to(device)
    fit = run_epochs(model, data, tr, va, cfg, weights, rng, log)

    _, pred = evaluate_loss(model, data, va, weights)
    model.to("cpu")
    val_metrics = compute_metrics(pred["prob"], pred["v"], data.v[va], data.slip[va],
                                  ds.window_s)
    prov = _provenance(ds, cfg, _init_name(init))
    prov["device"] = str(device)
    if init_ckpt is not None:
        prov["init_provenance"] = {k: init_ckpt.meta.get("provenance", {}).get(k)
                                   for k in ("dataset", "stage", "seed", "git_revision")}
    prov.update(metrics={"val": val_metrics, "best_val_loss": fit.best_loss},
                training={"best_epoch": fit.best_epoch, "epochs_run": len(fit.history),
                          "stop_reason": fit.stop_reason, "train_time_s": fit.train_time_s,
                          "feature_time_s": t_feat, "n_train_windows": int(tr.size),
                          "n_val_windows": int(va.size)})
    meta = _cnn_meta(ds, cfg, model, fcfg, channels, weights, cal, prov)
    meta.update(checkpoint_fields(pred["prob"], pred["v"], data.v[va], data.slip[va]))
    model.eval()
    tensors = {k: v.detach().clone() for k, v in model.state_dict().items()}
    return TrainResult(meta=meta, tensors=tensors, history=fit.history, model=model)


# --- SVM ----------------------------------------------------------------------------------

def train_svm(ds: WindowSet, cfg: TrainConfig, *, feature_config: FeatureConfig | None = None,
              svm_config: SvmConfig = SvmConfig(), channels: Sequence[str] | None = None,
              log: Callable[[str], None] = print) -> TrainResult:
    """Fit the SVM baseline on (at most ``svm_config.max_train``) training windows."""
    rng = np.random.default_rng(cfg.seed)
    channels = list(channels or ds.channel_names)
    cols = ds.channel_indices(channels)
    fcfg = feature_config or FeatureConfig()
    tr, va = split_windows(ds, cfg)
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
    meta = checkpoint_meta(
        SvmBackend.model_type, svm_config, fcfg, ds, channels, provenance=prov,
        calibration=cal, train_config=cfg.to_dict(),
        normalization={"mean": arrays.mean.tolist(), "std": arrays.std.tolist(),
                       "scope": "per handcrafted feature over training windows"})
    meta.update(checkpoint_fields(prob, v, ds.velocity(va), ds.slip(va)))
    return TrainResult(meta=meta, tensors=arrays.to_tensors(), history=[], model=arrays)


# --- CLI ----------------------------------------------------------------------------------

def _csv(s: str | None) -> list[str] | None:
    return [x for x in s.split(",") if x] if s else None


def add_arguments(p: argparse.ArgumentParser) -> None:
    d, m, f = TrainConfig(), ModelConfig(), FeatureConfig()
    p.add_argument("--dataset", required=True, help="dataset directory (aslip export)")
    p.add_argument("--stage", choices=STAGES, default="auto",
                   help="auto: train the candidate recipes (--recipes) within "
                        "--time-budget and keep the best on the validation trials; "
                        "pretrain: the CNN on robot-induced data; finetune: the heads on "
                        "another set from --init (the paper's frozen encoder); scratch: "
                        "every weight on this dataset; svm: the paper's SVM baseline; "
                        "stream: the causal streaming estimator (docs/streaming.md)")
    p.add_argument("--init", default=None, help="checkpoint to finetune (--stage finetune)")
    p.add_argument("--pretrain-dataset", default=None,
                   help="--stage auto: a robot-induced dataset to pretrain the encoder on "
                        "(optional; the frozen/partial/unfrozen recipes need it)")
    p.add_argument("--recipes", default=None,
                   help="--stage auto: comma-separated candidates out of "
                        "frozen,partial,unfrozen,scratch,svm (default frozen,unfrozen,"
                        "scratch,svm)")
    p.add_argument("--seeds", default="0",
                   help="--stage auto: training seeds of the scratch candidate")
    p.add_argument("--keep-candidates", action="store_true",
                   help="--stage auto: also write every candidate's checkpoint to "
                        "<out>.candidates/<name>.pt")
    p.add_argument("--device", choices=DEVICES, default=d.device,
                   help="where the network trains: cpu (default), cuda, or auto (a CUDA GPU "
                        "where torch sees one, else the CPU)")
    p.add_argument("--out", required=True, help="checkpoint file to write")
    p.add_argument("--seed", type=int, default=d.seed, help="training seed")
    p.add_argument("--split-seed", type=int, default=d.split_seed,
                   help="seed of the by-trial split (keep fixed across training seeds)")
    p.add_argument("--epochs", type=int, default=d.epochs, help="maximum epochs")
    p.add_argument("--patience", type=int, default=d.patience, help="early-stopping epochs")
    p.add_argument("--time-budget", type=float, default=None,
                   help="seconds of training after which the best epoch is kept (default "
                        f"{d.time_budget_s:g}); --stage auto: the whole call's budget, "
                        "shared among the candidates (default 960)")
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
    if args.time_budget is None and args.stage != "auto":
        args.time_budget = TrainConfig.time_budget_s
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
                          noslip_ratio=args.noslip_ratio,
                          time_budget_s=args.time_budget or TrainConfig.time_budget_s,
                          gain_db=args.gain_db, channel_gain_db=args.channel_gain_db,
                          threads=args.threads, progress=not args.no_progress,
                          calibration=args.calibration, device=args.device,
                          induced=args.induced, objects=tuple(_csv(args.objects) or ()) or None,
                          conditions=tuple(_csv(args.conditions) or ()) or None)
        fcfg = FeatureConfig(sample_rate=args.feature_rate, n_fft=args.n_fft, hop=args.hop,
                             n_mels=args.n_mels, fmin=args.fmin, fmax=args.fmax)
        svm_config = SvmConfig(C=args.svm_c, max_train=args.svm_max_train)
        model_options = dict(width=args.width, depth=args.depth,
                             temporal_channels=args.temporal_channels,
                             temporal_layers=args.temporal_layers,
                             head_hidden=args.head_hidden, dropout=args.dropout, gate=args.gate)
        if args.stage == "auto":
            from .recipes import run_selected
            return run_selected(args, ds, cfg, fcfg, model_options, svm_config)
        if args.stage == "svm":
            res = train_svm(ds, cfg, feature_config=fcfg, channels=_csv(args.channels),
                            svm_config=svm_config)
        else:
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
