"""Training data: the log-mel feature cache, the by-trial split and labelled batches.

Log-mel features of every dataset window are computed once per (dataset, feature config,
channels) with the shared ``features.LogMel`` and cached as a float16 ``.npy`` beside the
dataset, memory-mapped on later runs; epochs then cost only the network.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from aslip_ros.util import atomic_path

from aslip_ros.learn.data_io import WindowSet, select_windows
from aslip_ros.learn.features import FeatureConfig, LogMel
from aslip_ros.learn.training.config import TrainConfig
from aslip_ros.slip import ROTATION_EPSILON_RAD_S


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
            ds.release_audio()      # resident memory flat in the hours read
        out.flush()
        del out
    return np.load(path, mmap_mode="r")


def split_windows(ds: WindowSet, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation window indices (by trial, with the config's filters). With
    ``cfg.val_trials`` the split's training and validation trials are shared out again:
    those trials validate, the rest train (``()``: all train, the validation is empty)."""
    kw = dict(induced=cfg.induced, objects=cfg.objects, conditions=cfg.conditions,
              seed=cfg.split_seed)
    tr = select_windows(ds, "train", **kw)
    va = select_windows(ds, "val", **kw)
    if cfg.val_trials is not None:
        dev = np.sort(np.concatenate([tr, va]))
        held = np.isin(np.asarray(ds.windows["trial"])[dev],
                       np.asarray(cfg.val_trials, dtype=np.int64))
        tr, va = dev[~held], dev[held]
        if tr.size == 0:
            raise ValueError(f"no training windows in {ds.root} once trials "
                             f"{list(cfg.val_trials)} are held out")
        return tr, va
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


def rotation_args(ds: WindowSet, idx: np.ndarray, w_pred: np.ndarray | None
                  ) -> dict[str, Any]:
    """``compute_metrics``' rotational arguments for windows ``idx`` (none when they have no
    angular label): the labels and the model's raw rates (None: no rotational output)."""
    w_true = ds.angular(idx)
    if not np.isfinite(w_true).any():
        return {}
    return {"angular": w_pred, "true_angular": w_true}


class Batches:
    """Tensors for index batches from the feature cache and labels.

    ``moving``: windows that slip in the plane or rotate (``|wy|`` above
    ``ROTATION_EPSILON_RAD_S``): the ones every epoch draws (``loop.epoch_indices``), so a
    pure rotation, planar no-slip, is not thinned out with the still windows. Without
    angular labels it is the planar ``slip``.
    """

    #: Batches read between two openings of a memory-mapped feature cache: the mapping's
    #: resident pages are dropped that often (``x``), so that training's resident memory
    #: does not grow with the hours in the cache.
    REMAP_BATCHES = 64

    def __init__(self, feats: np.ndarray, ds: WindowSet,
                 offsets: np.ndarray | None = None) -> None:
        self.feats = feats
        self._reads = 0
        self.offsets = offsets          # (n_windows, C) per-grasp calibration, or None
        all_idx = np.arange(len(ds))
        self.v = ds.velocity(all_idx)
        self.slip = ds.slip(all_idx)
        self.w = ds.angular(all_idx)    # rad/s, NaN: no angular label
        self.moving = self.slip | (np.abs(np.nan_to_num(self.w)) > ROTATION_EPSILON_RAD_S)
        self.prev = ds.previous_index()

    def labels(self, b: np.ndarray, device: torch.device | str = "cpu"
               ) -> dict[str, torch.Tensor]:
        prev = self.prev[b]
        valid = prev >= 0
        pv = np.where(valid[:, None], self.v[np.maximum(prev, 0)], 0.0).astype(np.float32)
        valid &= self.slip[np.maximum(prev, 0)]
        return {"v_true": torch.from_numpy(self.v[b]).to(device),
                "slip": torch.from_numpy(self.slip[b]).to(device),
                "prev_v_true": torch.from_numpy(pv).to(device),
                "prev_valid": torch.from_numpy(valid).to(device),
                "w_true": torch.from_numpy(self.w[b]).to(device)}

    def x(self, b: np.ndarray) -> np.ndarray:
        self._reads += 1
        path = getattr(self.feats, "filename", None)
        if path and self._reads % self.REMAP_BATCHES == 0:
            self.feats = np.load(path, mmap_mode="r")
        # Sorted reads are much faster on a memory map; restore the batch order after.
        order = np.argsort(b)
        out = np.empty((b.size,) + self.feats.shape[1:], dtype=np.float32)
        out[order] = self.feats[b[order]]
        if self.offsets is not None:
            out -= self.offsets[b][:, :, None, None]
        return out
