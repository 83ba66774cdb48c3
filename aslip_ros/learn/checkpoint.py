"""Self-describing checkpoints that load with ``torch.load(weights_only=True)``.

On disk a checkpoint is one ``torch.save`` file holding a dict of plain types only::

    {"format": "aslip-checkpoint", "version": 1,
     "meta": "<JSON document>",            # str: everything needed to rebuild and check
     "tensors": {name: torch.Tensor}}      # state dict (CNN) or SVM arrays

The JSON document (``meta``, built by ``checkpoint_meta``) holds ``model_type`` (a key of
``learn.models.registry``: "aslip_cnn", "svm", "aslip_stream", "per_output" or a registered
one), ``model_config``, ``feature_config``, ``normalization`` (per-mel-bin mean/std, also
inside the CNN's state dict as buffers), ``channel_names``, ``layout``, ``sample_rate`` (Hz,
the stream's rate), ``window_s``, ``window_samples``, ``epsilon_m_s``, ``threshold``,
``outputs`` (what the model estimates: ``"slip"``, the velocity components and ``"wy"`` for
a model with a rotational output; a checkpoint without the key is planar), optionally
``output_calibration`` (the threshold's fit and the direction-sigma model, from the
validation windows: learn/calibration/output.py; older checkpoints have none and report no
sigma) and ``provenance`` (dataset path, git revision, seed, stage, init checkpoint,
metrics, versions). Keeping the
metadata a JSON string means nothing in the file needs an unpickler beyond tensors.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import torch

from aslip_ros.learn.calibration.grasp import meta_problems as calibration_problems
from aslip_ros.learn.calibration.output import meta_problems as output_problems
from aslip_ros.learn.compat import CheckpointMismatch, check_compatible
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.models.registry import model_backend
from aslip_ros.slip import ANGULAR_COMPONENT, DEFAULT_THRESHOLD, VELOCITY_COMPONENTS
from aslip_ros.util import atomic_path

__all__ = ["Checkpoint", "CheckpointFacts", "CheckpointMismatch", "check_compatible",
           "checkpoint_meta", "estimates_rotation", "load_checkpoint", "model_outputs",
           "save_checkpoint", "validate_meta"]

FORMAT = "aslip-checkpoint"
VERSION = 1
_REQUIRED = ("model_type", "model_config", "feature_config", "channel_names", "sample_rate",
             "window_s", "window_samples", "epsilon_m_s")
#: What every model estimates: p(slip) and the planar velocity components, in order.
PLANAR_OUTPUTS = ("slip",) + VELOCITY_COMPONENTS
#: Every output a checkpoint's ``outputs`` may name.
KNOWN_OUTPUTS = PLANAR_OUTPUTS + (ANGULAR_COMPONENT,)
_TYPES = {"int": (int,), "float": (int, float), "str": (str,), "None": (type(None),),
          "bool": (bool,)}


@dataclass
class Checkpoint:
    meta: dict[str, Any]
    tensors: dict[str, torch.Tensor] = field(default_factory=dict)

    @property
    def model_type(self) -> str:
        return self.meta["model_type"]

    @property
    def sample_rate(self) -> float:
        return float(self.meta["sample_rate"])

    @property
    def channel_names(self) -> list[str]:
        return list(self.meta["channel_names"])

    def check_compatible(self, sample_rate: float, channel_names: Sequence[str]) -> None:
        check_compatible(self.meta, sample_rate, channel_names)


def model_outputs(meta: dict[str, Any]) -> list[str]:
    """What the checkpoint's model estimates (``outputs``; planar when the key is absent,
    as in every checkpoint written before the rotational output existed)."""
    outputs = meta.get("outputs")
    return list(PLANAR_OUTPUTS) if outputs is None else list(outputs)


def estimates_rotation(meta: dict[str, Any]) -> bool:
    """Whether the model estimates the rotational slip rate ``wy``."""
    return ANGULAR_COMPONENT in model_outputs(meta)


def angular_problems(meta: dict[str, Any], has_output: bool) -> list[str]:
    """A model type's check that ``outputs`` names ``wy`` exactly when its model has a
    rotational output (a document without ``outputs`` is planar)."""
    if estimates_rotation(meta) == bool(has_output):
        return []
    return [f"outputs {model_outputs(meta)!r} {'lack' if has_output else 'name'} "
            f"{ANGULAR_COMPONENT!r} but the model {'has' if has_output else 'has no'} "
            "rotational output"]


def _outputs_problems(outputs: Any) -> list[str]:
    if outputs is None:
        return []
    if not isinstance(outputs, list) or not all(isinstance(o, str) for o in outputs) \
            or len(set(outputs)) != len(outputs) or not set(PLANAR_OUTPUTS) <= set(outputs) \
            or not set(outputs) <= set(KNOWN_OUTPUTS):
        return [f"outputs must list {list(PLANAR_OUTPUTS)} and optionally "
                f"{ANGULAR_COMPONENT!r}, each once, got {outputs!r}"]
    return []


def _number(meta: dict, key: str, low: float, *, strict: bool = True,
            integer: bool = False) -> list[str]:
    v = meta.get(key)
    kinds = (int,) if integer else (int, float)
    if isinstance(v, bool) or not isinstance(v, kinds) or not math.isfinite(v):
        return [f"{key} must be {'an integer' if integer else 'a finite number'}, got {v!r}"]
    if v < low or (strict and v == low):
        return [f"{key} must be {'>' if strict else '>='} {low:g}, got {v!r}"]
    return []


def _config(cls: type, d: Any, key: str) -> tuple[Any, list[str]]:
    """Build dataclass ``cls`` from ``d`` after checking each field's JSON type."""
    if not isinstance(d, dict):
        return None, [f"{key} must be a JSON object, got {type(d).__name__}"]
    fields = {f.name: f.type for f in dataclasses.fields(cls)}
    problems = [f"{key} has unknown fields {sorted(set(d) - set(fields))}"] \
        if set(d) - set(fields) else []
    for name, v in d.items():
        allowed = tuple(t for part in str(fields.get(name, "")).split("|")
                        for t in _TYPES.get(part.strip(), ()))
        if name in fields and allowed and (isinstance(v, bool) and bool not in allowed
                                           or not isinstance(v, allowed)
                                           or isinstance(v, float) and not math.isfinite(v)):
            problems.append(f"{key}.{name} must be {fields[name]}, got {v!r}")
    if problems:
        return None, problems
    try:
        return cls(**d), []
    except (TypeError, ValueError) as exc:
        return None, [f"{key}: {exc}"]


