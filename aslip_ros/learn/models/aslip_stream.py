"""The causal streaming slip network: per-frame embedding and a GRU, stepped one hop at a time.

Input: one log-mel frame per 10 ms hop, ``(C, M)`` from ``streaming.StreamingLogMel``,
normalised per mel bin with the training statistics the model holds. Each frame goes
through a two-layer embedding (all microphones together: their level differences carry
the direction) into a GRU whose state is the only memory; the heads read the state and
give the slip logit and the slip velocity now, ``(vx, vz)`` in units of ``speed_scale``,
and, for a model built with ``StreamConfig.angular``, the rotational rate ``wy`` now (its
output is the rim speed ``wy * ROTATION_RADIUS_M`` in units of ``speed_scale``).

Why a GRU rather than a cached causal dilated convolution: one step on a 96-wide state is
a few small matrix-vector products (measured ~20 us p50 in numpy, against ~55 us for the
frame's features), its memory is not capped by a receptive field, and a reset is one zero
vector, where a dilated convolution keeps a frame cache per layer. A convolutional variant
was not trained for comparison (docs/streaming.md).

``StreamNet.forward`` runs whole sequences (training, offline evaluation); ``GruStepper``
is the same arithmetic in numpy for one frame at a time (the live path: torch's per-call
overhead alone exceeds the budget of a hop). Tests hold the two to the same outputs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from aslip_ros.learn.checkpoint import Checkpoint, angular_problems
from aslip_ros.learn.incremental_features import stream_meta_problems
from aslip_ros.learn.models.registry import load_weights, register_model
from aslip_ros.slip import ROTATION_RADIUS_M


@dataclass(frozen=True)
class StreamConfig:
    """Architecture of the streaming net; stored in the checkpoint's ``model_config``.
    ``angular``: a fourth head output, the rotational rate (False for every checkpoint
    trained before it existed). ``context``: how many of the newest frames the embedding
    reads together (1, every checkpoint before it existed: the current frame alone; the
    frames before a sequence's first read as the feature mean)."""

    n_channels: int = 4
    n_mels: int = 40
    embed: int = 128
    hidden: int = 96
    speed_scale: float = 0.02
    angular: bool = False
    context: int = 1

    def __post_init__(self) -> None:
        if min(self.n_channels, self.n_mels, self.embed, self.hidden, self.context) < 1:
            raise ValueError("n_channels, n_mels, embed, hidden and context must be >= 1")
        if not self.speed_scale > 0:
            raise ValueError("speed_scale must be > 0")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "StreamConfig":
        return cls(**d)


class StreamNet(nn.Module):
    """``forward(x (B, T, C, M), h0 (1, B, H) or None) -> (logit (B, T), v (B, T, 2),
    w (B, T) or None, h)``; ``v`` in m/s, ``w`` the rate wy in rad/s (None without the
    rotational output)."""

    def __init__(self, cfg: StreamConfig) -> None:
        super().__init__()
        self.cfg = cfg
        n_in = cfg.n_channels * cfg.n_mels * cfg.context
        self.register_buffer("feat_mean", torch.zeros(cfg.n_mels))
        self.register_buffer("feat_std", torch.ones(cfg.n_mels))
        self.embed1 = nn.Linear(n_in, cfg.embed)
        self.embed2 = nn.Linear(cfg.embed, cfg.embed)
        self.gru = nn.GRU(cfg.embed, cfg.hidden, batch_first=True)
        self.head = nn.Linear(cfg.hidden, 4 if cfg.angular else 3)

    def set_normalization(self, mean: np.ndarray, std: np.ndarray) -> None:
        self.feat_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.feat_std.copy_(torch.as_tensor(std, dtype=torch.float32))

    def forward(self, x: torch.Tensor, h0: torch.Tensor | None = None):
        b, t = x.shape[:2]
        z = ((x - self.feat_mean) / self.feat_std).reshape(b, t, -1)
        k = self.cfg.context
        if k > 1:   # (B, T, k * F): the k newest frames, oldest first, zeros before the start
            z = F.pad(z, (0, 0, k - 1, 0)).unfold(1, k, 1).transpose(2, 3).reshape(b, t, -1)
        z = torch.relu(self.embed2(torch.relu(self.embed1(z))))
        y, h = self.gru(z, h0)
        out = self.head(y)
        w = out[..., 3] * _rate_scale(self.cfg) if self.cfg.angular else None
        return out[..., 0], out[..., 1:3] * self.cfg.speed_scale, w, h


def _rate_scale(cfg: StreamConfig) -> float:
    """rad/s per unit of the rotational output (the rim speed in ``speed_scale`` units)."""
    return cfg.speed_scale / ROTATION_RADIUS_M


class GruStepper:
    """One frame at a time in numpy, with the weights of a ``StreamNet`` state dict."""

    def __init__(self, cfg: StreamConfig, state: dict[str, torch.Tensor]) -> None:
        def w(name: str) -> np.ndarray:
            return state[name].detach().cpu().numpy().astype(np.float32)

        self.cfg = cfg
        self.inv_std = (1.0 / w("feat_std")).astype(np.float32)
        self.mean = w("feat_mean")
        self.w1, self.b1 = np.ascontiguousarray(w("embed1.weight").T), w("embed1.bias")
        self.w2, self.b2 = np.ascontiguousarray(w("embed2.weight").T), w("embed2.bias")
        self.w_ih = np.ascontiguousarray(w("gru.weight_ih_l0").T)      # (E, 3H): r, z, n
        self.w_hh = np.ascontiguousarray(w("gru.weight_hh_l0").T)      # (H, 3H)
        self.b_ih, self.b_hh = w("gru.bias_ih_l0"), w("gru.bias_hh_l0")
        self.wh, self.bh = np.ascontiguousarray(w("head.weight").T), w("head.bias")
        n = cfg.n_channels * cfg.n_mels
        self.h = np.zeros(cfg.hidden, np.float32)
        self.z = np.zeros(n * cfg.context, np.float32)     # the newest frames, oldest first

    def reset(self) -> None:
        self.h = np.zeros(self.cfg.hidden, np.float32)
        self.z[:] = 0.0

    def step(self, frame: np.ndarray) -> tuple[float, np.ndarray, float | None]:
        """``frame (C, M)`` raw log-mel -> (p_slip, v (2,) m/s, wy rad/s or None without
        the rotational output); advances the state."""
        z = ((frame - self.mean) * self.inv_std).reshape(-1)
        if self.cfg.context > 1:
            self.z[:-z.size] = self.z[z.size:]
            self.z[-z.size:] = z
            z = self.z
        z = np.maximum(z @ self.w1 + self.b1, 0.0)
        z = np.maximum(z @ self.w2 + self.b2, 0.0)
        hsz = self.cfg.hidden
        gi = z @ self.w_ih + self.b_ih
        gh = self.h @ self.w_hh + self.b_hh
        rz = 1.0 / (1.0 + np.exp(-(gi[:2 * hsz] + gh[:2 * hsz])))
        n = np.tanh(gi[2 * hsz:] + rz[:hsz] * gh[2 * hsz:])
        self.h = ((1.0 - rz[hsz:]) * n + rz[hsz:] * self.h).astype(np.float32)
        out = self.h @ self.wh + self.bh
        p = 1.0 / (1.0 + np.exp(-float(out[0])))
        w = float(out[3]) * _rate_scale(self.cfg) if self.cfg.angular else None
        return p, out[1:3] * np.float32(self.cfg.speed_scale), w


def offline_outputs(model: StreamNet, frames: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """p_slip ``(T,)``, v ``(T, 2)`` and wy ``(T,)`` (None without the rotational output)
    for one sequence ``(T, C, M)`` from a zero state."""
    with torch.inference_mode():
        logit, v, w, _ = model(torch.from_numpy(np.ascontiguousarray(frames, np.float32))[None])
    return (torch.sigmoid(logit[0]).numpy(), v[0].numpy(),
            None if w is None else w[0].numpy())


@register_model
class StreamBackend:
    """The causal streaming estimator, run per audio block by
    ``learn.inference.stream_predictor.StreamingPredictor``."""

    model_type: ClassVar[str] = "aslip_stream"
    config: ClassVar[type] = StreamConfig
    streaming: ClassVar[bool] = True

    def __init__(self, cfg: StreamConfig, net: StreamNet) -> None:
        self.cfg = cfg
        self.net = net.eval()

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        return (stream_meta_problems(meta, model_config, feature_config)
                + angular_problems(meta, model_config.angular))

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "StreamBackend":
        cfg = StreamConfig.from_dict(ckpt.meta["model_config"])
        net = load_weights(StreamNet(cfg), ckpt.tensors)
        return cls(cfg, net)

    def stepper(self) -> GruStepper:
        """A fresh per-hop stepper (numpy) over this network's weights."""
        return GruStepper(self.cfg, self.net.state_dict())

    def offline(self, frames: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Batched forward over ``(T, C, M)`` frames from a zero state: p, raw v, wy (None
        without the rotational output)."""
        return offline_outputs(self.net, frames)
