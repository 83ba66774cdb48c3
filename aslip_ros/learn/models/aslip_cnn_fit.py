"""The CNN's fit: its stages, its resumable job and its epoch loop (the loss beside it:
aslip_cnn_loss.py). The network is learn/models/aslip_cnn.py, whose backend names this
module's ``fit`` (``CnnBackend.fit``), so that ``aslip train`` reaches the CNN as it reaches
a plug-in model (learn/training/train.py, ``train_backend``; docs/design.md "Extending").

Stages, one function each (``STAGES``; each returns a ``CnnJob``, built but not trained):

- ``pretrain``: every weight, on (robot-induced) data: a checkpoint to finetune from;
- ``finetune``: from ``init``, the encoder frozen but for ``cfg.finetune_trainable``, the
  heads trained;
- ``scratch``: every weight on this dataset (e.g. "single mic, no pretrain").

``train_cnn`` runs the job of ``cfg.stage`` without a pause; ``aslip train --stage auto``
resumes jobs slice by slice (learn/training/recipes.py).

The loop: balanced epochs, random gain and SpecAugment, early stopping on the validation
trials and a time budget. ``--device`` (default cpu; auto: a CUDA GPU where torch sees one,
``training.config.resolve_device``) moves the network and its batches; features,
augmentation and metrics stay on the CPU in numpy, and checkpoints always hold CPU tensors.

Rotational slip: training windows with angular labels (``wy``, dataset version 2) give the
network its ``angular`` head; a finetune whose init has none gets a new head. Per-grasp
calibration (``cfg.calibration``): the constants are fitted on the training trials and
every window is read with its own trial's causal calibration removed
(``calibration.frames``); they go into the checkpoint under ``calibration``, and a finetune
keeps its init's. Log-mel features of every dataset window are cached once beside the
dataset (learn/training/data.py).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch
from torch.optim.swa_utils import AveragedModel

from aslip_ros.learn.calibration.frames import training_calibration
from aslip_ros.learn.calibration.output import checkpoint_fields
from aslip_ros.learn.checkpoint import Checkpoint, checkpoint_meta, load_checkpoint
from aslip_ros.learn.data_io import WindowSet
from aslip_ros.learn.features import FeatureConfig, normalization_stats
from aslip_ros.learn.metrics import compute_metrics
from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet, output_arrays
from aslip_ros.learn.models.aslip_cnn_loss import LossWeights, slip_loss
from aslip_ros.learn.models.registry import CNN
from aslip_ros.learn.training.config import (TrainConfig, TrainResult, provenance,
                                             resolve_device, seed_everything)
from aslip_ros.learn.training.data import Batches, feature_cache, rotation_args, split_windows
from aslip_ros.learn.training import distributed
from aslip_ros.learn.training.resume import RESUME_FREE, JobState


_DB_TO_LOG_POWER = math.log(10.0) / 10.0  # +1 dB amplitude-power gain in natural-log power


def _device_of(model: SlipNet) -> torch.device:
    return model.feat_mean.device


def augment(x: np.ndarray, mean: np.ndarray, rng: np.random.Generator,
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


def epoch_indices(idx: np.ndarray, slip: np.ndarray, ratio: float,
                  rng: np.random.Generator) -> np.ndarray:
    """All slip windows plus at most ``ratio`` no-slip windows per slip window, shuffled
    (``slip``: the windows always drawn, ``Batches.moving``)."""
    pos, neg = idx[slip[idx]], idx[~slip[idx]]
    if pos.size == 0:
        chosen = neg
    else:
        n_neg = min(neg.size, int(round(ratio * pos.size)))
        chosen = np.concatenate([pos, rng.choice(neg, n_neg, replace=False)])
    return rng.permutation(chosen)


def evaluate_loss(model: SlipNet, data: Batches, idx: np.ndarray, weights: LossWeights,
                  bs: int = 1024) -> tuple[float, dict[str, np.ndarray]]:
    """Mean loss over ``idx`` and the model's p(slip), ungated velocity and, for a model
    with a rotational output, its rate ``w`` (rad/s; None without) there."""
    model.eval()
    dev = _device_of(model)
    total, n = 0.0, 0
    probs, vels, rates = [], [], []
    with torch.inference_mode():
        for s in range(0, idx.size, bs):
            b = idx[s:s + bs]
            out = model(torch.from_numpy(data.x(b)).to(dev))
            loss, _ = slip_loss(out, speed_scale=model.cfg.speed_scale, weights=weights,
                                **data.labels(b, dev))
            total += float(loss) * b.size
            n += b.size
            p, v = output_arrays(out)
            probs.append(p)
            vels.append(v)
            if out.angular is not None:
                rates.append(out.angular.cpu().numpy())
    pred = {"prob": np.concatenate(probs) if probs else np.zeros(0),
            "v": np.concatenate(vels) if vels else np.zeros((0, 2)),
            "w": (np.concatenate(rates) if rates else np.zeros(0)) if model.cfg.angular
            else None}
    return total / max(n, 1), pred


def param_groups(model: SlipNet, lr: float, encoder_lr_scale: float) -> list[dict[str, Any]]:
    """Trainable weights as Adam groups: the encoder's at ``lr * encoder_lr_scale`` (a
    finetuned encoder moves less than the new heads), the rest at ``lr``."""
    enc = [p for p in model.encoder.parameters() if p.requires_grad]
    ids = {id(p) for p in enc}
    rest = [p for p in model.parameters() if p.requires_grad and id(p) not in ids]
    groups = [{"params": rest, "lr": lr}]
    if enc:
        groups.append({"params": enc, "lr": lr * encoder_lr_scale})
    return groups


@dataclass
class Fit:
    """What the epoch loop leaves: the best epoch (its weights are loaded) and the run."""

    best_loss: float | None       # None: trained without validation
    best_epoch: int
    stop_reason: str              # max_epochs | early_stopping | time_budget
    train_time_s: float
    history: list[dict[str, float]] = field(default_factory=list)


def _train_epoch(model: SlipNet, data: Batches, order: np.ndarray, opt: torch.optim.Optimizer,
                 feat_mean: np.ndarray, rng: np.random.Generator, cfg: TrainConfig,
                 weights: LossWeights, label: str, net: torch.nn.Module | None = None
                 ) -> float:
    """One pass over ``order``; the mean training loss. ``net``: what the forward pass runs
    (the model under DistributedDataParallel, each rank on its share of every batch)."""
    net = model if net is None else net
    model.train()
    n_batches = max(1, order.size // cfg.batch_size)  # drop the ragged tail (BN stability)
    batches: Any = range(n_batches)
    if cfg.progress:
        from tqdm import tqdm
        batches = tqdm(batches, desc=label, unit="batch", leave=False)
    run_loss = 0.0
    dev = _device_of(model)
    for i in batches:
        b = distributed.share(order[i * cfg.batch_size:(i + 1) * cfg.batch_size])
        x = torch.from_numpy(augment(data.x(b), feat_mean, rng, cfg)).to(dev)
        out = net(x)
        loss, _ = slip_loss(out, speed_scale=model.cfg.speed_scale, weights=weights,
                            **data.labels(b, dev))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        run_loss += float(loss.detach())
    return run_loss / n_batches


class EpochRun:
    """Adam on the trainable weights, run in slices: ``advance(seconds)`` trains whole
    epochs until the slice is spent (the epoch that crosses it finishes), ``cfg.epochs`` or
    ``cfg.patience`` epochs without a better validation loss; ``finish()`` loads the best
    epoch's weights. The optimiser, the random stream and the best epoch carry over from one
    slice to the next, so a job the budget allocator resumes trains as one run would."""

    def __init__(self, model: SlipNet, data: Batches, tr: np.ndarray, va: np.ndarray,
                 cfg: TrainConfig, weights: LossWeights, rng: np.random.Generator,
                 log: Callable[[str], None]) -> None:
        self.model, self.data, self.tr, self.va = model, data, tr, va
        self.cfg, self.weights, self.rng, self.log = cfg, weights, rng, log
        # Under torchrun: DDP, and each rank's own augmentation stream (the epoch's order
        # comes from the shared one, the same on every rank).
        self.net = distributed.wrap(model)
        self.aug_rng = (np.random.default_rng([cfg.seed, distributed.rank()])
                        if distributed.active() else rng)
        self.opt = torch.optim.Adam(param_groups(model, cfg.lr, cfg.encoder_lr_scale),
                                    lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.feat_mean = model.feat_mean.detach().cpu().numpy().copy()
        self.best = (math.inf, -1, copy.deepcopy(model.state_dict()))
        # A run without validation (a refit) averages its last epochs' weights from here on
        # (``cfg.average_last``; torch's stochastic weight averaging).
        self.average_from = (cfg.epochs - max(1, round(cfg.average_last * cfg.epochs))
                             if va.size == 0 and cfg.average_last > 0 else None)
        self.average: AveragedModel | None = None
        self.history: list[dict[str, float]] = []
        self.train_time_s = 0.0
        self.stop_reason = ""           # set once no epoch is left: max_epochs | early_stopping
        # Called with ``state_dict()`` after each epoch (``aslip train --resume``).
        self.on_epoch: Callable[[dict[str, Any]], None] | None = None

    @property
    def done(self) -> bool:
        return bool(self.stop_reason)

    @property
    def epochs_run(self) -> int:
        return len(self.history)

    def _epoch(self) -> None:
        epoch = len(self.history)
        order = epoch_indices(self.tr, self.data.moving, self.cfg.noslip_ratio, self.rng)
        train_loss = _train_epoch(self.model, self.data, order, self.opt, self.feat_mean,
                                  self.aug_rng, self.cfg, self.weights, f"epoch {epoch}",
                                  self.net)
        val_loss = (evaluate_loss(self.model, self.data, self.va, self.weights)[0]
                    if self.va.size else None)
        self.history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss,
                             "time_s": self.train_time_s})
        if self.cfg.progress:
            self.log(f"epoch {epoch:3d}  train {train_loss:.4f}  val "
                     + ("-" if val_loss is None else f"{val_loss:.4f}"))
        if val_loss is None:
            # No validation (the final model of a cross-validated choice): ``cfg.epochs``,
            # chosen on the folds, sets the stop, and the last epoch is the model, or the
            # mean of the last epochs' weights; no loss to record (None, not NaN: the
            # checkpoint is strict JSON).
            self.best = (None, epoch, self._averaged(epoch))
        elif val_loss < self.best[0]:
            self.best = (val_loss, epoch, copy.deepcopy(self.model.state_dict()))
        elif epoch - self.best[1] >= self.cfg.patience:
            self.stop_reason = "early_stopping"
        if not self.stop_reason and epoch + 1 >= self.cfg.epochs:
            self.stop_reason = "max_epochs"

    def _averaged(self, epoch: int) -> dict[str, Any]:
        """The weights of a run without validation after ``epoch``: the epoch's own, or from
        ``average_from`` on their running mean (BatchNorm statistics averaged with them)."""
        if self.average_from is None or epoch < self.average_from:
            return self.model.state_dict()
        if self.average is None:
            self.average = AveragedModel(self.model, use_buffers=True)
        self.average.update_parameters(self.model)
        return self.average.module.state_dict()

    def state_dict(self) -> dict[str, Any]:
        """Everything the next epoch depends on: weights, optimiser, best epoch, history,
        time trained, stop reason and both random streams (learn/training/resume.py)."""
        return {"model": self.model.state_dict(), "opt": self.opt.state_dict(),
                "average": None if self.average is None else self.average.state_dict(),
                "best": self.best, "history": self.history,
                "train_time_s": self.train_time_s, "stop_reason": self.stop_reason,
                "rng": self.rng.bit_generator.state, "torch_rng": torch.get_rng_state()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Go on from ``state_dict()``'s epoch."""
        self.model.load_state_dict(state["model"])
        self.opt.load_state_dict(state["opt"])
        if state.get("average") is not None:
            self.average = AveragedModel(self.model, use_buffers=True)
            self.average.load_state_dict(state["average"])
        self.best = tuple(state["best"])
        self.history = list(state["history"])
        self.train_time_s = float(state["train_time_s"])
        self.stop_reason = str(state["stop_reason"])
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])

    def advance(self, seconds: float) -> None:
        """Train whole epochs until ``seconds`` of this slice have passed (at least one)."""
        t0 = distributed.now()          # rank 0's clock: every rank stops at one epoch
        while not self.done:
            self._epoch()
            elapsed = distributed.now() - t0
            self.history[-1]["time_s"] = self.train_time_s + elapsed
            if self.on_epoch is not None:
                self.on_epoch(dict(self.state_dict(), train_time_s=self.train_time_s + elapsed))
            if elapsed > seconds:
                break
        self.train_time_s += distributed.now() - t0

    def best_state(self) -> dict[str, Any]:
        return self.best[2]

    def finish(self, stop_reason: str = "time_budget") -> Fit:
        """Load the best epoch's weights; ``stop_reason`` names why a run that still had
        epochs left ended."""
        self.model.load_state_dict(self.best[2])
        return Fit(self.best[0], self.best[1], self.stop_reason or stop_reason,
                   self.train_time_s, self.history)


