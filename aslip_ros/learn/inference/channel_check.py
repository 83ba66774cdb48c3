"""Dead or disconnected microphones in one audio window (ROS-free, numpy only, cheap).

    dead = dead_channels(window, channel_names)    # window: (N, C) float, full scale 1.0

A model fed a window in which one channel is digital silence, or far below the others,
under-reports slip (``make stability``: one disconnected microphone drives detection
down). Live users (``slip_inference``) withhold the estimate for such a window instead.
"""

from __future__ import annotations

import math
import statistics
from typing import Sequence

import numpy as np


#: RMS (full scale = 1.0) at or below which a channel is digital silence: about -140 dBFS,
#: under the LSB of a 24-bit converter and far under any real microphone's noise floor.
DEAD_FLOOR_RMS = 1e-7
#: A channel this far below the median of the other channels is dead (normal level
#: differences between the microphones of one grasp stay within about 20 dB).
DEAD_MARGIN_DB = 40.0


def dead_channels(window: np.ndarray, channel_names: Sequence[str],
                  margin_db: float = DEAD_MARGIN_DB,
                  floor_rms: float = DEAD_FLOOR_RMS) -> list[str]:
    """The channels of one ``(N, C)`` window that look dead or disconnected, in order.

    A channel is dead when its RMS is at or below ``floor_rms`` (digital silence, e.g. an
    unplugged input), or when it lies more than ``margin_db`` below the median RMS of the
    other channels while that median is above ``floor_rms``. Channels quiet together
    (silence, no slip: all at their noise floor) are never flagged, nor are level
    differences well inside the margin. A channel holding NaN or Inf is not judged here
    (the stream gate drops such frames). Costs one pass over the window (~20 us at
    2400 x 4) and never warns or returns NaN.
    """
    x = np.asarray(window)
    if x.dtype.kind != "f":
        x = x.astype(np.float32)            # integers would overflow when squared
    if x.ndim != 2 or x.shape[1] != len(channel_names):
        raise ValueError(f"expected a window shaped (N, {len(channel_names)}), got {x.shape}")
    if not (math.isfinite(margin_db) and margin_db > 0.0):
        raise ValueError(f"margin_db must be finite and > 0, got {margin_db}")
    if not (math.isfinite(floor_rms) and floor_rms >= 0.0):
        raise ValueError(f"floor_rms must be finite and >= 0, got {floor_rms}")
    if x.shape[0] == 0:
        return []
    # Mean square per channel without a squared copy of the window: one BLAS dot per
    # channel (float32 accumulation is ample for a level decision; a column-wise einsum
    # costs the live path 2-3x more on a 200 ms window).
    n = x.shape[0]
    ms = [float(np.dot(col, col)) / n for col in x.T]
    rms = [math.sqrt(v) if v >= 0.0 else math.nan for v in ms]   # NaN stays NaN
    ratio = 10.0 ** (-margin_db / 20.0)
    dead = []
    for i, r in enumerate(rms):
        if r <= floor_rms:
            dead.append(channel_names[i])
            continue
        others = [o for j, o in enumerate(rms) if j != i and math.isfinite(o)]
        if others:
            ref = statistics.median(others)
            if ref > floor_rms and r < ref * ratio:
                dead.append(channel_names[i])
    return dead
