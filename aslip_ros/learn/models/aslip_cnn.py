"""The A-SLIP slip network: channel attention, 2D conv blocks, temporal convs, attention pooling.

Input: raw log-mel features ``(B, C, M, T)`` from ``features.LogMel``; the model normalises
them with the dataset statistics it holds as buffers. Output: ``SlipOutput`` with the slip
logit ``(B,)``, the non-negative slip speed in m/s ``(B,)``, the unnormalised direction
``(B, 2)`` in the grasp plane (x along the fingers, z vertical) and, for a model built with
``ModelConfig.angular``, the rotational slip rate ``wy`` about the pad normal in rad/s
``(B,)`` (``aslip_ros.slip.ANGULAR_COMPONENT``; None without that head).

How "a learnable channel attention mechanism fuses the multi-microphone streams" is read
here (docs/model.md): the gate produces one weight per microphone and scales that
microphone's spectrogram; the weighted spectrograms then enter the first 2D convolution as
its input channels, whose learned mixing is the fusion. Summing the weighted channels into
one map instead would throw away the cross-microphone differences that carry direction.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple, Sequence

import numpy as np

import torch
from torch import nn
from torch.nn import functional as F

from aslip_ros.learn.checkpoint import Checkpoint, angular_problems
from aslip_ros.learn.features import FeatureConfig, LogMel
from aslip_ros.learn.models.registry import load_weights, register_model
from aslip_ros.slip import ROTATION_RADIUS_M


@dataclass(frozen=True)
class ModelConfig:
    """Architecture hyper-parameters; stored in the checkpoint and enough to rebuild the net.

    ``width`` is the channel count of the first 2D block, doubling per block up to
    ``4 * width``; ``depth`` is the number of 2D blocks (each halves the mel axis).
    ``speed_scale`` (m/s) sets the unit of the magnitude head so that its raw output is
    order one; training sets it to the median training slip speed. ``angular`` adds the
    rotational head (a model trained on windows with an angular label); its raw output is
    the rim speed ``wy * ROTATION_RADIUS_M`` in units of ``speed_scale``, so it is trained
    on the magnitude's scale. False for every checkpoint trained before it existed.
    """

    n_channels: int = 4
    n_mels: int = 40
    width: int = 16
    depth: int = 3
    temporal_layers: int = 2
    temporal_channels: int = 64
    temporal_kernel: int = 3
    gate_hidden: int = 8
    gate: str = "softmax"
    dropout: float = 0.1
    head_hidden: int = 32
    speed_scale: float = 0.02
    angular: bool = False

    def __post_init__(self) -> None:
        if self.n_channels < 1 or self.n_mels < 1:
            raise ValueError("n_channels and n_mels must be >= 1")
        if self.width < 1 or self.depth < 1 or self.temporal_channels < 1:
            raise ValueError("width, depth and temporal_channels must be >= 1")
        if self.temporal_layers < 0 or self.temporal_kernel < 1 or self.temporal_kernel % 2 == 0:
            raise ValueError("temporal_layers >= 0 and an odd temporal_kernel are required")
        if self.gate not in ("softmax", "sigmoid"):
            raise ValueError(f"gate must be 'softmax' or 'sigmoid', got {self.gate!r}")
        if not (0.0 <= self.dropout < 1.0) or self.speed_scale <= 0:
            raise ValueError("dropout in [0, 1) and speed_scale > 0 are required")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ModelConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown model parameters: {sorted(unknown)}")
        return cls(**d)


class SlipOutput(NamedTuple):
    logit: torch.Tensor       # (B,) slip logit; p(slip) = sigmoid(logit)
    magnitude: torch.Tensor   # (B,) slip speed, m/s, >= 0
    direction: torch.Tensor   # (B, 2) unnormalised (x, z) direction
    angular: torch.Tensor | None = None   # (B,) wy [rad/s]; None: no rotational head


class ChannelAttention(nn.Module):
    """Per-microphone weights from frequency-averaged spectrograms via a small temporal conv."""

    def __init__(self, n_channels: int, hidden: int, mode: str) -> None:
        super().__init__()
        self.mode = mode
        self.net = nn.Sequential(
            nn.Conv1d(n_channels, hidden, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv1d(hidden, n_channels, 3, padding=1),
        )

    def weights(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C) weights; softmax weights are scaled by C so their mean is one."""
        score = self.net(x.mean(dim=2)).mean(dim=2)  # (B, C, T) -> (B, C)
        if self.mode == "softmax":
            return torch.softmax(score, dim=1) * x.shape[1]
        return 2.0 * torch.sigmoid(score)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.weights(x)[:, :, None, None]


