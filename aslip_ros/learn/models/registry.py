"""What a checkpoint's ``model_type`` means: one registry of model backends.

A window backend turns fixed-length audio windows into p(slip) and an ungated velocity::

    backend = model_backend(ckpt.model_type).from_checkpoint(ckpt)
    prob, raw_velocity = backend.predict(windows, offsets)     # (B,), (B, 2) in m/s

``windows`` are validated ``(B, window_samples, C)`` float32 at the checkpoint's rate;
``offsets`` ``(B, C)`` (or None) are the per-grasp calibration of each window, natural-log
power to remove per channel. The live estimator (``learn.inference``) owns input checks,
the threshold and the gating; a backend owns only its model. ``validate_meta``
(learn/checkpoint.py) checks a checkpoint's ``model_config`` with the backend's ``config``
dataclass and ``meta_problems``, so a model type is known, loaded and checked here alone.

This module sits below everything it registers: the built-in types are named by
``module:Class`` (``BUILTIN``) and imported the first time a checkpoint of that type is met,
so the checkpoint format can consult the registry without importing any model. A model
module registers its backend with ``@register_model``. A streaming backend
(``streaming = True``, ``aslip_stream``) runs per audio block, not per window.

A window backend whose ``predict(windows, offsets)`` is exactly ``infer_features(
logmel(windows) - offsets)`` (its ``logmel`` a ``features.LogMel``) says so with
``reads_logmel = True`` (the CNN, an SVM on log-mel): the live estimator then hands it the
log-mel it slides hop by hop instead of the whole window (learn/inference/live.py).

A new model is one module that defines a config dataclass, a network and a backend class,
registered by ``register_model`` or, for programs that do not import it (``aslip train``,
``aslip evaluate``, ``slip_inference``), declared by its distribution as an entry point
``<model_type> = module:Class`` in the ``aslip_ros.models`` group (docs/design.md,
"Extending"). A backend may also define ``fit``: ``aslip train --stage <model_type>`` then
trains it (:func:`aslip_ros.learn.training.train.train_backend`, through ``model_fit``).
``fit`` may be a ``module:function`` string instead of a classmethod, for a model that keeps
its training apart from its inference (the CNN: learn/models/aslip_cnn_fit.py), and
``stages`` may name the stages it trains in place of its type's name (the CNN's pretrain,
finetune, scratch; the fit reads ``config.stage``). A checkpoint never names code to import:
only a registered class, a built-in, or one an installed distribution declares for its type.
"""

from __future__ import annotations

import dataclasses
from importlib.metadata import entry_points
from typing import Any, Callable, ClassVar, Protocol

import numpy as np

from aslip_ros import plugin

#: The built-in model types and where each one's backend lives (imported on first use).
BUILTIN: dict[str, str] = {
    "aslip_cnn": "aslip_ros.learn.models.aslip_cnn:CnnBackend",
    "svm": "aslip_ros.learn.models.svm:SvmBackend",
    "aslip_stream": "aslip_ros.learn.models.aslip_stream:StreamBackend",
    "per_output": "aslip_ros.learn.models.per_output:PerOutputBackend",
    "aslip_hybrid": "aslip_ros.learn.models.aslip_hybrid:HybridBackend",
}
CNN, SVM, STREAM, PER_OUTPUT, HYBRID = BUILTIN
ENTRY_POINT_GROUP = "aslip_ros.models"

MODELS: dict[str, type] = {}


class ModelBackend(Protocol):
    """A model type: its config, the checks of its checkpoint document, and inference."""

    model_type: ClassVar[str]        # the checkpoint's ``model_type``
    config: ClassVar[type]           # dataclass of ``model_config`` (JSON types, to_dict)
    streaming: ClassVar[bool]        # True: per-block model, no window ``predict``

    @classmethod
    def meta_problems(cls, meta: dict[str, Any], model_config: Any,
                      feature_config: Any) -> list[str]:
        """What the document gets wrong for this model (empty when sound)."""

    @classmethod
    def from_checkpoint(cls, ckpt: Any) -> "ModelBackend":
        """Build from a loaded checkpoint; ValueError when its tensors do not fit."""

    def predict(self, windows: np.ndarray,
                offsets: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """p(slip) ``(B,)`` and the ungated velocity ``(B, 2)`` for ``(B, N, C)`` windows."""


def has_fit(backend: type) -> bool:
    """Whether the model type trains itself (a ``fit``), without importing that fit."""
    fit = getattr(backend, "fit", None)
    return callable(fit) or (isinstance(fit, str) and plugin.is_reference(fit))


def model_fit(backend: type) -> Callable[..., Any] | None:
    """The model type's training stage: its ``fit`` classmethod, or the function its ``fit``
    names as ``module:function`` (imported now); None without one."""
    fit = getattr(backend, "fit", None)
    if isinstance(fit, str):
        return plugin.load(fit, f"model {backend.model_type!r}'s fit")
    return fit if callable(fit) else None


def load_weights(net: Any, tensors: dict) -> Any:
    """``net`` with a checkpoint's state dict loaded; ValueError when they do not fit."""
    try:
        net.load_state_dict(tensors)
    except RuntimeError as exc:
        raise ValueError(f"checkpoint weights do not fit its model config: {exc}") from exc
    return net


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
    if held is None and backend.model_type in BUILTIN and \
            BUILTIN[backend.model_type] != f"{backend.__module__}:{backend.__qualname__}":
        held = _builtin(backend.model_type)
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
    """The built-in types, then those registered since."""
    return tuple(BUILTIN) + tuple(t for t in MODELS if t not in BUILTIN)


def _builtin(model_type: str) -> type:
    backend = plugin.load(BUILTIN[model_type], "a built-in model")   # registers itself
    return MODELS.setdefault(model_type, backend)


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
    """The backend class of ``model_type``: registered, built in, or declared by an
    installed distribution's ``aslip_ros.models`` entry point; ValueError naming the known
    ones."""
    if not isinstance(model_type, str):
        raise ValueError(f"unknown model_type {model_type!r} (known: {model_types()})")
    backend = MODELS.get(model_type)
    if backend is None and model_type in BUILTIN:
        backend = _builtin(model_type)
    if backend is None:
        backend = _from_entry_point(model_type)
    if backend is None:
        raise ValueError(f"unknown model_type {model_type!r} (known: {model_types()})")
    return backend
