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
"""

from __future__ import annotations

import collections


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
