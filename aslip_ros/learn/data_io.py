"""The learning code's view of an exported dataset (docs/design.md, "Dataset on disk").

Reading and splitting belong to ``aslip_ros.data.dataset`` (``Dataset``, ``split_trials``);
``WindowSet`` wraps that reader with the batched, label-array accessors training and
evaluation need. Splits are by trial, never by window, and come from the data package's
helper so every consumer of a dataset sees the same split.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from aslip_ros.data.dataset import Dataset
from aslip_ros.slip import ANGULAR_COMPONENT, VELOCITY_COMPONENTS


@dataclass
class WindowSet:
    """An opened dataset. Arrays index windows; ``trials`` index the manifest's trials."""

    dataset: Dataset

    def __post_init__(self) -> None:
        # The structured windows are small (a few MB at 10^5 rows); read them once.
        self.windows = np.asarray(self.dataset.windows)

    # --- manifest facts -------------------------------------------------------------------
    @property
    def root(self) -> Path:
        return self.dataset.path

    @property
    def manifest(self) -> dict[str, Any]:
        return self.dataset.manifest

    @property
    def sample_rate(self) -> float:
        return self.dataset.sample_rate

    @property
    def channel_names(self) -> list[str]:
        return list(self.dataset.channel_names)

    @property
    def layout(self) -> str | None:
        return self.dataset.layout

    @property
    def window_s(self) -> float:
        return self.dataset.window_s

    @property
    def window_samples(self) -> int:
        return self.dataset.n_window_samples

    @property
    def hop_s(self) -> float:
        return self.dataset.hop_s

    @property
    def epsilon(self) -> float:
        return self.dataset.epsilon_m_s

    @property
    def trials(self) -> list[dict[str, Any]]:
        return self.dataset.trials

    def __len__(self) -> int:
        return int(self.windows.shape[0])

    # --- per-window views -----------------------------------------------------------------
    def trial_field(self, key: str, idx: np.ndarray | None = None,
                    default: str = "") -> np.ndarray:
        """A manifest trial field (e.g. ``object``) broadcast to windows, as a str array."""
        per_trial = np.array([str(t.get(key, default)) for t in self.trials], dtype=object)
        w = self.windows["trial"] if idx is None else self.windows["trial"][idx]
        return per_trial[w]

    def velocity(self, idx: np.ndarray) -> np.ndarray:
        """(n, N_VELOCITY) float32: the slip velocity label per component, in m/s."""
        w = self.windows[idx]
        return np.stack([w[c] for c in VELOCITY_COMPONENTS], axis=1).astype(np.float32)

    def angular(self, idx: np.ndarray) -> np.ndarray:
        """(n,) float32: the rotational slip label ``wy`` [rad/s]; NaN where a window has no
        angular label (a version 1 dataset, or a recording without one)."""
        if ANGULAR_COMPONENT not in (self.windows.dtype.names or ()):
            return np.full(self.windows["trial"][idx].shape, np.nan, np.float32)
        return self.windows[ANGULAR_COMPONENT][idx].astype(np.float32)

    def has_angular(self, idx: np.ndarray | None = None) -> bool:
        """Whether any of the windows ``idx`` (default: all) has an angular label."""
        w = self.angular(np.arange(len(self)) if idx is None else idx)
        return bool(np.isfinite(w).any())

    def slip(self, idx: np.ndarray) -> np.ndarray:
        return self.windows["slip"][idx].astype(bool)

    def speed(self, idx: np.ndarray) -> np.ndarray:
        return self.windows["speed"][idx].astype(np.float32)

    def audio(self, k: int) -> np.ndarray:
        """Trial ``k``'s audio, (n_samples, n_channels) float32, memory-mapped."""
        arr = self.dataset.audio(int(k))
        if arr.ndim != 2 or arr.shape[1] != len(self.channel_names):
            raise ValueError(f"{self.trials[k]['file']}: shape {arr.shape} does not match "
                             f"{len(self.channel_names)} channels")
        return arr

    def release_audio(self) -> None:
        """Drop the audio maps read so far (``Dataset.release_audio``)."""
        self.dataset.release_audio()

    def window_audio(self, idx: Sequence[int] | np.ndarray,
                     channels: Sequence[int] | None = None) -> np.ndarray:
        """(n, window_samples, C) float32 audio of the given windows (optionally some channels)."""
        idx = np.asarray(idx, dtype=np.int64)
        n = self.window_samples
        cols = slice(None) if channels is None else list(channels)
        n_c = len(self.channel_names) if channels is None else len(channels)
        out = np.empty((idx.size, n, n_c), dtype=np.float32)
        for j, i in enumerate(idx):
            row = self.windows[i]
            a = self.audio(int(row["trial"]))
            s = int(row["start"])
            if s < 0 or s + n > a.shape[0]:
                raise ValueError(f"window {i} [{s}, {s + n}) is outside its trial's audio")
            out[j] = a[s:s + n][:, cols]
        return out

    def previous_index(self) -> np.ndarray:
        """For each window, the index of the preceding window of the same trial, else -1."""
        order = np.lexsort((self.windows["start"], self.windows["trial"]))
        prev = np.full(len(self), -1, dtype=np.int64)
        same = self.windows["trial"][order[1:]] == self.windows["trial"][order[:-1]]
        prev[order[1:][same]] = order[:-1][same]
        return prev

    def channel_indices(self, names: Sequence[str]) -> list[int]:
        """Column indices of ``names``; ValueError naming any the dataset lacks."""
        have = self.channel_names
        missing = [n for n in names if n not in have]
        if missing:
            raise ValueError(f"dataset {self.root} has no channels {missing} (has {have})")
        return [have.index(n) for n in names]

    def fingerprint(self) -> str:
        """Short content hash of the manifest and windows: keys feature caches."""
        h = hashlib.sha1()
        h.update(json.dumps(self.manifest, sort_keys=True).encode())
        h.update(np.ascontiguousarray(self.windows).tobytes())
        return h.hexdigest()[:16]


def open_dataset(path: str | os.PathLike) -> WindowSet:
    """Open ``<dataset>/`` with the data package's reader; ValueError when it is not one."""
    return WindowSet(Dataset(path))


def trial_splits(ds: WindowSet, seed: int = 0) -> list[str]:
    """Split name per manifest trial (``Dataset.trial_splits``: made over all trials, so a
    trial keeps its split whatever subset a model is trained or evaluated on)."""
    return ds.dataset.trial_splits(seed)


def select_windows(ds: WindowSet, split: str = "all", *, induced: str | None = None,
                   objects: Sequence[str] | None = None, conditions: Sequence[str] | None = None,
                   seed: int = 0) -> np.ndarray:
    """Indices of windows in ``split`` ("train", "val", "test" or "all"), optionally filtered
    (``Dataset.select``)."""
    filters = {k: v for k, v in (("induced", induced), ("object", objects),
                                 ("condition", conditions)) if v}
    return ds.dataset.select(split, seed=seed, **filters)
