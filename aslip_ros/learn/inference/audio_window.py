"""Live audio windows (ROS-free, numpy only): a ring buffer and a stream continuity gate.

    gate = StreamGate(max_time_jump_s=0.05)
    verdict, detail = gate.check(block)     # ok, gap, repeated, out_of_order, time_jump,
                                            # new_stream
    ring = RingBuffer(window_samples, channels); ring.push(block.block); ring.window()

``block`` is anything with ``first_sample_index``, ``frames``, ``stamp_ns``,
``end_stamp_ns`` and ``sample_rate`` (``aslip_ros.nodes.convert.AudioData`` in the node).
"""

from __future__ import annotations

from typing import Optional

import numpy as np


class RingBuffer:
    """Fixed-length multi-channel history; ``window()`` returns the newest samples in order."""

    def __init__(self, length: int, channels: int) -> None:
        self._buf = np.zeros((2 * length, channels), dtype=np.float32)
        self.length = int(length)
        self._pos = 0
        self.filled = 0

    def reset(self) -> None:
        """Forget the history (after a gap)."""
        self._pos = 0
        self.filled = 0

    def push(self, block: np.ndarray) -> None:
        """Append ``(frames, channels)`` samples."""
        n = block.shape[0]
        if n >= self.length:
            self._buf[:self.length] = block[-self.length:]
            self._buf[self.length:] = block[-self.length:]
            self._pos = 0
        else:
            # Written twice (at pos and pos + length) so the newest window is always one
            # contiguous slice: no copy-and-concatenate per inference.
            end = self._pos + n
            if end <= self.length:
                self._buf[self._pos:end] = block
                self._buf[self._pos + self.length:end + self.length] = block
            else:
                k = self.length - self._pos
                self._buf[self._pos:self.length] = block[:k]
                self._buf[self._pos + self.length:] = block[:k]
                self._buf[:n - k] = block[k:]
                self._buf[self.length:self.length + n - k] = block[k:]
            self._pos = end % self.length
        self.filled = min(self.length, self.filled + n)

    def window(self) -> np.ndarray:
        """The newest ``length`` samples, oldest first (a view; valid until the next push)."""
        return self._buf[self._pos:self._pos + self.length]


class StreamGate:
    """Continuity checks on a single audio stream (sample index and stamp).

    The stamp says which index a block should carry: ``expected = anchor stamp + index
    offset / rate``. A block whose stamp agrees with its index (within ``max_time_jump_s``)
    belongs to the stream: contiguous (ok), ahead (a gap: blocks lost upstream) or behind
    (repeated / out of order: dropped). A block whose index disagrees with its stamp, away
    from the expected index, is a new stream: a source that restarted its counter at 0, or
    an index that leapt to 2**63. Waiting for the old index to come round again would
    silence the node for as long as the old stream ran, so the gate re-anchors on it. A
    source that restarts both its counter and its clock looks like a run of old blocks; once
    such a run is contiguous for ``restart_after_s`` of audio, it too is a new stream.
    """

    def __init__(self, max_time_jump_s: float, restart_after_s: float = 0.1) -> None:
        self.max_time_jump_ns = int(max_time_jump_s * 1e9)
        self.restart_after_s = float(restart_after_s)
        self.next_index: Optional[int] = None
        self.next_stamp_ns: Optional[int] = None
        self._behind_next: Optional[int] = None     # a contiguous run of blocks behind
        self._behind_frames = 0

    def check(self, a) -> tuple:
        """``(verdict, detail)``; verdict one of ok, gap, repeated, out_of_order, time_jump,
        new_stream."""
        if self.next_index is None:
            return "ok", ""
        offset = a.first_sample_index - self.next_index
        if offset == 0:
            jump = a.stamp_ns - self.next_stamp_ns
            if abs(jump) > self.max_time_jump_ns:
                return "time_jump", f"stamp off by {jump * 1e-9:+.3f} s at a contiguous index"
            return "ok", ""
        expected_ns = self.next_stamp_ns + offset * 1e9 / a.sample_rate
        if abs(a.stamp_ns - expected_ns) > self.max_time_jump_ns:
            return "new_stream", (f"sample index {a.first_sample_index} where "
                                  f"{self.next_index} was expected, with a stamp that does "
                                  f"not fit it ({(a.stamp_ns - expected_ns) * 1e-9:+.3f} s)")
        if offset > 0:
            return "gap", f"{offset} frames missing"
        if self._behind_next == a.first_sample_index:
            self._behind_frames += a.frames
        else:
            self._behind_frames = a.frames
        self._behind_next = a.first_sample_index + a.frames
        if self._behind_frames >= self.restart_after_s * a.sample_rate:
            return "new_stream", (f"{self._behind_frames} contiguous frames behind the "
                                  f"expected sample index {self.next_index}")
        kind = "repeated" if offset == -a.frames else "out_of_order"
        return kind, f"sample index {a.first_sample_index} < expected {self.next_index}"

    def accept(self, a) -> None:
        """Take ``a`` as the newest block (also re-anchors after a time jump or restart)."""
        self.next_index = a.first_sample_index + a.frames
        self.next_stamp_ns = a.end_stamp_ns
        self._behind_next, self._behind_frames = None, 0
