"""Self-describing checkpoints that load with ``torch.load(weights_only=True)``.

On disk a checkpoint is one ``torch.save`` file holding a dict of plain types only::

    {"format": "aslip-checkpoint", "version": 1,
     "meta": "<JSON document>",            # str: everything needed to rebuild and check
     "tensors": {name: torch.Tensor}}      # state dict (CNN) or SVM arrays

The JSON document (``meta``) holds ``model_type`` ("aslip_cnn" or "svm"), ``model_config``,
``feature_config``, ``normalization`` (per-mel-bin mean/std, also inside the CNN's state
dict as buffers), ``channel_names``, ``layout``, ``sample_rate`` (Hz, the stream's rate),
``window_s``, ``window_samples``, ``epsilon_m_s``, ``threshold`` and ``provenance``
(dataset path, git revision, seed, stage, init checkpoint, metrics, versions). Keeping the
metadata a JSON string means nothing in the file needs an unpickler beyond tensors.
"""

from __future__ import annotations

import json
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import torch

from aslip_ros.util import atomic_path

FORMAT = "aslip-checkpoint"
VERSION = 1
MODEL_TYPES = ("aslip_cnn", "svm")
_REQUIRED = ("model_type", "feature_config", "channel_names", "sample_rate", "window_s",
             "window_samples", "epsilon_m_s")


class CheckpointMismatch(ValueError):
    """The checkpoint does not fit the stream or dataset it is applied to."""


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


def check_compatible(meta: dict[str, Any], sample_rate: float,
                     channel_names: Sequence[str]) -> None:
    """Raise ``CheckpointMismatch`` unless rate, channel count and names (in order) match."""
    problems = []
    want_rate = float(meta["sample_rate"])
    if abs(float(sample_rate) - want_rate) > 1e-6 * want_rate:
        problems.append(f"sample rate {float(sample_rate):g} Hz != trained {want_rate:g} Hz")
    want = list(meta["channel_names"])
    got = list(channel_names)
    if len(got) != len(want):
        problems.append(f"{len(got)} channels != trained {len(want)} channels")
    if got != want:
        problems.append(f"channel names {got} != trained {want}")
    if problems:
        raise CheckpointMismatch("checkpoint does not match the input: " + "; ".join(problems)
                                 + f" (layout {meta.get('layout')!r})")


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
    missing = [k for k in _REQUIRED if k not in meta]
    if missing:
        raise ValueError(f"checkpoint metadata lacks {missing}")
    if meta["model_type"] not in MODEL_TYPES:
        raise ValueError(f"unknown model_type {meta['model_type']!r}")
    doc = json.dumps(_plain(meta), allow_nan=False)
    clean = {}
    for k, v in tensors.items():
        if not isinstance(v, torch.Tensor):
            raise ValueError(f"tensor {k!r} is a {type(v).__name__}, not a torch.Tensor")
        clean[str(k)] = v.detach().cpu().contiguous()
    payload = {"format": FORMAT, "version": VERSION, "meta": doc, "tensors": clean}
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
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
    meta = json.loads(payload["meta"])
    missing = [k for k in _REQUIRED if k not in meta]
    if missing:
        raise ValueError(f"{path}: checkpoint metadata lacks {missing}")
    return Checkpoint(meta=meta, tensors=dict(payload["tensors"]))