# --- the job and the stages ------------------------------------------------------------

def _init_name(init: str | os.PathLike | Checkpoint | None) -> str | None:
    if isinstance(init, Checkpoint):
        return "in memory, pretrained on " + str(init.meta.get("provenance", {}).get("dataset"))
    return str(init) if init else None


def _open_init(ds: WindowSet, init: str | os.PathLike | Checkpoint | None
               ) -> Checkpoint | None:
    """The checkpoint to start from, checked against the dataset (None without one)."""
    init_ckpt = init if isinstance(init, Checkpoint) else load_checkpoint(init) if init else None
    if init_ckpt is None:
        return None
    if init_ckpt.model_type != CNN:
        raise ValueError("--init must be a CNN checkpoint")
    init_ckpt.check_compatible(ds.sample_rate, [ds.channel_names[c] for c in
                                                ds.channel_indices(init_ckpt.channel_names)])
    if int(init_ckpt.meta["window_samples"]) != ds.window_samples:
        raise ValueError("the --init checkpoint was trained on another window length")
    return init_ckpt


def _init_model(init_ckpt: Checkpoint, angular: bool) -> SlipNet:
    """The init's network; with ``angular`` and an init without a rotational head, a new
    head (randomly initialised) beside its trained weights."""
    cfg = ModelConfig.from_dict(init_ckpt.meta["model_config"])
    if not angular or cfg.angular:
        model = SlipNet(cfg)
        model.load_state_dict(init_ckpt.tensors)
        return model
    model = SlipNet(dataclasses.replace(cfg, angular=True))
    missing, unexpected = model.load_state_dict(init_ckpt.tensors, strict=False)
    if unexpected or any(not k.startswith("heads.angular.") for k in missing):
        raise ValueError(f"the --init checkpoint's weights do not fit its model config "
                         f"(missing {missing}, unexpected {unexpected})")
    return model


