"""A test-only window model: p(slip) from the loudest microphone's level, direction from the
level differences between microphones (docs/design.md, "Extending").

It shows everything a new model needs: a config dataclass (the checkpoint's
``model_config``), a backend class with the ``learn.models.registry.ModelBackend`` members, and
``register_model`` before a checkpoint of its type is saved or loaded. ``write_checkpoint``
writes one with the package's one metadata builder, ``checkpoint.checkpoint_meta``.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from aslip_ros.learn.checkpoint import Checkpoint, checkpoint_meta, save_checkpoint
from aslip_ros.learn.features import FeatureConfig


@dataclass(frozen=True)
class LevelConfig:
    n_channels: int = 4
    speed_m_s: float = 0.03          # the one speed it reports

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class LevelModel:
    """Slip when the loudest channel's RMS is above ``level`` (a tensor of the checkpoint)."""

    model_type: ClassVar[str] = "test_level"
    config: ClassVar[type] = LevelConfig
    streaming: ClassVar[bool] = False

    def __init__(self, cfg: LevelConfig, level: float, mic_angles: np.ndarray) -> None:
        self.cfg, self.level, self.mic_angles = cfg, level, mic_angles

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        if model_config.n_channels != len(meta["channel_names"]):
            return [f"model_config.n_channels {model_config.n_channels} != "
                    f"{len(meta['channel_names'])} channel_names"]
        return []

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "LevelModel":
        cfg = LevelConfig(**ckpt.meta["model_config"])
        try:
            level = float(ckpt.tensors["level"])
            angles = ckpt.tensors["mic_angles"].numpy().astype(np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"test_level checkpoint tensors: {exc}") from exc
        return cls(cfg, level, angles)

    @classmethod
    def fit(cls, ds, train_idx: np.ndarray, *, channels, feature_config, config
            ) -> tuple[LevelConfig, dict[str, torch.Tensor]]:
        """The training stage: the level halfway (in dB) between the median loudest-channel
        RMS of the training trials' slip and no-slip windows."""
        cols = ds.channel_indices(channels)
        rms = np.concatenate([
            np.sqrt((ds.window_audio(train_idx[s:s + 256], cols).astype(np.float64) ** 2)
                    .mean(axis=1)).max(axis=1) for s in range(0, train_idx.size, 256)])
        slip = ds.slip(train_idx)
        level = float(np.sqrt(np.median(rms[slip]) * np.median(rms[~slip])))
        n = len(channels)
        angles = 2 * np.pi * np.arange(n) / n + np.pi / 4     # learn/synthetic.py's mics
        return LevelConfig(n_channels=n), {"level": torch.tensor(level),
                                           "mic_angles": torch.from_numpy(angles)}

    def predict(self, windows: np.ndarray, offsets: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray]:
        rms = np.sqrt((windows.astype(np.float64) ** 2).mean(axis=1))       # (B, C)
        if offsets is not None:          # natural-log power removed: amplitude / exp(o / 2)
            rms = rms / np.exp(offsets / 2.0)
        prob = 1.0 / (1.0 + np.exp(-50.0 * (rms.max(axis=1) / self.level - 1.0)))
        d = rms @ np.stack([np.cos(self.mic_angles), np.sin(self.mic_angles)], axis=1)
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        return prob.astype(np.float32), (self.cfg.speed_m_s * d).astype(np.float32)


def write_checkpoint(path: str | os.PathLike, ds, level: float = 0.01) -> str:
    """A ``test_level`` checkpoint for dataset ``ds`` (a ``learn.data_io.WindowSet``)."""
    n = len(ds.channel_names)
    angles = 2 * np.pi * np.arange(n) / n + np.pi / 4     # learn/synthetic.py's microphones
    meta = checkpoint_meta(LevelModel.model_type, LevelConfig(n_channels=n), FeatureConfig(),
                           ds, ds.channel_names, normalization=None,
                           provenance={"dataset": str(ds.root), "stage": "test"})
    save_checkpoint(path, meta, {"level": torch.tensor(level),
                                 "mic_angles": torch.from_numpy(angles)})
    return str(path)
