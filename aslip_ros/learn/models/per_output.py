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

A role may name a blend of parts, joined by ``BLEND`` (``svm+unfrozen``): its output is
the parts' mean (``combine``): the mean p(slip), the mean speed, the unit vector of the sum
of the parts' unit directions (a part whose velocity is 0 has no say), the mean rate.
Candidate models of different kinds err apart, and their mean errs less than either where
neither is much better (docs/model.md, "Each output from the candidate that gives it best").

Each part reads the same windows; the per-grasp offsets the stream computes go to the parts
trained with the calibration (their ``calibration`` must equal the checkpoint's) and not to
those trained without. A part is a window model (no streaming one, no ``per_output``) of the
checkpoint's rate, channels and window. The metrics of the combination are the parts':
detection reads only p(slip), the speed error only the velocity's norm and the direction
error only its angle (learn/metrics.py). A part that gives only the speed, and can give it
alone (an SVM: ``predict_speed``, ``infer_speed``), computes only that, unless some window
has no direction from the direction parts.
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
#: Joins the parts of a blend in a role's name (candidate names hold no "+").
BLEND = "+"


def members(name: str) -> list[str]:
    """The parts a role's name stands for: one, or a blend's (``BLEND``)."""
    return name.split(BLEND)


def blend(names: list[str]) -> str:
    """The role name of the blend of ``names`` (in that order)."""
    if any(BLEND in n or not n for n in names):
        raise ValueError(f"part names must be non-empty and hold no {BLEND!r}: {names}")
    return BLEND.join(names)


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
        """role -> part name (or blend, ``members``), the roles this model fills."""
        return {r: n for r, n in self.to_dict().items() if n is not None}

    def parts(self) -> list[str]:
        """Every part some role reads, sorted."""
        return sorted({m for n in self.roles().values() for m in members(n)})


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
    cfg = PerOutputConfig(**roles)
    used = cfg.parts()
    meta = copy.deepcopy(parts[members(roles["detection"])[0]].meta)
    for key in ("calibration", "output_calibration", "normalization"):
        meta.pop(key, None)
    docs = {name: copy.deepcopy(parts[name].meta) for name in used}
    calibrations = [docs[n]["calibration"] for n in used if "calibration" in docs[n]]
    if calibrations:
        meta["calibration"] = calibrations[0]
    meta.update(model_type=PerOutputBackend.model_type, parts=docs,
                model_config=cfg.to_dict(),
                outputs=list(KNOWN_OUTPUTS if roles.get("rotation") else PLANAR_OUTPUTS))
    tensors = {f"{name}{SEP}{k}": v for name in used for k, v in parts[name].tensors.items()}
    return Checkpoint(meta=meta, tensors=tensors)


def document_problems(name: str, part: Any, container: str) -> list[str]:
    """What makes part ``name``'s document no part of a ``container`` checkpoint (one that
    holds its parts' documents: this one, ``aslip_hybrid``): not a document, a container
    itself, or an unsound document (``validate_meta``)."""
    where = f"parts.{name}"
    if not isinstance(part, dict):
        return [f"{where} must be a checkpoint document, got {type(part).__name__}"]
    if part.get("model_type") == container:
        return [f"{where} is itself a {container} model"]
    return [f"{where}: {p}" for p in validate_meta(part)]


def _part_problems(name: str, part: Any, meta: dict[str, Any]) -> list[str]:
    where = f"parts.{name}"
    problems = document_problems(name, part, PerOutputBackend.model_type)
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
        #: Parts that give the speed and nothing else, and can give it alone
        #: (``predict_speed``, ``infer_speed``: an SVM): only that is computed of them.
        others = {m for r, n in roles.items() if r != "speed" for m in members(n)}
        self._speed_only = {m for m in members(roles["speed"]) if m not in others
                            and hasattr(backends[m], "predict_speed")}

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        parts = meta.get("parts")
        if not isinstance(parts, dict) or not parts:
            return ["parts must map part names to checkpoint documents"]
        roles = model_config.roles()
        problems = [f"model_config.{r} names {m!r}, which is not among parts {sorted(parts)}"
                    for r, n in roles.items() for m in members(n) if m not in parts]
        unused = sorted(set(parts) - set(model_config.parts()))
        if unused:
            problems.append(f"parts {unused} give no output")
        if estimates_rotation(meta) != ("rotation" in roles):
            problems.append("outputs name wy exactly when model_config names a rotation part")
        for name, part in parts.items():
            problems += _part_problems(name, part, meta)
        rot = roles.get("rotation")
        for m in [] if problems or rot is None else members(rot):
            if not estimates_rotation(parts[m]):
                problems.append(f"the rotation part {m!r} estimates no rotation")
        if not problems and "calibration" in meta and \
                not any("calibration" in p for p in parts.values()):
            problems.append("the checkpoint has a calibration but no part was trained with it")
        return problems

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "PerOutputBackend":
        cfg = PerOutputConfig(**ckpt.meta["model_config"])
        names = cfg.parts()
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
        def run(name: str, b: Any, speed_only: bool):
            off = offsets if self.calibrated[name] else None
            return _speed_output(b.predict_speed(windows, off)) if speed_only \
                else b.predict(windows, off)
        return self._combined(run)

    def predict_with_features(self, windows: np.ndarray, feats: np.ndarray,
                              offsets: np.ndarray | None
                              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``predict`` with ``feats = self.logmel(windows)`` given (the live estimator's
        sliding log-mel): the parts that read it take it, less the offsets where they were
        trained with them; the others read the windows."""
        def run(name: str, b: Any, speed_only: bool):
            off = offsets if self.calibrated[name] else None
            if name not in self._reads_features:
                return _speed_output(b.predict_speed(windows, off)) if speed_only \
                    else b.predict(windows, off)
            f = feats if off is None else feats - off[:, :, None, None]
            return _speed_output(b.infer_speed(f)) if speed_only else b.infer_features(f)
        return self._combined(run)

    def _combined(self, run) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``combine`` of every part's output, ``run(name, backend, speed_only)``: of the
        speed-only parts their speed alone, unless some window has no direction from the
        direction parts (the speed parts' own direction then stands in: run them whole)."""
        outs = {n: run(n, b, n in self._speed_only) for n, b in self.backends.items()}
        if self._speed_only and not _has_direction(
                [outs[m] for m in members(self.roles["direction"])]):
            outs.update({n: run(n, self.backends[n], False) for n in self._speed_only})
        return combine(role_outputs(self.roles, outs))


def _speed_output(speed: np.ndarray) -> tuple[None, np.ndarray, None]:
    """A speed-only part's output as ``combine`` reads it for the speed role: a velocity of
    that norm (along x: its direction is read only where the direction parts give none,
    and ``_combined`` then runs the part whole)."""
    speed = np.asarray(speed, np.float64)
    return None, np.stack([speed, np.zeros_like(speed)], axis=1), None


def _has_direction(outs: list[tuple]) -> bool:
    """Whether the summed unit directions of ``outs`` (``combine``'s direction) are
    defined in every window."""
    unit = sum(_unit(np.asarray(o[1], np.float64)) for o in outs)
    return bool(np.all(np.linalg.norm(unit, axis=1) > 0))


def _same_features(a: LogMel, b: LogMel) -> bool:
    return a.cfg.to_dict() == b.cfg.to_dict() and a.input_rate == b.input_rate


def role_outputs(roles: dict[str, str], outs: dict[str, tuple]) -> dict[str, list[tuple]]:
    """role -> the ``(p, v[, w])`` of each of its parts (``members``), from each part's."""
    return {role: [outs[m] for m in members(name)] for role, name in roles.items()}


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0)


def combine(outs: dict[str, list[tuple]]) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """p(slip), the velocity and the rate from each role's parts' ``(p, v[, w])`` (a list:
    one part, or a blend's, averaged as the module docstring says)."""
    def velocities(role: str) -> list[np.ndarray]:
        return [np.asarray(o[1], np.float64) for o in outs[role]]

    prob = np.mean([np.asarray(o[0], np.float64) for o in outs["detection"]], axis=0)
    speed = np.mean([np.linalg.norm(v, axis=1) for v in velocities("speed")], axis=0)
    unit = _unit(sum(_unit(v) for v in velocities("direction")))
    # Where the direction parts have none, the speed parts' own.
    fallback = _unit(sum(_unit(v) for v in velocities("speed")))
    unit = np.where(np.linalg.norm(unit, axis=1, keepdims=True) > 0, unit, fallback)
    v = (unit * speed[:, None]).astype(np.float32)
    rot = outs.get("rotation")
    rates = [] if rot is None else [o[2] for o in rot if len(o) > 2 and o[2] is not None]
    w = None if not rates or len(rates) < len(rot) else \
        np.mean([np.asarray(r, np.float64) for r in rates], axis=0).astype(np.float32)
    return prob.astype(np.float32), v, w
