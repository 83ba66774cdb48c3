"""What a checkpoint's ``model_type`` means: one registry of model backends.

A window backend turns fixed-length audio windows into p(slip) and an ungated velocity::

    backend = model_backend(ckpt.model_type).from_checkpoint(ckpt)
    prob, raw_velocity = backend.predict(windows, offsets)     # (B,), (B, 2) in m/s

``windows`` are validated ``(B, window_samples, C)`` float32 at the checkpoint's rate;
``offsets`` ``(B, C)`` (or None) are the per-grasp calibration of each window, natural-log
power to remove per channel. The Predictor (learn/predictor.py) owns input checks, the
threshold and the gating; a backend owns only its model. ``validate_meta``
(learn/checkpoint.py) checks a checkpoint's ``model_config`` with the backend's ``config``
dataclass and ``meta_problems``, so a model type is known, loaded and checked here alone.

The streaming model (``aslip_stream``) runs per audio block, not per window: its entry has
``streaming = True`` and its ``from_checkpoint`` gives a ``StreamingPredictor``. A new model
is one module that defines a backend class, registered by ``register_model`` or, for
programs that do not import it (``aslip evaluate``, ``slip_inference``), declared by its
distribution as an entry point ``<model_type> = module:Class`` in the ``aslip_ros.models``
group (docs/design.md, "Extending"). A checkpoint never names code to import: only a
registered class, or one an installed distribution declares for its type, is used.
"""

from __future__ import annotations

import dataclasses
from importlib.metadata import entry_points
from typing import Any, ClassVar, Protocol

import numpy as np
import torch

from .calibration_frames import remove_from_audio
from .checkpoint import Checkpoint
from .features import FeatureConfig, LogMel
from .network import ModelConfig, SlipNet, fuse_for_inference
from .streaming_model import StreamConfig
from .svm import SvmArrays, SvmConfig, SvmFeaturizer