def _build_model(ds: WindowSet, init_ckpt: Checkpoint | None, feats: np.ndarray,
                 tr: np.ndarray, channels: list[str], fcfg: FeatureConfig,
                 model_options: dict[str, Any] | None, rng: np.random.Generator) -> SlipNet:
    """The init checkpoint's network, or a new one normalised on the training windows with
    the median training slip speed as its speed scale; with a rotational head when the
    training windows carry angular labels."""
    angular = ds.has_angular(tr)
    if init_ckpt is not None:
        return _init_model(init_ckpt, angular)
    mean, std = normalization_stats(feats[np.sort(tr)] if tr.size <= 20000 else
                                    feats[np.sort(rng.choice(tr, 20000, replace=False))])
    slip_speed = ds.speed(tr)[ds.slip(tr)]
    scale = float(np.median(slip_speed)) if slip_speed.size else 0.02
    options = {"angular": angular, **dict(model_options or {})}
    mcfg = ModelConfig(n_channels=len(channels), n_mels=fcfg.n_mels,
                       speed_scale=max(scale, 1e-4), **options)
    model = SlipNet(mcfg)
    model.set_normalization(mean, std)
    return model


def _cnn_meta(ds: WindowSet, cfg: TrainConfig, model: SlipNet, fcfg: FeatureConfig,
              channels: list[str], weights: LossWeights, cal: Any, prov: dict[str, Any]
              ) -> dict[str, Any]:
    return checkpoint_meta(
        CNN, model.cfg, fcfg, ds, channels, provenance=prov, calibration=cal,
        angular=model.cfg.angular,
        normalization={"mean": model.feat_mean.tolist(), "std": model.feat_std.tolist(),
                       "scope": "per mel bin over training windows, channels and frames"},
        loss_weights=weights.to_dict(), train_config=cfg.to_dict())