def validate_meta(meta: Any) -> list[str]:
    """Every problem of a checkpoint's metadata document (an empty list when it is sound).

    Checks required keys, JSON types and ranges, that the model and feature configs build,
    and that the parts agree: ``window_samples == round(window_s * sample_rate)``, a window
    long enough for one feature frame, and the model type's own checks
    (``learn.models.registry``: e.g. one CNN input per channel name, equal mel counts).
    """
    if not isinstance(meta, dict):
        return [f"metadata must be a JSON object, got {type(meta).__name__}"]
    missing = [k for k in _REQUIRED if k not in meta]
    if missing:
        return [f"metadata lacks {missing}"]
    problems: list[str] = []
    try:
        backend = model_backend(meta["model_type"])
    except ValueError as exc:
        problems.append(str(exc))
    names = meta["channel_names"]
    if (not isinstance(names, list) or not names
            or not all(isinstance(n, str) and n for n in names) or len(set(names)) != len(names)):
        problems.append(f"channel_names must be a non-empty list of distinct names, got {names!r}")
    problems += _number(meta, "sample_rate", 0.0) + _number(meta, "window_s", 0.0)
    problems += _number(meta, "window_samples", 0, integer=True)
    problems += _number(meta, "epsilon_m_s", 0.0, strict=False)
    if meta.get("threshold") is not None:
        t = meta["threshold"]
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not 0.0 <= t <= 1.0:
            problems.append(f"threshold must be a number in [0, 1], got {t!r}")
    for key in ("layout",):
        if meta.get(key) is not None and not isinstance(meta[key], str):
            problems.append(f"{key} must be a string, got {meta[key]!r}")
    problems += _outputs_problems(meta.get("outputs"))
    if problems:
        return problems
    want = round(meta["window_s"] * meta["sample_rate"])
    if meta["window_samples"] != want:
        problems.append(f"window_samples {meta['window_samples']} != round(window_s x "
                        f"sample_rate) = {want}")
    fcfg, bad = _config(FeatureConfig, meta["feature_config"], "feature_config")
    problems += bad
    if fcfg is not None:
        try:
            fcfg.n_frames(meta["window_s"])
        except ValueError as exc:
            problems.append(f"feature_config: {exc}")
    mcfg, bad = _config(backend.config, meta["model_config"], "model_config")
    problems += bad
    if mcfg is not None:
        problems += backend.meta_problems(meta, mcfg, fcfg)
    if "calibration" in meta:
        problems += calibration_problems(meta["calibration"], names,
                                         None if fcfg is None else fcfg.n_mels,
                                         None if fcfg is None else fcfg.hop / fcfg.sample_rate)
    if meta.get("output_calibration") is not None:
        problems += output_problems(meta["output_calibration"])
    return problems


def dataset_layout(ds: Any, channels: Sequence[str]) -> str | None:
    """The dataset's layout name, with the channels appended when a model uses a subset."""
    if list(channels) == list(ds.channel_names):
        return ds.layout
    return f"{ds.layout}:{'+'.join(channels)}"