class ModelBackend(Protocol):
    """A model type: its config, the checks of its checkpoint document, and inference."""

    model_type: ClassVar[str]        # the checkpoint's ``model_type``
    config: ClassVar[type]           # dataclass of ``model_config`` (JSON types, to_dict)
    streaming: ClassVar[bool]        # True: per-block model, no window ``predict``

    @classmethod
    def meta_problems(cls, meta: dict[str, Any], model_config: Any,
                      feature_config: FeatureConfig | None) -> list[str]:
        """What the document gets wrong for this model (empty when sound)."""

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "ModelBackend":
        """Build from a loaded checkpoint; ValueError when its tensors do not fit."""

    def predict(self, windows: np.ndarray,
                offsets: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """p(slip) ``(B,)`` and the ungated velocity ``(B, 2)`` for ``(B, N, C)`` windows."""


def _mel_problems(meta: dict[str, Any], mcfg: Any, fcfg: FeatureConfig | None) -> list[str]:
    problems = []
    if mcfg.n_channels != len(meta["channel_names"]):
        problems.append(f"model_config.n_channels {mcfg.n_channels} != "
                        f"{len(meta['channel_names'])} channel_names")
    if fcfg is not None and mcfg.n_mels != fcfg.n_mels:
        problems.append(f"model_config.n_mels {mcfg.n_mels} != feature_config.n_mels "
                        f"{fcfg.n_mels}")
    return problems


class CnnBackend:
    """The A-SLIP CNN on log-mel features (learn/network.py)."""

    model_type: ClassVar[str] = "aslip_cnn"
    config: ClassVar[type] = ModelConfig
    streaming: ClassVar[bool] = False

    def __init__(self, cfg: ModelConfig, model: SlipNet, logmel: LogMel) -> None:
        self.cfg = cfg
        self.model = model
        self.logmel = logmel

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        return _mel_problems(meta, model_config, feature_config)

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "CnnBackend":
        cfg = ModelConfig.from_dict(ckpt.meta["model_config"])
        if cfg.n_channels != len(ckpt.channel_names):
            raise ValueError("checkpoint model channel count disagrees with channel_names")
        model = SlipNet(cfg)
        try:
            model.load_state_dict(ckpt.tensors)
        except RuntimeError as exc:
            raise ValueError(f"checkpoint weights do not fit its model config: {exc}") from exc
        logmel = LogMel(FeatureConfig.from_dict(ckpt.meta["feature_config"]), ckpt.sample_rate)
        return cls(cfg, fuse_for_inference(model), logmel)

    def predict(self, windows: np.ndarray,
                offsets: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        feats = self.logmel(windows)
        if offsets is not None:
            feats = feats - offsets[:, :, None, None]
        return self.infer_features(feats)

    def infer_features(self, feats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The model alone on log-mel features ``(B, C, M, T)`` (e.g. a training cache)."""
        with torch.inference_mode():
            out = self.model(torch.from_numpy(np.ascontiguousarray(feats, dtype=np.float32)))
            prob = torch.sigmoid(out.logit)
            d = out.direction / out.direction.norm(dim=1, keepdim=True).clamp(min=1e-8)
            v = d * out.magnitude[:, None]
        return prob.numpy(), v.numpy()


class SvmBackend:
    """The paper's SVM baseline on handcrafted band features (learn/svm.py)."""

    model_type: ClassVar[str] = "svm"
    config: ClassVar[type] = SvmConfig
    streaming: ClassVar[bool] = False

    def __init__(self, arrays: SvmArrays, featurizer: SvmFeaturizer) -> None:
        self.arrays = arrays
        self.featurizer = featurizer

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        if model_config.n_bands < 1:
            return [f"model_config.n_bands must be >= 1, got {model_config.n_bands}"]
        return []

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "SvmBackend":
        fcfg = FeatureConfig.from_dict(ckpt.meta["feature_config"])
        n_bands = int(ckpt.meta["model_config"]["n_bands"])
        return cls(SvmArrays.from_tensors(ckpt.tensors),
                   SvmFeaturizer(fcfg, ckpt.sample_rate, n_bands))

    def predict(self, windows: np.ndarray,
                offsets: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        if offsets is not None:
            windows = remove_from_audio(windows, offsets)
        return self.arrays.predict(self.featurizer(windows))


class StreamBackend:
    """The causal streaming estimator: per audio block (learn/streaming_predictor.py)."""

    model_type: ClassVar[str] = "aslip_stream"
    config: ClassVar[type] = StreamConfig
    streaming: ClassVar[bool] = True

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        from .streaming import stream_meta_problems
        return stream_meta_problems(meta, model_config, feature_config)

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint, **options: Any):
        """A ``StreamingPredictor`` (``options``: its ``threshold``, ``max_time_jump_s``)."""
        from .streaming_predictor import StreamingPredictor
        return StreamingPredictor(ckpt, **options)


MODELS: dict[str, type] = {}
ENTRY_POINT_GROUP = "aslip_ros.models"


def register_model(backend: type) -> type:
    """Make ``backend.model_type`` a known model (usable as a class decorator).

    ValueError when the class lacks a member of ``ModelBackend`` or the type is taken by
    another class.
    """
    missing = [m for m in ("model_type", "config", "streaming", "meta_problems",
                           "from_checkpoint") if not hasattr(backend, m)]
    if not missing and not backend.streaming and not hasattr(backend, "predict"):
        missing.append("predict")
    if missing:
        raise ValueError(f"{backend!r} is not a model backend: it lacks {missing}")
    if not (isinstance(backend.model_type, str) and backend.model_type):
        raise ValueError(f"{backend!r}: model_type must be a non-empty string")
    if not dataclasses.is_dataclass(backend.config):
        raise ValueError(f"{backend!r}: config must be a dataclass")
    held = MODELS.get(backend.model_type)
    if held is not None and held is not backend:
        raise ValueError(f"model_type {backend.model_type!r} is already {held.__name__}")
    MODELS[backend.model_type] = backend
    return backend


def unregister_model(model_type: str) -> None:
    """Forget a registered model type (tests; the built-in types stay)."""
    if model_type in BUILTIN:
        raise ValueError(f"{model_type!r} is a built-in model type")
    MODELS.pop(model_type, None)


def model_types() -> tuple[str, ...]:
    return tuple(MODELS)


def _from_entry_point(model_type: str) -> type | None:
    """Register the backend an installed distribution declares for ``model_type`` in the
    ``aslip_ros.models`` entry-point group (None when none does)."""
    for ep in entry_points(group=ENTRY_POINT_GROUP, name=model_type):
        try:
            backend = ep.load()
        except Exception as exc:  # noqa: BLE001 - any import failure: the model is unusable
            raise ValueError(f"model_type {model_type!r}: entry point {ep.value} does not "
                             f"load ({type(exc).__name__}: {exc})") from None
        if getattr(backend, "model_type", None) != model_type:
            raise ValueError(f"entry point {ep.value} is declared as {model_type!r} but its "
                             f"model_type is {getattr(backend, 'model_type', None)!r}")
        return register_model(backend)
    return None


def model_backend(model_type: Any) -> type:
    """The backend class of ``model_type``: registered, or declared by an installed
    distribution's ``aslip_ros.models`` entry point; ValueError naming the known ones."""
    if not isinstance(model_type, str):
        raise ValueError(f"unknown model_type {model_type!r} (known: {model_types()})")
    backend = MODELS.get(model_type) or _from_entry_point(model_type)
    if backend is None:
        raise ValueError(f"unknown model_type {model_type!r} (known: {model_types()})")
    return backend


BUILTIN = tuple(register_model(b).model_type for b in (CnnBackend, SvmBackend, StreamBackend))
CNN = CnnBackend.model_type
