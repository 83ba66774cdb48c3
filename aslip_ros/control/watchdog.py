"""Staleness watchdog for the controllers' inputs (slip estimates, TCP poses).

A controller must stop the arm when its inputs stop arriving: a crashed inference node, a
dropped network link or a hung driver all look the same from here, as silence. The
watchdog only answers "how old is the newest input?" against a monotonic clock; the clock
is injectable so tests step time by hand instead of sleeping.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Callable, Optional

#: Stale after 50 ms: the stop then leaves about 52 ms after the last valid input (the
#: deadline is exact, see nodes/controller.py) and the scene's arm, with its 20 ms lag, is
#: below 1 mm/s about 110 ms after it; measured with benchmarks.stale_input
#: against the targets of 60 ms (p99) and 150 ms. Five missed 10 ms hops before a stop.
DEFAULT_TIMEOUT_S = 0.05


class Watchdog:
    """Tracks the age of the newest input and reports when it is older than a timeout.

    Thread-safe: subscriptions may :meth:`feed` from one thread while a control timer calls
    :meth:`is_stale` from another. Before the first :meth:`feed` the input counts as stale,
    so a controller never moves on inputs it has not seen.
    """

    def __init__(self, timeout_s: float = DEFAULT_TIMEOUT_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Create a watchdog.

        :param timeout_s: inputs older than this [s] are stale; must be finite and > 0.
        :param clock: monotonic time source [s]; wall clocks jump and must not be used.
        """
        timeout_s = float(timeout_s)
        if not math.isfinite(timeout_s) or timeout_s <= 0.0:
            raise ValueError(f'watchdog timeout must be finite and > 0 s, got {timeout_s}')
        self._timeout_s = timeout_s
        self._clock = clock
        self._lock = threading.Lock()
        self._last: Optional[float] = None

    @property
    def timeout_s(self) -> float:
        """The staleness timeout [s]."""
        return self._timeout_s

    def now(self) -> float:
        """Current time on the watchdog's clock [s]."""
        return self._clock()

    def feed(self, now: Optional[float] = None) -> None:
        """Record that a fresh input arrived at ``now`` (default: the clock's current time)."""
        t = self._clock() if now is None else float(now)
        with self._lock:
            # A feed stamped earlier than the last one (out-of-order callbacks) must not make
            # the input look older than it is.
            if self._last is None or t > self._last:
                self._last = t

    def reset(self) -> None:
        """Forget every input: the watchdog is stale until the next :meth:`feed`."""
        with self._lock:
            self._last = None

    def age(self, now: Optional[float] = None) -> float:
        """Seconds since the newest input; ``inf`` if none has arrived."""
        t = self._clock() if now is None else float(now)
        with self._lock:
            last = self._last
        return math.inf if last is None else max(0.0, t - last)

    def is_stale(self, now: Optional[float] = None) -> bool:
        """True when no input arrived within the timeout (or none ever did)."""
        return self.age(now) > self._timeout_s


class ArrivalStats:
    """Arrival gaps of the input streams and how old slip estimates are when they arrive:
    what the stale-input timeout has to be measured against."""

    def __init__(self, stamp_clock: Callable[[], float] = time.time) -> None:
        """``stamp_clock``: now on the clock of the estimates' stamps [s] (the wall clock;
        simulated time in lockstep)."""
        self._stamp_clock = stamp_clock
        self.slip_gap_max = 0.0
        self.pose_gap_max = 0.0
        self.slip_age_max = 0.0
        self.slip_gaps_over_50ms = 0

    def slip(self, now: float, previous: Optional[float], stamp: float) -> None:
        """One valid slip estimate arrived at ``now`` (monotonic); ``stamp``: its stamp [s]
        (the end of the audio window, on ``stamp_clock``), 0 when unknown."""
        if previous is not None:
            gap = now - previous
            self.slip_gap_max = max(self.slip_gap_max, gap)
            self.slip_gaps_over_50ms += gap > 0.05
        if stamp > 0:
            self.slip_age_max = max(self.slip_age_max, self._stamp_clock() - stamp)

    def pose(self, now: float, previous: Optional[float]) -> None:
        """One TCP pose arrived at ``now`` (monotonic)."""
        if previous is not None:
            self.pose_gap_max = max(self.pose_gap_max, now - previous)

    def values(self) -> dict:
        """Diagnostic values [ms]."""
        return {"slip_gap_max_ms": self.slip_gap_max * 1e3,
                "slip_gaps_over_50ms": int(self.slip_gaps_over_50ms),
                "slip_age_max_ms": self.slip_age_max * 1e3,
                "pose_gap_max_ms": self.pose_gap_max * 1e3}
