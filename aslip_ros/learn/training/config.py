"""What a training run is asked to do (``TrainConfig``) and what it gives (``TrainResult``),
where it runs (``resolve_device``) and what its checkpoint says of it (``provenance``).

The bottom of ``learn.training``: the batching, every model's fit (the CNN's:
learn/models/aslip_cnn_fit.py), the pipeline, the recipes and the command line all import
these and nothing here imports them.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from aslip_ros.learn.calibration.grasp import METHODS
from aslip_ros.learn.checkpoint import Checkpoint, git_revision, save_checkpoint
from aslip_ros.learn.data_io import WindowSet
from aslip_ros.learn.models.registry import has_fit, model_backend, model_types


def fit_stage(stage: str) -> type | None:
    """The backend whose ``fit`` trains stage ``stage`` (None: no model's stage): the
    built-in or registered one that names it among its ``stages`` (the CNN's pretrain,
    finetune and scratch; by default a model type's one stage is its own name), else an
    installed distribution's model type ``stage``."""
    for model_type in model_types():
        backend = model_backend(model_type)
        if stage in getattr(backend, "stages", (model_type,)):
            return backend if has_fit(backend) else None
    try:
        backend = model_backend(stage)
    except ValueError:
        return None
    return backend if stage in getattr(backend, "stages", (stage,)) and has_fit(backend) \
        else None


#: The built-in stages of ``aslip train``: auto, svm and stream run in learn/training/,
#: pretrain, finetune and scratch are the CNN's (its backend's ``stages``); a model type
#: whose backend defines ``fit`` is a stage too (``learn.training.train.train_backend``,
#: docs/design.md "Extending").
STAGES = ("auto", "pretrain", "finetune", "scratch", "svm", "stream")
DEVICES = ("auto", "cpu", "cuda")
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
    # SpecAugment masks, off by default: measured (``make magnitude``, docs/results.md), they
    # cost magnitude error in 4 of 4 runs and detection in 2, and helped nothing.
    freq_mask: int = 0             # max frequency-mask width; -1: n_mels // 8; 0: none
    time_mask: int = 0             # max time-mask width (frames); 0: none
    time_budget_s: float = 1140.0  # stop (keeping the best epoch) after this much training
    threads: int = 2
    progress: bool = True
    # Library default off (the experiment tables were measured so); ``aslip train``
    # defaults to background.
    calibration: str = "off"
    induced: str | None = None
    objects: tuple[str, ...] | None = None
    conditions: tuple[str, ...] | None = None
    device: str = "auto"           # auto | cpu | cuda (resolve_device): a GPU where there is one
    encoder_lr_scale: float = 1.0  # learning rate of trainable encoder weights, times lr
    # Encoder parts a finetune trains (network.ENCODER_PARTS); () is the paper's frozen one.
    finetune_trainable: tuple[str, ...] = ()
    # Trial indices (positions in the dataset's trial list) to validate on instead of the
    # split's validation trials; training then takes the split's other training and
    # validation trials. () trains on all of them and validates on none: the final model
    # of a cross-validated choice (learn/training/folds.py). None: the split's.
    val_trials: tuple[int, ...] | None = None
    # Share of a run without validation (``val_trials=()``: the final model of a choice on
    # folds) whose last epochs' weights are averaged into the model (stochastic weight
    # averaging); 0: the last epoch's weights. Measured (docs/results.md, "Averaging the
    # final model's last epochs"): one refit's test direction moved by up to 20 degrees
    # with its seed; averaging its last half kept it within the folds' interval.
    average_last: float = 0.5

    def __post_init__(self) -> None:
        if self.stage not in STAGES and fit_stage(self.stage) is None:
            raise ValueError(f"stage must be one of {STAGES} or a model type with a "
                             f"training stage (fit), got {self.stage!r}")
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
        if self.freq_mask < -1 or self.time_mask < 0:
            raise ValueError("freq_mask must be >= -1 and time_mask >= 0")
        if not 0.0 <= self.average_last <= 1.0:
            raise ValueError("average_last must be within [0, 1]")
        if not (self.gain_db >= 0 and self.channel_gain_db >= 0):
            raise ValueError("gain_db and channel_gain_db must be >= 0")

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for k in ("objects", "conditions"):
            d[k] = list(d[k]) if d[k] else None
        d["finetune_trainable"] = list(self.finetune_trainable)
        d["val_trials"] = (None if self.val_trials is None
                           else [int(t) for t in self.val_trials])
        return d


@dataclass
class TrainResult:
    meta: dict[str, Any]
    tensors: dict[str, torch.Tensor]
    history: list[dict[str, float]]
    model: Any = None
    # --stage auto: every candidate that finished, by name (the winner among them).
    candidates: dict[str, "TrainResult"] | None = None
    # The model's p(slip) and raw velocity on the validation windows, in their order
    # (``prob``, ``v``): selection's intervals over trials. Not saved.
    val_pred: dict[str, Any] | None = None

    def save(self, path: str | os.PathLike) -> Path:
        return save_checkpoint(path, self.meta, self.tensors)

    def checkpoint(self) -> Checkpoint:
        return Checkpoint(meta=self.meta, tensors=self.tensors)


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


def seed_everything(seed: int) -> None:
    """Seed torch's and numpy's global random streams."""
    torch.manual_seed(seed)
    np.random.seed(seed % (2 ** 32))


def provenance(ds: WindowSet, cfg: TrainConfig, init: str | None) -> dict[str, Any]:
    """The checkpoint's ``provenance`` of a run of ``cfg`` on ``ds`` (``init``: what it
    started from, None: a random start); the trainer adds its metrics and timings."""
    return {"dataset": str(Path(ds.root).resolve()), "dataset_fingerprint": ds.fingerprint(),
            "git_revision": git_revision(), "seed": cfg.seed, "split_seed": cfg.split_seed,
            "stage": cfg.stage, "init": init, "torch_version": torch.__version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "filters": {"induced": cfg.induced, "objects": cfg.to_dict()["objects"],
                        "conditions": cfg.to_dict()["conditions"]}}
