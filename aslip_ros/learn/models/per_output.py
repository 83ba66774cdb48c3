"""One model whose outputs come from different trained models: ``aslip train``'s per-output
choice (learn/training/selection.py, ``choose_outputs``).

A ``per_output`` checkpoint holds whole checkpoint documents of its parts under ``parts``
(name -> document) and their tensors as ``<name>/<tensor>``. ``model_config`` says which
part gives each output:

  detection  p(slip)
  speed      the norm of the planar velocity
  direction  the planar velocity's unit vector (where that part's estimate is 0, the speed
             part's own direction)
  rotation   the rotational rate ``wy``, exactly where ``outputs`` names it

Each part reads the same windows; the per-grasp offsets the stream computes go to the parts
trained with the calibration (their ``calibration`` must equal the checkpoint's) and not to
those trained without. A part is a window model (no streaming one, no ``per_output``) of the
checkpoint's rate, channels and window. The metrics of the combination are the parts':
detection reads only p(slip), the speed error only the velocity's norm and the direction
error only its angle (learn/metrics.py).
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from aslip_ros.learn.checkpoint import (KNOWN_OUTPUTS, PLANAR_OUTPUTS, Checkpoint,
                                        estimates_rotation, validate_meta)
from aslip_ros.learn.features import LogMel
from aslip_ros.learn.models.registry import model_backend, register_model

#: The outputs a part can give, in the order the comparison lists them.
ROLES = ("detection", "speed", "direction", "rotation")
#: The stream every part must share with the checkpoint.
SHARED = ("sample_rate", "channel_names", "window_samples")
SEP = "/"


@dataclass(frozen=True)
class PerOutputConfig:
    """Which part (a name in the checkpoint's ``parts``) gives each output."""

    detection: str
    speed: str
    direction: str
    rotation: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def roles(self) -> dict[str, str]:
        """role -> part name, the roles this model fills."""
        return {r: n for r, n in self.to_dict().items() if n is not None}


def part_tensors(tensors: dict[str, torch.Tensor], name: str) -> dict[str, torch.Tensor]:
    """The tensors of part ``name`` under their own names."""
    head = name + SEP
    return {k[len(head):]: v for k, v in tensors.items() if k.startswith(head)}


def assemble(parts: dict[str, Checkpoint], roles: dict[str, str]) -> Checkpoint:
    """The ``per_output`` checkpoint whose outputs come from the named ``parts`` (``roles``:
    role -> part name; detection, speed and direction required). The stream facts, features
    and threshold are the detection part's; the calibration is the calibrated parts' (one
    set of offsets). The direction sigma of a combination is not any part's: the trainer
    fits ``output_calibration`` again on the combination's validation predictions
    (``learn.training.selection.compose``); without one the model reports no sigma."""
    used = sorted(set(roles.values()))
    meta = copy.deepcopy(parts[roles["detection"]].meta)
    for key in ("calibration", "output_calibration", "normalization"):
        meta.pop(key, None)
    docs = {name: copy.deepcopy(parts[name].meta) for name in used}
    calibrations = [docs[n]["calibration"] for n in used if "calibration" in docs[n]]
    if calibrations:
        meta["calibration"] = calibrations[0]
    meta.update(model_type=PerOutputBackend.model_type, parts=docs,
                model_config=PerOutputConfig(**roles).to_dict(),
                outputs=list(KNOWN_OUTPUTS if roles.get("rotation") else PLANAR_OUTPUTS))
    tensors = {f"{name}{SEP}{k}": v for name in used for k, v in parts[name].tensors.items()}
    return Checkpoint(meta=meta, tensors=tensors)


def _part_problems(name: str, part: Any, meta: dict[str, Any]) -> list[str]:
    where = f"parts.{name}"
    if not isinstance(part, dict):
        return [f"{where} must be a checkpoint document, got {type(part).__name__}"]
    if part.get("model_type") == PerOutputBackend.model_type:
        return [f"{where} is itself a {PerOutputBackend.model_type} model"]
    problems = [f"{where}: {p}" for p in validate_meta(part)]
    if problems:
        return problems
    if model_backend(part["model_type"]).streaming:
        problems.append(f"{where} is a streaming model ({part['model_type']}); parts read "
                        "windows")
    for key in SHARED:
        if part.get(key) != meta.get(key):
            problems.append(f"{where}.{key} {part.get(key)!r} differs from the checkpoint's "
                            f"{meta.get(key)!r}")
    if "calibration" in part and part["calibration"] != meta.get("calibration"):
        problems.append(f"{where}.calibration differs from the checkpoint's calibration (the "
                        "stream computes one set of per-grasp offsets)")
    return problems


@register_model
class PerOutputBackend:
    """Each output from the part the checkpoint names for it (module docstring)."""

    model_type: ClassVar[str] = "per_output"
    config: ClassVar[type] = PerOutputConfig
    streaming: ClassVar[bool] = False

    def __init__(self, roles: dict[str, str], backends: dict[str, Any],
                 calibrated: dict[str, bool]) -> None:
        self.roles = roles
        self.backends = backends
        self.calibrated = calibrated
        #: The log-mel the parts that read log-mel (``reads_logmel``: the CNN, an SVM on
        #: log-mel) share in ``predict_with_features``: the first such part's; None when
        #: no part reads it.
        self.logmel = None
        self._reads_features: set[str] = set()
        for name, b in backends.items():
            logmel = getattr(b, "logmel", None)
            if not isinstance(logmel, LogMel) or not getattr(b, "reads_logmel", False):
                continue
            if self.logmel is None:
                self.logmel = logmel
            if _same_features(logmel, self.logmel):
                self._reads_features.add(name)

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        parts = meta.get("parts")
        if not isinstance(parts, dict) or not parts:
            return ["parts must map part names to checkpoint documents"]
        roles = model_config.roles()
        problems = [f"model_config.{r} names {n!r}, which is not among parts {sorted(parts)}"
                    for r, n in roles.items() if n not in parts]
        unused = sorted(set(parts) - set(roles.values()))
        if unused:
            problems.append(f"parts {unused} give no output")
        if estimates_rotation(meta) != ("rotation" in roles):
            problems.append("outputs name wy exactly when model_config names a rotation part")
        for name, part in parts.items():
            problems += _part_problems(name, part, meta)
        rot = roles.get("rotation")
        if not problems and rot is not None and not estimates_rotation(parts[rot]):
            problems.append(f"the rotation part {rot!r} estimates no rotation")
        if not problems and "calibration" in meta and \
                not any("calibration" in p for p in parts.values()):
            problems.append("the checkpoint has a calibration but no part was trained with it")
        return problems

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "PerOutputBackend":
        cfg = PerOutputConfig(**ckpt.meta["model_config"])
        names = sorted(set(cfg.roles().values()))
        backends, calibrated = {}, {}
        for name in names:
            part = Checkpoint(meta=ckpt.meta["parts"][name],
                              tensors=part_tensors(ckpt.tensors, name))
            backends[name] = model_backend(part.model_type).from_checkpoint(part)
            calibrated[name] = part.meta.get("calibration") is not None
        extra = sorted(k for k in ckpt.tensors if k.split(SEP, 1)[0] not in names)
        if extra:
            raise ValueError(f"tensors {extra[:3]} belong to no part")
        return cls(cfg.roles(), backends, calibrated)

    def predict(self, windows: np.ndarray, offsets: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        outs = {name: b.predict(windows, offsets if self.calibrated[name] else None)
                for name, b in self.backends.items()}
        return combine({role: outs[name] for role, name in self.roles.items()})

    def predict_with_features(self, windows: np.ndarray, feats: np.ndarray,
                              offsets: np.ndarray | None
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``predict`` with ``feats = self.logmel(windows)`` given (the live estimator's
        sliding log-mel): the parts that read it take it, less the offsets where they were
        trained with them; the others read the windows."""
        outs = {}
        for name, b in self.backends.items():
            off = offsets if self.calibrated[name] else None
            if name in self._reads_features:
                f = feats if off is None else feats - off[:, :, None, None]
                outs[name] = b.infer_features(f)
            else:
                outs[name] = b.predict(windows, off)
        return combine({role: outs[name] for role, name in self.roles.items()})


def _same_features(a: LogMel, b: LogMel) -> bool:
    return a.cfg.to_dict() == b.cfg.to_dict() and a.input_rate == b.input_rate


def combine(outs: dict[str, tuple]) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """p(slip), the velocity and the rate from each role's ``(p, v[, w])``."""
    prob = np.asarray(outs["detection"][0])
    v_speed = np.asarray(outs["speed"][1], np.float64)
    v_dir = np.asarray(outs["direction"][1], np.float64)
    speed = np.linalg.norm(v_speed, axis=1)
    norm = np.linalg.norm(v_dir, axis=1)
    unit = np.where(norm[:, None] > 0, v_dir / np.maximum(norm, 1e-30)[:, None],
                    v_speed / np.maximum(speed, 1e-30)[:, None])
    v = (unit * speed[:, None]).astype(np.float32)
    rot = outs.get("rotation")
    w = None if rot is None or len(rot) < 3 or rot[2] is None else np.asarray(rot[2])
    return prob, v, w