class FreqMaxPool(nn.Module):
    """Max over pairs of adjacent mel bins, every frame kept (an odd last bin is dropped).

    Same result as ``nn.MaxPool2d((2, 1))``; a reshape and ``amax`` is several times faster
    on CPU for these small maps, which matters for the 3 ms inference budget.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, m, t = x.shape
        return x[:, :, : m - m % 2].reshape(b, c, m // 2, 2, t).amax(dim=3)


class TemporalAttentionPool(nn.Module):
    """Softmax-weighted average over time with learned per-frame scores."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.score = nn.Conv1d(channels, 1, 1)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        a = torch.softmax(self.score(h), dim=2)  # (B, 1, T)
        return (h * a).sum(dim=2)


#: The encoder's sub-modules, input to output (``SlipNet.freeze_encoder(trainable=...)``).
ENCODER_PARTS = ("attention", "conv2d", "conv1d", "pool")


class Encoder(nn.Module):
    """Normalised log-mel ``(B, C, M, T)`` -> latent ``(B, temporal_channels)``."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.attention = ChannelAttention(cfg.n_channels, cfg.gate_hidden, cfg.gate)
        blocks: list[nn.Module] = []
        c_in, m = cfg.n_channels, cfg.n_mels
        for i in range(cfg.depth):
            c_out = cfg.width * 2 ** min(i, 2)
            blocks += [nn.Conv2d(c_in, c_out, 3, padding=1, bias=False),
                       nn.BatchNorm2d(c_out), nn.ReLU(inplace=True), nn.Dropout(cfg.dropout)]
            if m >= 2:
                # Pool frequency only: every frame survives to the temporal layers.
                blocks.append(FreqMaxPool())
                m //= 2
            c_in = c_out
        self.conv2d = nn.Sequential(*blocks)
        layers: list[nn.Module] = []
        c = c_in * m
        for _ in range(cfg.temporal_layers):
            layers += [nn.Conv1d(c, cfg.temporal_channels, cfg.temporal_kernel,
                                 padding=cfg.temporal_kernel // 2, bias=False),
                       nn.BatchNorm1d(cfg.temporal_channels), nn.ReLU(inplace=True),
                       nn.Dropout(cfg.dropout)]
            c = cfg.temporal_channels
        if cfg.temporal_layers == 0:
            layers.append(nn.Conv1d(c, cfg.temporal_channels, 1))
        self.conv1d = nn.Sequential(*layers)
        self.pool = TemporalAttentionPool(cfg.temporal_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.conv2d(self.attention(x))        # (B, W, M', T)
        h = h.flatten(1, 2)                       # (B, W * M', T)
        return self.pool(self.conv1d(h))


def _head(c_in: int, hidden: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(c_in, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, c_out))


class SlipNet(nn.Module):
    """The A-SLIP network. ``freeze_encoder()`` prepares head-only finetuning."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.register_buffer("feat_mean", torch.zeros(cfg.n_mels))
        self.register_buffer("feat_std", torch.ones(cfg.n_mels))
        self.encoder = Encoder(cfg)
        h = cfg.temporal_channels
        self.heads = nn.ModuleDict({
            "slip": _head(h, cfg.head_hidden, 1),
            "magnitude": _head(h, cfg.head_hidden, 1),
            "direction": _head(h, cfg.head_hidden, 2),
        })
        if cfg.angular:
            self.heads["angular"] = _head(h, cfg.head_hidden, 1)
        self._encoder_frozen = False

    def set_normalization(self, mean, std) -> None:
        """Install per-mel-bin statistics of the raw log-mel features."""
        mean = torch.as_tensor(mean, dtype=torch.float32).reshape(-1)
        std = torch.as_tensor(std, dtype=torch.float32).reshape(-1)
        if mean.numel() != self.cfg.n_mels or std.numel() != self.cfg.n_mels:
            raise ValueError(f"normalisation stats must have {self.cfg.n_mels} entries")
        if not (torch.isfinite(mean).all() and torch.isfinite(std).all() and (std > 0).all()):
            raise ValueError("normalisation stats must be finite with std > 0")
        self.feat_mean.copy_(mean)
        self.feat_std.copy_(std)

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.feat_mean[:, None]) / self.feat_std[:, None]

    def forward(self, x: torch.Tensor) -> SlipOutput:
        if x.ndim != 4 or x.shape[1] != self.cfg.n_channels or x.shape[2] != self.cfg.n_mels:
            raise ValueError(f"expected (B, {self.cfg.n_channels}, {self.cfg.n_mels}, T) "
                             f"features, got {tuple(x.shape)}")
        z = self.encoder(self.normalize(x))
        logit = self.heads["slip"](z).squeeze(1)
        # softplus keeps speed >= 0 with gradient everywhere (ReLU would die at zero speed).
        magnitude = F.softplus(self.heads["magnitude"](z).squeeze(1)) * self.cfg.speed_scale
        angular = None
        if self.cfg.angular:
            # Signed and unbounded: the rate's sign is the direction of the turn.
            angular = self.heads["angular"](z).squeeze(1) * (self.cfg.speed_scale
                                                             / ROTATION_RADIUS_M)
        return SlipOutput(logit, magnitude, self.heads["direction"](z), angular)

    def freeze_encoder(self, trainable: Sequence[str] = ()) -> None:
        """Stop encoder updates: no gradients and batch-norm statistics fixed, except the
        weights of the encoder sub-modules named in ``trainable`` (e.g. ``("conv1d",
        "pool")`` for the temporal layers; ``ENCODER_PARTS`` for all), which keep their
        gradients. Batch-norm statistics stay fixed throughout: a small finetuning set would
        otherwise re-estimate them from few grasps."""
        unknown = set(trainable) - set(ENCODER_PARTS)
        if unknown:
            raise ValueError(f"unknown encoder parts {sorted(unknown)}; have {ENCODER_PARTS}")
        self._encoder_frozen = True
        for name, mod in self.encoder.named_children():
            for p in mod.parameters():
                p.requires_grad_(name in trainable)
        self.encoder.eval()

    def train(self, mode: bool = True) -> "SlipNet":
        super().train(mode)
        if self._encoder_frozen:
            # BN running statistics are buffers, not parameters: requires_grad alone would
            # let them drift during finetuning, so the encoder stays in eval mode.
            self.encoder.eval()
        return self

    def head_parameters(self) -> list[nn.Parameter]:
        return list(self.heads.parameters())