def checkpoint_meta(model_type: str, model_config: Any, feature_config: Any, ds: Any,
                    channels: Sequence[str], *, normalization: dict[str, Any] | None,
                    provenance: dict[str, Any], threshold: float = DEFAULT_THRESHOLD,
                    calibration: Any = None, window_s: float | None = None,
                    window_samples: int | None = None, angular: bool = False,
                    **extra: Any) -> dict[str, Any]:
    """The checkpoint document of a model trained on dataset ``ds`` (a ``WindowSet``).

    ``model_config`` and ``feature_config`` are config objects (``to_dict``), as is
    ``calibration`` when given; ``angular``: the model estimates ``wy`` too (``outputs``).
    Rate, epsilon and, unless given (a streaming model reads one
    frame, not the dataset's window), window length come from the dataset; ``extra``
    keys (``train_config``, ``loss_weights``, ``hop_s``, ``label``...) are added as they are.
    Every trainer builds its document here; ``save_checkpoint`` validates it.
    """
    meta: dict[str, Any] = {
        "model_type": model_type, "model_config": model_config.to_dict(),
        "feature_config": feature_config.to_dict(), "normalization": normalization,
        "channel_names": list(channels), "layout": dataset_layout(ds, channels),
        "sample_rate": float(ds.sample_rate),
        "window_s": float(ds.window_s if window_s is None else window_s),
        "window_samples": int(ds.window_samples if window_samples is None
                              else window_samples),
        "epsilon_m_s": float(ds.epsilon), "threshold": float(threshold),
        "outputs": list(KNOWN_OUTPUTS if angular else PLANAR_OUTPUTS),
    }
    meta.update(extra)
    meta["provenance"] = provenance
    if calibration is not None:
        meta["calibration"] = calibration.to_dict()
    return meta


def git_revision(start: str | os.PathLike | None = None) -> str | None:
    """The repository HEAD of the package source, or None outside a repository."""
    where = Path(start) if start else Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True,
                             text=True, timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    rev = out.stdout.strip()
    return rev if out.returncode == 0 and rev else None


def _plain(obj: Any) -> Any:
    """Round-trip through JSON so the document is plain types only (fails loudly otherwise)."""
    return json.loads(json.dumps(obj, allow_nan=False))


def save_checkpoint(path: str | os.PathLike, meta: dict[str, Any],
                    tensors: dict[str, torch.Tensor]) -> Path:
    """Validate and write atomically; returns the path."""
    doc = json.dumps(_plain(meta), allow_nan=False)
    problems = validate_meta(json.loads(doc))
    if problems:
        raise ValueError("checkpoint metadata: " + "; ".join(problems))
    clean = {}
    for k, v in tensors.items():
        if not isinstance(v, torch.Tensor):
            raise ValueError(f"tensor {k!r} is a {type(v).__name__}, not a torch.Tensor")
        clean[str(k)] = v.detach().cpu().contiguous()
    payload = {"format": FORMAT, "version": VERSION, "meta": doc, "tensors": clean}
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            torch.save(payload, tmp)
    except (OSError, RuntimeError) as exc:     # torch reports a failed write as either
        raise OSError(f"cannot write checkpoint {path}: "
                      f"{getattr(exc, 'strerror', None) or exc}") from None
    return path


def load_checkpoint(path: str | os.PathLike) -> Checkpoint:
    """Load with ``weights_only=True``; raises ValueError on anything not an A-SLIP checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for foreign or corrupt files
        raise ValueError(f"{path} is not a loadable checkpoint: {exc}") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path} is not an {FORMAT} file")
    if payload.get("version") != VERSION:
        raise ValueError(f"{path}: unsupported checkpoint version {payload.get('version')}")
    if "meta" not in payload:
        raise ValueError(f"{path}: not a usable checkpoint: no metadata document")
    try:
        meta = json.loads(payload["meta"])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: checkpoint metadata is not a JSON document ({exc})") from None
    problems = validate_meta(meta)
    tensors = payload.get("tensors")
    if not isinstance(tensors, dict):
        problems.append("no tensors dict")
    else:
        for k, v in tensors.items():
            if not isinstance(v, torch.Tensor):
                problems.append(f"tensor {k!r} is a {type(v).__name__}")
            elif v.is_floating_point() and not bool(torch.isfinite(v).all()):
                problems.append(f"tensor {k!r} holds NaN or infinite values")
    if problems:
        raise ValueError(f"{path}: not a usable checkpoint: " + "; ".join(problems))
    return Checkpoint(meta=meta, tensors=dict(tensors))


class CheckpointFacts:
    """What every predictor reports about its checkpoint (``self.checkpoint``): the model
    type and the stream it expects."""

    checkpoint: Checkpoint

    @property
    def meta(self) -> dict[str, Any]:
        return self.checkpoint.meta

    @property
    def model_type(self) -> str:
        return self.checkpoint.model_type

    @property
    def sample_rate(self) -> float:
        return self.checkpoint.sample_rate

    @property
    def channel_names(self) -> list[str]:
        return self.checkpoint.channel_names

    @property
    def n_channels(self) -> int:
        return len(self.channel_names)

    @property
    def layout(self) -> str | None:
        return self.meta.get("layout")
