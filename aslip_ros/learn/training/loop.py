"""The CNN's epoch loop: augmentation, balanced epochs, early stopping, a time budget.

``resolve_device`` reads ``--device``: ``cpu`` (the default), ``cuda`` (an error naming the
cause when torch sees no CUDA GPU) or ``auto`` (CUDA where torch sees a GPU, else the CPU).
Features, augmentation and metrics stay on the CPU in numpy; only batches and the network
move, and the caller moves the network back before its weights are saved.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import torch

from aslip_ros.learn.training.losses import LossWeights, slip_loss
from aslip_ros.learn.models.aslip_cnn import SlipNet, output_arrays
from aslip_ros.learn.training.config import DEVICES, TrainConfig
from aslip_ros.learn.training.data import Batches


_DB_TO_LOG_POWER = math.log(10.0) / 10.0  # +1 dB amplitude-power gain in natural-log power


def resolve_device(name: str) -> torch.device:
    """The torch device for ``--device``; ValueError for ``cuda`` without a usable GPU."""
    if name not in DEVICES:
        raise ValueError(f"device must be one of {DEVICES}, got {name!r}")
    has_cuda = torch.cuda.is_available()
    if name == "cuda" and not has_cuda:
        raise ValueError("--device cuda but torch sees no CUDA GPU (torch "
                         f"{torch.__version__}, torch.cuda.is_available() is False); use "
                         "--device cpu, or auto to take a GPU only where there is one")
    return torch.device("cuda" if name == "cuda" or (name == "auto" and has_cuda) else "cpu")


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

    best_loss: float
    best_epoch: int
    stop_reason: str              # max_epochs | early_stopping | time_budget
    train_time_s: float
    history: list[dict[str, float]] = field(default_factory=list)


def _train_epoch(model: SlipNet, data: Batches, order: np.ndarray, opt: torch.optim.Optimizer,
                 feat_mean: np.ndarray, rng: np.random.Generator, cfg: TrainConfig,
                 weights: LossWeights, label: str) -> float:
    """One pass over ``order``; the mean training loss."""
    model.train()
    n_batches = max(1, order.size // cfg.batch_size)  # drop the ragged tail (BN stability)
    batches: Any = range(n_batches)
    if cfg.progress:
        from tqdm import tqdm
        batches = tqdm(batches, desc=label, unit="batch", leave=False)
    run_loss = 0.0
    dev = _device_of(model)
    for i in batches:
        b = order[i * cfg.batch_size:(i + 1) * cfg.batch_size]
        x = torch.from_numpy(augment(data.x(b), feat_mean, rng, cfg)).to(dev)
        out = model(x)
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
        self.opt = torch.optim.Adam(param_groups(model, cfg.lr, cfg.encoder_lr_scale),
                                    lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.feat_mean = model.feat_mean.detach().cpu().numpy().copy()
        self.best = (math.inf, -1, copy.deepcopy(model.state_dict()))
        self.history: list[dict[str, float]] = []
        self.train_time_s = 0.0
        self.stop_reason = ""           # set once no epoch is left: max_epochs | early_stopping

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
                                  self.rng, self.cfg, self.weights, f"epoch {epoch}")
        val_loss, _ = evaluate_loss(self.model, self.data, self.va, self.weights)
        self.history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss,
                             "time_s": self.train_time_s})
        if self.cfg.progress:
            self.log(f"epoch {epoch:3d}  train {train_loss:.4f}  val {val_loss:.4f}")
        if val_loss < self.best[0]:
            self.best = (val_loss, epoch, copy.deepcopy(self.model.state_dict()))
        elif epoch - self.best[1] >= self.cfg.patience:
            self.stop_reason = "early_stopping"
        if not self.stop_reason and epoch + 1 >= self.cfg.epochs:
            self.stop_reason = "max_epochs"

    def advance(self, seconds: float) -> None:
        """Train whole epochs until ``seconds`` of this slice have passed (at least one)."""
        t0 = time.perf_counter()
        while not self.done:
            self._epoch()
            elapsed = time.perf_counter() - t0
            self.history[-1]["time_s"] = self.train_time_s + elapsed
            if elapsed > seconds:
                break
        self.train_time_s += time.perf_counter() - t0

    def best_state(self) -> dict[str, Any]:
        return self.best[2]

    def finish(self, stop_reason: str = "time_budget") -> Fit:
        """Load the best epoch's weights; ``stop_reason`` names why a run that still had
        epochs left ended."""
        self.model.load_state_dict(self.best[2])
        return Fit(self.best[0], self.best[1], self.stop_reason or stop_reason,
                   self.train_time_s, self.history)
