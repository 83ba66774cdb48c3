"""The streaming model and a window model run as one: ``aslip_hybrid`` (issue #37).

The causal streaming model (``aslip_stream``) answers every 10 ms hop from the audio up to
that hop, so it notices slip first; the 200 ms window CNN reads the whole window at once
and gives the steadier direction and speed, about half a window late. Neither is best at
both closed-loop tasks (docs/results.md, Table III). A hybrid checkpoint holds both and
says which gives each output; the live estimator runs them side by side
(learn/inference/hybrid_estimator.py): the stream part answers every hop as it always
does, and each of its estimates takes the outputs the checkpoint gives the window part
from the newest window estimate, when there is one no older than ``max_window_age_s``
(else the stream part's own).

The checkpoint holds the two parts' whole documents under ``parts`` (``stream``,
``window``) and their tensors as ``stream/<tensor>`` and ``window/<tensor>``, as a
``per_output`` checkpoint does. ``model_config`` names the part of each role: ``stream``,
``window`` or ``stream+window`` (their mean: ``per_output.combine``). The detection is one
part's, or ``either``'s: slip when either part says so at its own threshold, the estimate
then taking p(slip) and threshold from the part that said it (the stream part's first), or
``latched``'s: only the stream part starts a slip, and while one goes on either part keeps
it (a window estimate alone never starts one). The checkpoint's threshold and output
calibration are the stream part's under ``either`` and ``latched``. The
top-level stream facts (rate, channels, window, features) are the window part's: the
longest audio any estimate reads. Build one with ``assemble``.

The default (``HybridConfig()``): the stream part starts a slip and either part keeps it
(``latched``), the window part gives the speed and the direction, the stream part the
rotation. It is the package's default estimator (``aslip``: ``models/aslip.pt``, run by
both closed-loop launch files and ``make demo``). In the closed loop (docs/results.md, "One
estimator for both tasks") it stops as the streaming model does, also at 4x the robot's
noise, where ``either`` and the window CNN stop early on the approach (15/15 against 6/15),
and it tracks as the window CNN does (7.6 against 7.4 mm over 50 slip-tracks; the stream
part's detection alone 8.4, the streaming model 11.6).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import hashlib
import os
from pathlib import Path
from dataclasses import dataclass
from typing import Any, ClassVar

from aslip_ros.learn.checkpoint import (KNOWN_OUTPUTS, PLANAR_OUTPUTS, Checkpoint,
                                        estimates_rotation, validate_meta)
from aslip_ros.learn.models.per_output import (BLEND, ROLES, SEP, document_problems, members,
                                               part_tensors)
from aslip_ros.learn.models.registry import model_backend, register_model

STREAM, WINDOW = "stream", "window"
PARTS = (STREAM, WINDOW)
#: The detection of either part: slip when either says so (module docstring).
EITHER = "either"
#: The stream part starts a slip, either part keeps it going (module docstring).
LATCHED = "latched"
DETECTIONS = PARTS + (EITHER, LATCHED)
#: What a role may name: one part, or the blend of both.
CHOICES = (STREAM, WINDOW, STREAM + BLEND + WINDOW)
#: The stream facts both parts must share with the checkpoint.
SHARED = ("sample_rate", "channel_names")


@dataclass(frozen=True)
class HybridConfig:
    """Which part gives each output, and how old a window estimate may be to be used [s]
    (counted on the stream clock, from its window's last sample to the hop's)."""

    detection: str = LATCHED
    speed: str = WINDOW
    direction: str = WINDOW
    rotation: str | None = STREAM
    max_window_age_s: float = 0.1

    def __post_init__(self) -> None:
        for role in ROLES[1:]:
            name = getattr(self, role)
            if name is None and role == "rotation":
                continue
            if name not in CHOICES:
                raise ValueError(f"{role} must be one of {CHOICES}, got {name!r}")
        if self.detection not in DETECTIONS:
            raise ValueError(f"detection must be one of {DETECTIONS}, got "
                             f"{self.detection!r}")
        if not 0.0 < self.max_window_age_s <= 10.0:
            raise ValueError(f"max_window_age_s must be in (0, 10], got {self.max_window_age_s}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def roles(self) -> dict[str, str]:
        """role -> part name (or ``stream+window``, or ``either``), the roles this model
        fills."""
        return {r: getattr(self, r) for r in ROLES if getattr(self, r) is not None}

    @property
    def threshold_part(self) -> str:
        """The part whose threshold is the checkpoint's (and the ``threshold`` parameter's)."""
        return STREAM if self.detection in (EITHER, LATCHED) else self.detection


def assemble(stream: Checkpoint, window: Checkpoint,
             config: HybridConfig = HybridConfig()) -> Checkpoint:
    """The hybrid checkpoint of a streaming and a window checkpoint; ValueError when they do
    not fit together (another stream, a part of the wrong kind, a rotation neither has)."""
    parts = {STREAM: stream, WINDOW: window}
    meta = copy.deepcopy(window.meta)
    for key in ("calibration", "output_calibration", "normalization", "provenance",
                "train_config", "loss_weights", "parts"):
        meta.pop(key, None)
    detection = parts[config.threshold_part].meta
    meta["threshold"] = detection.get("threshold")
    if detection.get("output_calibration") is not None:
        meta["output_calibration"] = copy.deepcopy(detection["output_calibration"])
    meta.update(model_type=HybridBackend.model_type, model_config=config.to_dict(),
                parts={n: copy.deepcopy(p.meta) for n, p in parts.items()},
                outputs=list(KNOWN_OUTPUTS if config.rotation else PLANAR_OUTPUTS))
    tensors = {f"{n}{SEP}{k}": v for n, p in parts.items() for k, v in p.tensors.items()}
    problems = validate_meta(meta)
    if problems:
        raise ValueError("these checkpoints make no hybrid: " + "; ".join(problems))
    return Checkpoint(meta=meta, tensors=tensors)


def _part_problems(name: str, part: Any, meta: dict[str, Any]) -> list[str]:
    where = f"parts.{name}"
    problems = document_problems(name, part, HybridBackend.model_type)
    if problems:
        return problems
    streams = bool(model_backend(part["model_type"]).streaming)
    if streams != (name == STREAM):
        problems.append(f"{where} must be a {'streaming' if name == STREAM else 'window'} "
                        f"model, got {part['model_type']}")
    for key in SHARED:
        if part.get(key) != meta.get(key):
            problems.append(f"{where}.{key} {part.get(key)!r} differs from the checkpoint's "
                            f"{meta.get(key)!r}")
    return problems


@register_model
class HybridBackend:
    """The two parts of a hybrid checkpoint, loaded (module docstring). It streams: the
    live estimator runs it (``hybrid_estimator.HybridEstimator``), not a window
    ``predict``."""

    model_type: ClassVar[str] = "aslip_hybrid"
    config: ClassVar[type] = HybridConfig
    streaming: ClassVar[bool] = True

    def __init__(self, config: HybridConfig, parts: dict[str, Checkpoint]) -> None:
        self.cfg = config
        self.parts = parts

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        parts = meta.get("parts")
        if not isinstance(parts, dict) or sorted(parts) != sorted(PARTS):
            return [f"parts must hold exactly {list(PARTS)}"]
        problems = []
        for name, part in parts.items():
            problems += _part_problems(name, part, meta)
        if problems:
            return problems
        if estimates_rotation(meta) != (model_config.rotation is not None):
            problems.append("outputs name wy exactly when model_config names a rotation part")
        for m in members(model_config.rotation) if model_config.rotation else []:
            if not estimates_rotation(parts[m]):
                problems.append(f"the rotation part {m!r} estimates no rotation")
        return problems

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "HybridBackend":
        cfg = HybridConfig(**ckpt.meta["model_config"])
        extra = sorted(k for k in ckpt.tensors if k.split(SEP, 1)[0] not in PARTS)
        if extra:
            raise ValueError(f"tensors {extra[:3]} belong to no part")
        return cls(cfg, {n: Checkpoint(meta=ckpt.meta["parts"][n],
                                       tensors=part_tensors(ckpt.tensors, n))
                         for n in PARTS})


def parts_sha256(stream: str | os.PathLike, window: str | os.PathLike) -> dict[str, str]:
    """The sha256 of two part files, as :func:`assembled_from` gives them back."""
    return {n: hashlib.sha256(Path(p).read_bytes()).hexdigest()
            for n, p in zip(PARTS, (stream, window))}


def assembled_from(path: str | os.PathLike) -> dict[str, str] | None:
    """The sha256 of the two files a hybrid checkpoint was assembled from (``stream``,
    ``window``), as :func:`write_hybrid` recorded them; None for any other file."""
    from aslip_ros.learn.checkpoint import load_checkpoint
    try:
        src = load_checkpoint(path).meta.get("provenance", {}).get("assembled_from")
    except (OSError, ValueError):
        return None
    if not isinstance(src, dict):
        return None
    return {n: src.get(f"{n}_sha256") for n in PARTS}


def write_hybrid(stream: str | os.PathLike, window: str | os.PathLike,
                 out: str | os.PathLike, config: HybridConfig = HybridConfig()) -> Path:
    """Assemble the hybrid of two checkpoint files and write it to ``out`` (atomically),
    recording the parts' names and sha256 in ``provenance.assembled_from``. OSError /
    ValueError when a part is unreadable or they make no hybrid."""
    from aslip_ros.learn.checkpoint import load_checkpoint, save_checkpoint
    ck = assemble(load_checkpoint(stream), load_checkpoint(window), config)
    out = Path(out)
    sha = parts_sha256(stream, window)
    ck.meta["provenance"] = {"assembled_from": {
        "stream": Path(stream).name, "window": Path(window).name,
        "stream_sha256": sha[STREAM], "window_sha256": sha[WINDOW]}}
    out.parent.mkdir(parents=True, exist_ok=True)
    return Path(save_checkpoint(out, ck.meta, ck.tensors))


# --- ``aslip hybrid`` ------------------------------------------------------------------------

def add_arguments(p: argparse.ArgumentParser) -> None:
    d = HybridConfig()
    p.add_argument("--stream", required=True,
                   help="the streaming checkpoint (aslip train --stage stream)")
    p.add_argument("--window", required=True,
                   help="the window checkpoint (aslip train), of the same stream")
    p.add_argument("--out", required=True, help="the hybrid checkpoint to write")
    p.add_argument("--detection", choices=DETECTIONS, default=d.detection,
                   help="the part that says slip; either: slip when either part does, at "
                        "its own threshold; latched: the stream part starts a slip and "
                        "either part keeps it")
    for role in ("speed", "direction"):
        p.add_argument(f"--{role}", choices=CHOICES, default=getattr(d, role),
                       help=f"the part that gives the {role} ({STREAM + BLEND + WINDOW}: "
                            "their mean)")
    p.add_argument("--rotation", choices=CHOICES + ("none",), default=d.rotation,
                   help="the part that gives the rotational rate (none: no rotational "
                        "output)")
    p.add_argument("--max-window-age", type=float, default=d.max_window_age_s,
                   help="a window estimate older than this [s] is not used; the hop then "
                        "takes the stream part's own outputs")


def run(args: argparse.Namespace) -> int:
    cfg = HybridConfig(detection=args.detection, speed=args.speed, direction=args.direction,
                       rotation=None if args.rotation == "none" else args.rotation,
                       max_window_age_s=args.max_window_age)
    out = write_hybrid(args.stream, args.window, args.out, cfg)
    roles = ", ".join(f"{r} {n}" for r, n in cfg.roles().items())
    print(f"wrote {out}: {roles}")
    return 0
