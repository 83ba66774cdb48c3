"""StreamGate and RingBuffer (ROS-free): continuity verdicts, restarts, window order."""

from dataclasses import dataclass

import numpy as np
import pytest

from aslip_ros.learn.inference.audio_window import RingBuffer, StreamGate

RATE = 48000.0
N = 480                       # 10 ms blocks
T0 = 1_000_000_000_000


@dataclass
class Block:
    first_sample_index: int
    stamp_ns: int
    frames: int = N
    sample_rate: float = RATE

    @property
    def end_stamp_ns(self) -> int:
        return self.stamp_ns + int(round(self.frames * 1e9 / self.sample_rate))


def _stream(gate, n, index=0, stamp=T0):
    for k in range(n):
        b = Block(index + k * N, stamp + k * 10_000_000)
        assert gate.check(b)[0] == "ok"
        gate.accept(b)
    return index + n * N, stamp + n * 10_000_000


def test_contiguous_gap_and_old_blocks():
    g = StreamGate(0.05)
    i, t = _stream(g, 10)
    assert g.check(Block(i - N, t - 10_000_000))[0] == "repeated"
    assert g.check(Block(i - 10 * N, t - 100_000_000))[0] == "out_of_order"
    verdict, detail = g.check(Block(i + 4800, t + 100_000_000))
    assert verdict == "gap" and "4800 frames" in detail
    assert g.check(Block(i, t + 5 * 10**9))[0] == "time_jump"
    assert g.check(Block(i, t + 20_000_000))[0] == "ok"      # stamp jitter within 50 ms


@pytest.mark.parametrize("index", [0, 2**63, 2**63 + 12345])
def test_an_index_that_disagrees_with_its_stamp_is_a_new_stream(index):
    """A source restarting at 0 after 10 minutes, or a block numbered 2**63: re-anchor now
    rather than wait for the old index to come round (or count 9e18 frames lost)."""
    g = StreamGate(0.05)
    i, t = _stream(g, 5, index=600 * 48000, stamp=T0 + 600 * 10**9)
    verdict, _ = g.check(Block(index, t))
    assert verdict == "new_stream"
    g.accept(Block(index, t))
    i2, t2 = _stream(g, 5, index=index + N, stamp=t + 10_000_000)
    assert g.next_index == i2


def test_a_source_restarting_counter_and_clock_is_taken_after_a_short_run():
    """Index and stamp both back at their start: consistent with the old stream, so the
    first blocks read as out of order; 0.1 s of them in a row is a new stream."""
    g = StreamGate(0.05, restart_after_s=0.1)
    _stream(g, 200)
    verdicts = []
    for k in range(12):
        b = Block(k * N, T0 + k * 10_000_000)
        verdicts.append(g.check(b)[0])
        if verdicts[-1] == "new_stream":
            g.accept(b)
            break
    assert verdicts[:9] == ["out_of_order"] * 9 and verdicts[-1] == "new_stream"
    assert len(verdicts) == 10                       # 10 blocks = 0.1 s


def test_scattered_old_blocks_never_make_a_new_stream():
    g = StreamGate(0.05, restart_after_s=0.1)
    i, t = _stream(g, 200)
    for k in range(50):                              # late blocks, never contiguous
        back = (k % 7 + 2) * N
        assert g.check(Block(i - back, t - back * 10_000_000 // N))[0] == "out_of_order"


def test_ring_buffer_window_is_the_newest_samples_in_order():
    ring = RingBuffer(5, 2)
    data = np.arange(26, dtype=np.float32).reshape(13, 2)
    for a, b in ((0, 3), (3, 4), (4, 11), (11, 13)):
        ring.push(data[a:b])
    np.testing.assert_array_equal(ring.window(), data[8:13])
    assert ring.filled == 5
    ring.reset()
    assert ring.filled == 0