class CnnJob:
    """One CNN training run that can be paused: ``advance(seconds)`` trains whole epochs
    for about that long, ``val_metrics()`` scores the best epoch so far on the validation
    trials, ``result()`` ends the run with the best epoch's weights. ``train_cnn`` is one
    uninterrupted job; ``aslip train --stage auto`` resumes the candidates that survive
    each round of its budget allocator (learn/training/recipes.py). ``trainable``: None
    trains every weight; a tuple freezes the encoder but for the parts it names
    (``aslip_cnn.ENCODER_PARTS``; the stage functions below choose)."""

    def __init__(self, ds: WindowSet, cfg: TrainConfig, *,
                 trainable: Sequence[str] | None = None,
                 feature_config: FeatureConfig | None = None,
                 model_options: dict[str, Any] | None = None,
                 channels: Sequence[str] | None = None,
                 init: str | os.PathLike | Checkpoint | None = None,
                 weights: LossWeights = LossWeights(),
                 cache_dir: str | os.PathLike | None = None,
                 state: JobState | None = None,
                 log: Callable[[str], None] = print) -> None:
        torch.set_num_threads(max(1, cfg.threads))
        self.device = resolve_device(cfg.device)
        seed_everything(cfg.seed)
        rng = np.random.default_rng(cfg.seed)
        init_ckpt = _open_init(ds, init)
        if init_ckpt is not None:   # the init's channels and features: its weights read those
            channels = init_ckpt.channel_names
            feature_config = FeatureConfig.from_dict(init_ckpt.meta["feature_config"])
        self.channels = list(channels or ds.channel_names)
        self.fcfg = feature_config or FeatureConfig()
        self.ds, self.cfg, self.weights, self.init = ds, cfg, weights, init
        self.init_ckpt = init_ckpt

        t0 = time.perf_counter()
        with distributed.rank0_first():         # one rank writes the cache, the others read
            feats = feature_cache(ds, self.fcfg, self.channels, cache_dir,
                                  progress=cfg.progress)
        self.tr, self.va = split_windows(ds, cfg)
        reuse = None if init_ckpt is None else init_ckpt.meta.get("calibration")
        self.cal, offsets = training_calibration(ds, cfg.calibration, self.channels, self.fcfg,
                                                 self.tr, self.va, reuse, log)
        self.feature_time_s = time.perf_counter() - t0
        self.data = Batches(feats, ds, offsets)
        self.model = _build_model(ds, init_ckpt, feats, self.tr, self.channels, self.fcfg,
                                  model_options, rng)
        if trainable is not None:
            self.model.freeze_encoder(trainable)
        self.model.to(self.device)
        self.run = EpochRun(self.model, self.data, self.tr, self.va, cfg, weights, rng, log)
        if state is not None:
            self._resume(state, model_options, log)

    def _resume(self, state: JobState, model_options: dict[str, Any] | None,
                log: Callable[[str], None]) -> None:
        """Go on from ``state``'s last epoch where it has one; save it after each epoch."""
        built_from = {"config": {k: v for k, v in dataclasses.asdict(self.cfg).items()
                                 if k not in RESUME_FREE},
                      "dataset": self.ds.fingerprint(), "channels": self.channels,
                      "features": self.fcfg.to_dict(), "model": dict(model_options or {}),
                      "init": _init_name(self.init)}
        saved = state.load(built_from)
        if saved is not None:
            self.run.load_state_dict(saved)
            log(f"resumed from {state.path} after epoch {self.run.epochs_run - 1} "
                f"({self.run.train_time_s:.0f} s trained)")
        self.run.on_epoch = state.save if distributed.is_main() else None

    @property
    def done(self) -> bool:
        return self.run.done

    @property
    def train_time_s(self) -> float:
        return self.run.train_time_s

    def advance(self, seconds: float) -> None:
        self.run.advance(seconds)

    def _predict_val(self) -> dict[str, np.ndarray]:
        _, pred = evaluate_loss(self.model, self.data, self.va, self.weights)
        return pred

    def val_predictions(self) -> dict[str, Any]:
        """The best epoch's predictions on the validation windows (``va``, in order);
        training resumes from the current weights."""
        current = copy.deepcopy(self.model.state_dict())
        self.model.load_state_dict(self.run.best_state())
        pred = self._predict_val()
        self.model.load_state_dict(current)
        return pred

    @property
    def best_epoch(self) -> int:
        return self.run.best[1]

    def val_metrics(self) -> dict[str, Any]:
        """The best epoch's validation metrics; training resumes from the current weights."""
        pred = self.val_predictions()
        return compute_metrics(pred["prob"], pred["v"], self.data.v[self.va],
                               self.data.slip[self.va], self.ds.window_s,
                               **rotation_args(self.ds, self.va, pred["w"]))

    def result(self, stop_reason: str = "time_budget") -> TrainResult:
        """End the run: the best epoch's weights, its metrics and the checkpoint document."""
        fit = self.run.finish(stop_reason)
        ds, cfg, data, va = self.ds, self.cfg, self.data, self.va
        pred = self._predict_val() if va.size else None
        model = self.model.to("cpu")
        val_metrics = {} if pred is None else compute_metrics(
            pred["prob"], pred["v"], data.v[va], data.slip[va], ds.window_s,
            **rotation_args(ds, va, pred["w"]))
        prov = provenance(ds, cfg, _init_name(self.init))
        prov["device"] = str(self.device)
        if self.init_ckpt is not None:
            prov["init_provenance"] = {k: self.init_ckpt.meta.get("provenance", {}).get(k)
                                       for k in ("dataset", "stage", "seed", "git_revision")}
        prov.update(metrics={"val": val_metrics, "best_val_loss": fit.best_loss},
                    training={"best_epoch": fit.best_epoch, "epochs_run": len(fit.history),
                              "stop_reason": fit.stop_reason,
                              "train_time_s": fit.train_time_s,
                              "feature_time_s": self.feature_time_s,
                              "n_train_windows": int(self.tr.size),
                              "n_val_windows": int(va.size)})
        meta = _cnn_meta(ds, cfg, model, self.fcfg, self.channels, self.weights, self.cal,
                         prov)
        if pred is not None:     # without validation the caller fits them (folds.refit)
            meta.update(checkpoint_fields(pred["prob"], pred["v"], data.v[va],
                                          data.slip[va], w_pred=pred["w"],
                                          w_true=data.w[va]))
        model.eval()
        tensors = {k: v.detach().clone() for k, v in model.state_dict().items()}
        return TrainResult(meta=meta, tensors=tensors, history=fit.history, model=model,
                           val_pred=pred)


