"""Is every stream of a recording arriving? The one verdict on a trial's streams.

A hardware trial records streams that come from elsewhere (the audio interface, the
motion-capture driver). A stream that never arrives, or stops mid-trial, leaves a bag that
looks like a recording and holds nothing to label; a lab would find out at export. The
watch turns that into a verdict while the trial runs: :meth:`StreamWatch.check` names the
first stream that failed, and ``nodes/stream_watch.py`` exits 1 with it, which ends
``data_collection.launch.py`` with exit status 1 (the launch file's event handling).

Thresholds (:class:`WatchConfig`, the node's parameters are built from it):

- ``start_timeout_s``: every stream's first message within this long of the watch's start
  (node start-up and discovery included: a pose stream was measured 2 s late on an idle
  machine, and the hardware rehearsal's audio over 5 s late on a 2-core CI machine beside
  two CPU hogs; 15 s is three times that, and a dead stream still fails the trial early);
- ``stall_timeout_s``: a stream that delivered and then says nothing for this long has
  stopped. The streams run at 100 Hz (audio blocks of 10 ms) to 120 Hz (motion capture),
  so 1 s is 100 missed messages: no scheduling hiccup, and longer than any pose dropout
  the export tolerates (``labels.DEFAULT_MAX_GAP_S``), yet the trial ends within about a
  second of the failure.

:meth:`StreamWatch.complete` says when a trial of a given length is recorded: that long
after the last of the streams delivered its first message (a trial is as long as asked
with every stream, however long the nodes and discovery took to start).

ROS-free; the clock is injectable, so the tests step time by hand.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Dict, Optional, Sequence

#: Declared ranges of the thresholds [s] (the node's parameter ranges).
START_TIMEOUT_RANGE_S = (0.5, 600.0)
STALL_TIMEOUT_RANGE_S = (0.05, 60.0)


@dataclass(frozen=True)
class WatchConfig:
    """Thresholds of a :class:`StreamWatch` [s]; see the module's docstring."""

    start_timeout_s: float = 15.0
    stall_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        for name, (lo, hi) in (("start_timeout_s", START_TIMEOUT_RANGE_S),
                               ("stall_timeout_s", STALL_TIMEOUT_RANGE_S)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)
                    and lo <= value <= hi):
                raise ValueError(f"{name} must lie in [{lo}, {hi}] s, got {value!r}")


@dataclass(frozen=True)
class StreamFault:
    """A stream that failed: it never arrived, or it stopped."""

    stream: str
    never: bool          # no message at all (else: it stopped after ``count`` messages)
    silent_s: float      # how long it had been silent when found [s]
    count: int = 0

    def message(self) -> str:
        """The one line that names the stream and what happened to it."""
        if self.never:
            return (f"{self.stream}: no message in the first {self.silent_s:.1f} s: the "
                    "stream never arrived; the trial failed")
        return (f"{self.stream}: no message for {self.silent_s:.1f} s after {self.count} "
                "messages: the stream stopped mid-trial; the trial failed")


class StreamWatch:
    """Watches named streams from a start instant; :meth:`arrived` from any thread.

    :param streams: the stream names (topics), each watched from ``start``.
    :param config: the thresholds.
    :param clock: monotonic time source [s].
    :param start: the start instant on ``clock`` (default: now).
    """

    def __init__(self, streams: Sequence[str], config: WatchConfig = WatchConfig(),
                 clock: Callable[[], float] = time.monotonic,
                 start: Optional[float] = None) -> None:
        names = list(streams)
        if not names or len(set(names)) != len(names) or not all(names):
            raise ValueError(f"streams must be distinct non-empty names, got {names}")
        self.config = config
        self._clock = clock
        self._start = clock() if start is None else float(start)
        self._lock = threading.Lock()
        self._last: Dict[str, Optional[float]] = {s: None for s in names}
        self._count: Dict[str, int] = {s: 0 for s in names}
        self._all_in: Optional[float] = None     # when the last stream's first message came

    @property
    def streams(self) -> list:
        """The watched stream names, in the given order."""
        return list(self._last)

    def arrived(self, stream: str, now: Optional[float] = None) -> None:
        """A message of ``stream`` arrived at ``now`` (default: the clock's now)."""
        t = self._clock() if now is None else float(now)
        with self._lock:
            if stream not in self._last:
                raise KeyError(f"{stream} is not watched ({', '.join(self._last)})")
            last = self._last[stream]
            if last is None or t > last:
                self._last[stream] = t
            self._count[stream] += 1
            if self._all_in is None and all(x is not None for x in self._last.values()):
                self._all_in = t

    def waiting(self) -> list:
        """The streams that have not delivered a message yet."""
        with self._lock:
            return [s for s, last in self._last.items() if last is None]

    def counts(self) -> dict:
        """Messages seen per stream."""
        with self._lock:
            return dict(self._count)

    def complete(self, duration_s: float, now: Optional[float] = None) -> bool:
        """Whether every stream has been in for ``duration_s`` (since the last of them
        delivered its first message)."""
        t = self._clock() if now is None else float(now)
        with self._lock:
            return self._all_in is not None and t - self._all_in >= duration_s

    def check(self, now: Optional[float] = None) -> Optional[StreamFault]:
        """The failed stream whose threshold passed first, or None while all are well."""
        t = self._clock() if now is None else float(now)
        cfg = self.config
        worst = None        # (when its threshold passed, fault)
        with self._lock:
            for stream, last in self._last.items():
                if last is None:
                    silent, limit = t - self._start, cfg.start_timeout_s
                else:
                    silent, limit = t - last, cfg.stall_timeout_s
                if silent <= limit:
                    continue
                fault = StreamFault(stream, last is None, silent, self._count[stream])
                passed = t - (silent - limit)
                if worst is None or passed < worst[0]:
                    worst = (passed, fault)
        return None if worst is None else worst[1]
