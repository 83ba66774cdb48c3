"""Tap detection and the channel-order verdict of ``aslip check taps``.

The person at the gripper taps each pad in turn while the check prompts for it: pad ``i``
is expected in the ``i``-th interval of ``seconds_per_pad`` after a short lead-in, on the
stream's own clock (sample index / rate), so a recording replayed faster than real time
gives the same answer as the live device.

A tap is an onset: the energy of a 10 ms frame on some channel rises far
(:data:`ONSET_DB`) above that channel's running noise floor. The channel with the most
energy over the :data:`TAP_WINDOW_S` after the onset is where the tap came in.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np

from aslip_ros.bringup.verdict import Verdict

FRAME_S = 0.010
#: A frame this far above its channel's noise floor is an onset.
ONSET_DB = 20.0
#: Energy below this (dBFS, mean square) is never an onset, however quiet the floor.
MIN_ONSET_DBFS = -60.0
#: The loudest channel is decided over this long after the onset.
TAP_WINDOW_S = 0.05
#: No new tap starts this soon after one (a tap rings for a while).
REFRACTORY_S = 0.25
#: The noise floor follows quieter frames quickly and louder ones slowly.
FLOOR_RISE, FLOOR_FALL = 0.02, 0.5
#: Before the first prompt: the noise floor is learnt and the person reads the prompt.
LEAD_IN_S = 1.0
#: The share of a pad's taps that must agree on one channel.
MIN_AGREEMENT = 2.0 / 3.0


@dataclass(frozen=True)
class Tap:
    """One detected tap: its onset [s of stream time] and per-channel energy [dBFS]."""

    time_s: float
    channel: int
    levels_dbfs: tuple


class TapDetector:
    """Feed blocks (``(frames, channels)``, with their first sample index); get taps.

    :param sample_rate: [Hz].
    :param channels: channel count.
    """

    def __init__(self, sample_rate: float, channels: int) -> None:
        self.rate = float(sample_rate)
        self.channels = int(channels)
        self.hop = max(1, int(round(self.rate * FRAME_S)))
        self._window_frames = max(1, int(round(TAP_WINDOW_S / FRAME_S)))
        self._pending = np.zeros((0, self.channels))
        self._pending_index = 0
        self._floor: Optional[np.ndarray] = None
        self._tap_start: Optional[int] = None      # onset sample of the tap being measured
        self._tap_energy = np.zeros(self.channels)
        self._tap_frames = 0
        self._last_onset = -np.inf

    def feed(self, data: np.ndarray, first_sample_index: int) -> List[Tap]:
        """Add a block; return the taps whose measuring window ended in it."""
        x = np.asarray(data, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.channels:
            raise ValueError(f'block shaped {x.shape}, expected (frames, {self.channels})')
        if first_sample_index != self._pending_index + len(self._pending):
            # A gap (dropped blocks): start the frame grid again at the block.
            self._pending = np.zeros((0, self.channels))
            self._pending_index = int(first_sample_index)
        buf = np.concatenate([self._pending, x])
        taps = []
        n_frames = len(buf) // self.hop
        for k in range(n_frames):
            frame = buf[k * self.hop:(k + 1) * self.hop]
            tap = self._frame(np.mean(np.square(frame), axis=0),
                              self._pending_index + k * self.hop)
            if tap is not None:
                taps.append(tap)
        used = n_frames * self.hop
        self._pending = buf[used:]
        self._pending_index += used
        return taps

    def _frame(self, energy: np.ndarray, start: int) -> Optional[Tap]:
        if self._floor is None:
            self._floor = np.maximum(energy, 1e-20)
        if self._tap_start is not None:
            self._tap_energy += energy
            self._tap_frames += 1
            if self._tap_frames >= self._window_frames:
                return self._end_tap()
            return None
        ratio_db = 10.0 * np.log10(np.maximum(energy, 1e-20) / self._floor)
        loud = 10.0 * np.log10(np.maximum(energy, 1e-20)) > MIN_ONSET_DBFS
        t = start / self.rate
        if np.any((ratio_db > ONSET_DB) & loud) and t - self._last_onset >= REFRACTORY_S:
            self._tap_start, self._last_onset = start, t
            self._tap_energy = energy.copy()
            self._tap_frames = 1
            return None
        # The floor learns only between taps, and only slowly upwards.
        rate = np.where(energy < self._floor, FLOOR_FALL, FLOOR_RISE)
        if t - self._last_onset >= REFRACTORY_S:
            self._floor = np.maximum(self._floor + rate * (energy - self._floor), 1e-20)
        return None

    def _end_tap(self) -> Tap:
        e = self._tap_energy / self._tap_frames
        tap = Tap(self._tap_start / self.rate, int(np.argmax(e)),
                  tuple(float(10.0 * np.log10(max(v, 1e-20))) for v in e))
        self._tap_start = None
        return tap


def pad_of(time_s: float, seconds_per_pad: float, lead_in_s: float = LEAD_IN_S) -> int:
    """Index of the pad whose interval holds ``time_s`` (-1 in the lead-in)."""
    if time_s < lead_in_s:
        return -1
    return int((time_s - lead_in_s) // seconds_per_pad)


def _label(names: Sequence[str], channel: int) -> str:
    return f'channel {channel} ({names[channel]})'


def taps_verdict(names: Sequence[str], taps: Sequence[Tap], seconds_per_pad: float,
                 taps_per_pad: int = 1, lead_in_s: float = LEAD_IN_S) -> Verdict:
    """Whether pad ``i`` (``names[i]``) came in on channel ``i`` for every pad.

    A mismatch names the pad tapped, the channel that was loudest instead, and the swap or
    the order that would fix it.
    """
    verdict = Verdict()
    heard: dict = {}
    for i, name in enumerate(names):
        mine = [t.channel for t in taps if pad_of(t.time_s, seconds_per_pad, lead_in_s) == i]
        if not mine:
            verdict.fail(f'no tap detected while {name} was prompted: tap harder, or '
                         f'{_label(names, i)} is dead (run aslip check audio)')
            continue
        if len(mine) < taps_per_pad:
            verdict.notes.append(f'{name}: {len(mine)} of {taps_per_pad} taps detected')
        channel, count = Counter(mine).most_common(1)[0]
        if count < MIN_AGREEMENT * len(mine):
            verdict.fail(f'taps on {name} were loudest on different channels {mine}: tap '
                         'the pad itself, firmly, away from the others')
            continue
        heard[i] = channel
    wrong = {i: ch for i, ch in heard.items() if ch != i}
    for i, ch in wrong.items():
        fix = (f'swap channels {min(i, ch)} and {max(i, ch)}' if heard.get(ch) == i else
               f'{names[i]} is wired to input {ch}')
        verdict.fail(f'you tapped {names[i]} but {_label(names, ch)} was loudest: {fix}')
    if wrong and len(heard) == len(names) and sorted(heard.values()) == list(range(len(names))):
        order = [names[i] for i in sorted(heard, key=heard.get)]
        verdict.notes.append('the channel names in input order are: ' + ','.join(order))
    return verdict