def fuse_for_inference(model: SlipNet) -> SlipNet:
    """An eval-mode copy with batch norm folded into the preceding convolutions.

    Numerically the same function (to float rounding) with fewer operators: at batch size
    one the per-operator overhead, not arithmetic, dominates CPU latency.
    """
    import copy

    from torch.nn.utils.fusion import fuse_conv_bn_eval

    fused = copy.deepcopy(model).eval()
    for seq in (fused.encoder.conv2d, fused.encoder.conv1d):
        mods = list(seq)
        for i, mod in enumerate(mods):
            if isinstance(mod, (nn.BatchNorm1d, nn.BatchNorm2d)) and i > 0 and isinstance(
                    mods[i - 1], (nn.Conv1d, nn.Conv2d)):
                mods[i - 1] = fuse_conv_bn_eval(mods[i - 1], mod)
                mods[i] = nn.Identity()
            elif isinstance(mod, nn.Dropout):
                mods[i] = nn.Identity()
        for i, mod in enumerate(mods):
            seq[i] = mod
    for p in fused.parameters():
        p.requires_grad_(False)
    return fused


class _Estimates(nn.Module):
    """A ``SlipNet`` whose output is the estimates as a plain tuple of tensors (what
    TorchScript's tracer takes): p(slip), the ungated velocity and, for a model with the
    rotational head, the rate (``estimates``)."""

    def __init__(self, net: SlipNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = self.net(x)
        return (*estimates(out), *(() if out.angular is None else (out.angular,)))


class TracedSlipNet:
    """``fuse_for_inference``'s model with ``estimates`` after it, traced and frozen by
    TorchScript: the same operators on the same weights (equal to the eager model's, checked
    in test/test_learn_network.py) without Python's per-module dispatch, which at batch one
    on one thread is a third of the forward's time (docs/model.md, "Live cost"). Traced on
    one window of ``n_frames``; other batch sizes run the same graph. The input's shape is
    checked here: the traced graph holds the network's own check as a constant.

    TorchScript is deprecated in the pinned torch (2.13), and ``torch.export`` ran this network
    slower than the eager model (1.5 against 1.2 ms). Where tracing is missing or fails, the
    eager module runs instead (``traced`` False): the same estimates, more slowly."""

    def __init__(self, model: SlipNet, n_frames: int) -> None:
        import warnings

        self.cfg = model.cfg
        self.n_frames = int(n_frames)
        eager = _Estimates(fuse_for_inference(model)).eval()
        example = torch.zeros(1, self.cfg.n_channels, self.cfg.n_mels, self.n_frames)
        try:
            with warnings.catch_warnings(), torch.no_grad():
                # The tracer warns that the network's shape check is now a constant, and
                # that TorchScript is deprecated.
                warnings.simplefilter("ignore", torch.jit.TracerWarning)
                warnings.simplefilter("ignore", DeprecationWarning)
                module = torch.jit.freeze(torch.jit.trace(eager, example, check_trace=False))
            self.traced = True
        except (AttributeError, RuntimeError):
            module, self.traced = eager, False
        self.module = module

    def __call__(self, x: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """p(slip) ``(B,)``, the ungated velocity ``(B, 2)`` [m/s] and the rate ``(B,)``
        [rad/s] (None without the rotational head) of log-mel features ``(B, C, M, T)``."""
        want = (self.cfg.n_channels, self.cfg.n_mels, self.n_frames)
        if x.ndim != 4 or tuple(x.shape[1:]) != want:
            raise ValueError(f"expected (B, {want[0]}, {want[1]}, {want[2]}) features, "
                             f"got {tuple(x.shape)}")
        out = self.module(x)
        return out[0], out[1], out[2] if len(out) > 2 else None


def _mel_problems(meta: dict[str, Any], mcfg: Any, fcfg: FeatureConfig | None) -> list[str]:
    problems = []
    if mcfg.n_channels != len(meta["channel_names"]):
        problems.append(f"model_config.n_channels {mcfg.n_channels} != "
                        f"{len(meta['channel_names'])} channel_names")
    if fcfg is not None and mcfg.n_mels != fcfg.n_mels:
        problems.append(f"model_config.n_mels {mcfg.n_mels} != feature_config.n_mels "
                        f"{fcfg.n_mels}")
    return problems


@register_model
class CnnBackend:
    """The A-SLIP CNN on log-mel features: the backend of ``aslip_cnn`` checkpoints."""

    model_type: ClassVar[str] = "aslip_cnn"
    config: ClassVar[type] = ModelConfig
    streaming: ClassVar[bool] = False
    #: Its training, apart from inference: ``aslip train --stage pretrain|finetune|scratch``
    #: (learn/models/aslip_cnn_fit.py, imported when a stage runs).
    fit: ClassVar[str] = "aslip_ros.learn.models.aslip_cnn_fit:fit"
    stages: ClassVar[tuple[str, ...]] = ("pretrain", "finetune", "scratch")
    #: ``predict`` is ``infer_features`` of ``logmel`` less the offsets: the live path may
    #: give it the sliding log-mel instead (learn/inference/live.py).
    reads_logmel: ClassVar[bool] = True

    def __init__(self, cfg: ModelConfig, model: TracedSlipNet, logmel: LogMel) -> None:
        self.cfg = cfg
        self.model = model
        self.logmel = logmel

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        return (_mel_problems(meta, model_config, feature_config)
                + angular_problems(meta, model_config.angular))

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "CnnBackend":
        cfg = ModelConfig.from_dict(ckpt.meta["model_config"])
        if cfg.n_channels != len(ckpt.channel_names):
            raise ValueError("checkpoint model channel count disagrees with channel_names")
        model = load_weights(SlipNet(cfg), ckpt.tensors)
        logmel = LogMel(FeatureConfig.from_dict(ckpt.meta["feature_config"]), ckpt.sample_rate)
        n_frames = logmel.n_frames(int(ckpt.meta["window_samples"]))
        return cls(cfg, TracedSlipNet(model, n_frames), logmel)

    def predict(self, windows: np.ndarray, offsets: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        feats = self.logmel(windows)
        if offsets is not None:
            feats = feats - offsets[:, :, None, None]
        return self.infer_features(feats)

    def infer_features(self, feats: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The model alone on log-mel features ``(B, C, M, T)`` (e.g. a training cache):
        p(slip), the ungated velocity and the rate ``wy`` (None without that head)."""
        with torch.inference_mode():
            prob, v, rate = self.model(
                torch.from_numpy(np.ascontiguousarray(feats, dtype=np.float32)))
        return prob.numpy(), v.numpy(), None if rate is None else rate.numpy()


def estimates(out: SlipOutput) -> tuple[torch.Tensor, torch.Tensor]:
    """p(slip) ``(B,)`` and the ungated velocity ``(B, 2)`` [m/s] of a network output: the
    speed along the unit direction."""
    d = out.direction / out.direction.norm(dim=1, keepdim=True).clamp(min=1e-8)
    return torch.sigmoid(out.logit), d * out.magnitude[:, None]


def output_arrays(out: SlipOutput) -> tuple[np.ndarray, np.ndarray]:
    """``estimates`` as numpy arrays."""
    prob, v = estimates(out)
    return prob.cpu().numpy(), v.cpu().numpy()