def pretrain(ds: WindowSet, cfg: TrainConfig, **kw: Any) -> CnnJob:
    """Every weight on (robot-induced) data, from a random start (or ``init``): a
    checkpoint to finetune from."""
    return CnnJob(ds, cfg, **kw)


def finetune(ds: WindowSet, cfg: TrainConfig, *,
             init: str | os.PathLike | Checkpoint | None = None, **kw: Any) -> CnnJob:
    """From ``init`` (a path or a loaded checkpoint; its channels, features and
    calibration): the heads, with the encoder frozen but for ``cfg.finetune_trainable``
    (the paper's: all frozen)."""
    if init is None:
        raise ValueError("--stage finetune needs --init <checkpoint>")
    return CnnJob(ds, cfg, init=init, trainable=cfg.finetune_trainable, **kw)


def scratch(ds: WindowSet, cfg: TrainConfig, **kw: Any) -> CnnJob:
    """Every weight on this dataset, from a random start (or ``init``)."""
    return CnnJob(ds, cfg, **kw)


#: The CNN's stages of ``aslip train`` (``CnnBackend.stages``), by name.
STAGES: dict[str, Callable[..., CnnJob]] = {
    "pretrain": pretrain, "finetune": finetune, "scratch": scratch}


def train_cnn(ds: WindowSet, cfg: TrainConfig, **kw: Any) -> TrainResult:
    """Stage ``cfg.stage`` (``STAGES``) trained without a pause on ``cfg.device``, within
    ``cfg.time_budget_s``. Keywords: the job's (``CnnJob``: ``feature_config``,
    ``model_options``, ``channels``, ``init``, ``weights``, ``cache_dir``, ``log``)."""
    job = STAGES[cfg.stage](ds, cfg, **kw)
    left = cfg.time_budget_s - job.train_time_s      # a resumed job has trained already
    if left > 0 or not job.run.epochs_run:
        job.advance(left)
    return job.result()


def fit(ds: WindowSet, train_idx: np.ndarray, *, channels: Sequence[str],
        feature_config: FeatureConfig, config: TrainConfig, **options: Any) -> TrainResult:
    """``CnnBackend.fit``, as ``learn.training.train.train_backend`` calls a model's fit:
    stage ``config.stage``. The CNN validates itself (early stopping on the validation
    trials, metrics on its feature cache), so it returns the whole ``TrainResult``; its job
    splits the dataset as the pipeline did (``training.data.split_windows``, of which
    ``train_idx`` is the training part). ``options``: the job's keywords."""
    return train_cnn(ds, config, channels=channels, feature_config=feature_config, **options)
