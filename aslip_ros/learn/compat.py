"""Whether a checkpoint fits a stream: the one check of rate and channel names.

Floor of ``learn``: the checkpoint format, the per-grasp calibration and every predictor
raise ``CheckpointMismatch`` (a ValueError) from here, so none of them imports another for
it.
"""

from __future__ import annotations

from typing import Any, Sequence


class CheckpointMismatch(ValueError):
    """The checkpoint does not fit the stream or dataset it is applied to."""


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
