"""How much later than usual a stream's blocks reach a consumer (ROS-free, floor 0).

A live node that cannot keep up sees its input arrive later and later against the
stream's own stamps. The usual delay is the smallest ``arrival - stamp`` of the last
``window_s`` (a sliding minimum, so a slow drift between the source's clock and this host's,
or a constant offset, is followed); the lag of a block is how much later than that it came.

Only a stream stamped on this host's clock (or one synchronised with it, within
``plausible_s``) can be judged: a replay with its recording's stamps, a test's made-up
stamps or simulated time are no measure of this host's delay, and get a lag of 0. A lag
beyond ``reset_s`` is no backlog either (the input queue holds far less): the source's clock
jumped, and the measure starts again from that block.

A smaller step of the source's clock (every block from some moment on arrives, at the
stream's own pace, a fixed time later than before) would read as a lag for ``window_s``:
:meth:`LagMeter.behind` tells it from a backlog by how long the lag lasts. A consumer that
skips the blocks of a backlog works it off in far less than ``STEP_AFTER_S`` of its own
clock (skipping costs next to nothing); a lag over the limit for longer is the source's
clock having stepped, and the usual delay starts again from that block. ``scene_sim`` in
real time makes such steps: when it falls more than its catch-up behind, it skips scene
time, and its stamps, scene time from its start, stay that much behind this host's clock.
"""

from __future__ import annotations

import collections


#: A lag over the consumer's limit for this long on its own clock [s] is a step of the
#: source's clock, not a backlog (module docstring).
STEP_AFTER_S = 0.25


class LagMeter:
    """Sliding-minimum delay of a stream and each block's lag behind it [s]."""

    def __init__(self, window_s: float = 10.0, reset_s: float = 2.0,
                 plausible_s: float = 5.0) -> None:
        if not (window_s > 0.0 and reset_s > 0.0 and plausible_s > 0.0):
            raise ValueError("window_s, reset_s and plausible_s must be > 0, got "
                             f"{window_s}, {reset_s}, {plausible_s}")
        self.window_s = float(window_s)
        self.reset_s = float(reset_s)
        self.plausible_s = float(plausible_s)
        self._hist: collections.deque = collections.deque()   # (arrival, offset), offsets rising
        self.resets = 0
        #: Steps of the source's clock taken up by :meth:`behind`.
        self.steps = 0
        self._late_since: float | None = None    # arrival of the first block over the limit

    def lag(self, arrival_s: float, stamp_s: float) -> float:
        """The lag of a block that arrived at ``arrival_s`` (this host's wall clock) with
        stamp ``stamp_s`` [s]; 0 for a stream not stamped on this host's clock."""
        offset = arrival_s - stamp_s
        if abs(offset) > self.plausible_s:
            self._hist.clear()
            return 0.0
        if self._hist and offset - self._hist[0][1] > self.reset_s:
            self._hist.clear()
            self.resets += 1
        while self._hist and self._hist[-1][1] >= offset:
            self._hist.pop()
        self._hist.append((arrival_s, offset))
        while self._hist[0][0] < arrival_s - self.window_s:
            self._hist.popleft()
        return offset - self._hist[0][1]

    def reset(self) -> None:
        """Forget the usual delay (a new source)."""
        self._hist.clear()
        self._late_since = None

    def behind(self, arrival_s: float, stamp_s: float, limit_s: float,
               step_after_s: float = STEP_AFTER_S) -> tuple[float, bool]:
        """``(lag, skip)`` of a block: ``skip`` when its lag is over ``limit_s`` (> 0; 0 =
        never), for at most ``step_after_s`` of the arrival clock in a row. Longer, the
        source's clock stepped: the usual delay starts again from this block (counted in
        ``steps``), which is then on time."""
        lag = self.lag(arrival_s, stamp_s)
        if not (limit_s > 0.0 and lag > limit_s):
            self._late_since = None
            return lag, False
        if self._late_since is None:
            self._late_since = arrival_s
        elif arrival_s - self._late_since > step_after_s:
            self.steps += 1
            self.reset()
            return self.lag(arrival_s, stamp_s), False
        return lag, True
