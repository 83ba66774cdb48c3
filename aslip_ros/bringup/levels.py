"""Per-channel audio levels of a short recording, and what they say about each microphone.

Accumulated block by block (:class:`LevelMeter`), so a long check holds no audio. Levels
are dBFS against full scale +-1: a full-scale sine reads -3 dBFS RMS and 0 dBFS peak.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Sequence

import numpy as np

from aslip_ros.bringup.verdict import Verdict

#: A sample at or beyond this magnitude counts as clipped (float capture saturates at 1).
CLIP_LEVEL = 0.999
#: Below this RMS a channel counts as silent: below the self-noise of any wired
#: preamplifier input, so a dead piezo, an open cable or a muted input.
DEFAULT_SILENT_DBFS = -80.0
#: A mean beyond this (fraction of full scale) is a DC offset worth fixing.
DEFAULT_MAX_DC = 0.05

OK, SILENT, CLIPPING, DC = 'OK', 'SILENT', 'CLIPPING', 'DC'
#: What to do about each finding (printed after the verdict word).
ADVICE = {
    SILENT: 'dead mic or wiring: check the cable, the input and its gain; tap the pad '
            'while the check runs',
    CLIPPING: 'lower the gain',
    DC: 'DC offset: phantom power or a faulty input; switch phantom power off for piezos',
}


def dbfs(x: float) -> float:
    """20 log10(x), -inf for 0."""
    return 20.0 * math.log10(x) if x > 0.0 else -math.inf


@dataclass(frozen=True)
class ChannelLevels:
    """One channel's levels and its verdict word (``OK``, ``SILENT``, ``CLIPPING``, ``DC``)."""

    name: str
    rms_dbfs: float
    peak_dbfs: float
    clipped: int
    dc: float
    status: str

    def row(self) -> str:
        """One table row."""
        advice = f' ({ADVICE[self.status]})' if self.status in ADVICE else ''
        return (f'{self.name:>20s} {self.rms_dbfs:9.1f} {self.peak_dbfs:9.1f} '
                f'{self.clipped:8d} {self.dc:+9.4f}  {self.status}{advice}')


HEADER = f"{'channel':>20s} {'RMS dBFS':>9s} {'peak dBFS':>9s} {'clipped':>8s} {'DC':>9s}  verdict"


def classify(rms_dbfs: float, clipped: int, dc: float,
             silent_dbfs: float = DEFAULT_SILENT_DBFS, max_dc: float = DEFAULT_MAX_DC) -> str:
    """The verdict word of one channel; a silent channel's other numbers mean nothing."""
    if not rms_dbfs > silent_dbfs:
        return SILENT
    if clipped > 0:
        return CLIPPING
    if abs(dc) > max_dc:
        return DC
    return OK


class LevelMeter:
    """Running per-channel sums over the blocks fed to it.

    :param names: one name per channel, in column order.
    """

    def __init__(self, names: Sequence[str]) -> None:
        self.names = [str(n) for n in names]
        n = len(self.names)
        if n < 1:
            raise ValueError('at least one channel is needed')
        self.frames = 0
        self._sum = np.zeros(n)
        self._sumsq = np.zeros(n)
        self._peak = np.zeros(n)
        self._clipped = np.zeros(n, dtype=np.int64)

    def feed(self, data: np.ndarray) -> None:
        """Add a ``(frames, channels)`` block."""
        x = np.asarray(data, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != len(self.names):
            raise ValueError(f'block shaped {x.shape}, expected (frames, {len(self.names)})')
        if not x.size:
            return
        self.frames += x.shape[0]
        self._sum += x.sum(axis=0)
        self._sumsq += np.square(x).sum(axis=0)
        mag = np.abs(x)
        self._peak = np.maximum(self._peak, mag.max(axis=0))
        self._clipped += (mag >= CLIP_LEVEL).sum(axis=0)

    def levels(self, silent_dbfs: float = DEFAULT_SILENT_DBFS,
               max_dc: float = DEFAULT_MAX_DC) -> List[ChannelLevels]:
        """Per-channel levels so far; ValueError before the first frame."""
        if self.frames == 0:
            raise ValueError('no audio was recorded')
        mean = self._sum / self.frames
        # The RMS of the signal around its mean, so a DC offset does not hide a dead mic.
        var = np.maximum(self._sumsq / self.frames - np.square(mean), 0.0)
        out = []
        for k, name in enumerate(self.names):
            rms = dbfs(float(np.sqrt(var[k])))
            out.append(ChannelLevels(name, rms, dbfs(float(self._peak[k])),
                                     int(self._clipped[k]), float(mean[k]),
                                     classify(rms, int(self._clipped[k]), float(mean[k]),
                                              silent_dbfs, max_dc)))
        return out


def levels_verdict(levels: Sequence[ChannelLevels]) -> Verdict:
    """FAIL naming every channel that is not OK."""
    verdict = Verdict()
    for ch in levels:
        if ch.status != OK:
            verdict.fail(f'{ch.name} {ch.status} ({ADVICE[ch.status]})')
    return verdict


def format_levels(levels: Sequence[ChannelLevels]) -> str:
    """The per-channel table."""
    return '\n'.join([HEADER] + [ch.row() for ch in levels])
