"""slip_inference on a machine that cannot keep up (issue #39): it degrades, it does not
stall. Blocks that reach a streaming node far later than the stream's usual delay are
skipped and counted, estimates resume on the first block on time, and every estimate keeps
the stamp of the audio it was computed from. A window model's waiting window is replaced by
the newest one (counted), never estimated under a newer stamp.

One process: the node is built in the test's context and its audio callback is fed
directly, with the arrival clock in the test's hands, so "behind" is a fact of the input,
not of the machine running the test.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from node_support import SCENE_NAMES, header_ns

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
STREAM = ROOT / "models" / "aslip_stream.pt"
CNN = ROOT / "models" / "aslip_cnn.pt"
BLOCK_NS = 10_000_000


class _Clock:
    """The node's arrival clock [s], moved by the test."""

    def __init__(self) -> None:
        self.t = 5.003          # the stream's stamps are on this clock: 3 ms on the way

    def __call__(self) -> float:
        return self.t


def _node(rclpy_context, checkpoint: Path, **params):
    from rclpy.parameter import Parameter

    from aslip_ros.nodes.slip_inference import SlipInference
    over = [Parameter(k, value=v) for k, v in dict(checkpoint=str(checkpoint), **params).items()]
    node = SlipInference(context=rclpy_context, parameter_overrides=over)
    sent = []
    lock = threading.Lock()

    def publish(msg, _pub=node.pub_slip.publish):
        with lock:
            sent.append(header_ns(msg))
        _pub(msg)
    node.pub_slip.publish = publish
    return node, sent, lock


def _clocked_node(rclpy_context):
    """A streaming node whose arrival clock is the test's: (node, sent, lock, clock)."""
    node, sent, lock = _node(rclpy_context, STREAM)
    clock = _Clock()
    node._arrival_s = clock
    return node, sent, lock, clock


def _blocks(n: int, start_index: int = 0, start_ns: int = 5_000_000_000, seed: int = 0):
    from aslip_ros.nodes import convert
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        block = (0.01 * rng.standard_normal((480, len(SCENE_NAMES)))).astype(np.float32)
        out.append(convert.audio_to_msg(start_index + 480 * k, start_ns + BLOCK_NS * k,
                                        48000.0, SCENE_NAMES, block, "4mic"))
    return out


def _end_ns(msg) -> int:
    return header_ns(msg) + BLOCK_NS


def test_a_streaming_node_behind_the_stream_skips_blocks_and_keeps_its_stamps(rclpy_context):
    node, sent, lock, clock = _clocked_node(rclpy_context)
    try:
        msgs = _blocks(120)
        for m in msgs[:40]:                  # on time: one block per 10 ms
            clock.t += 0.01
            node._on_audio(m)
        with lock:
            on_time = len(sent)
        assert on_time > 0 and node.skipped_behind == 0
        clock.t += 0.3                       # the node stalled 300 ms: a backlog of 30
        for m in msgs[40:70]:                # blocks is taken at once
            node._on_audio(m)
        assert node.skipped_behind > 0       # the late ones were skipped ...
        assert node.est.report()["drops"].get("behind", 0) == node.skipped_behind
        for m in msgs[70:]:                  # ... and on time again, estimates resume
            clock.t += 0.01
            node._on_audio(m)
        with lock:
            stamps = list(sent)
        ends = {_end_ns(m) for m in msgs}
        # Every estimate is stamped inside the audio it came from (a streaming model
        # stamps each 10 ms hop with its last sample): none from a skipped block, none
        # twice, and estimates resume once the node is on time again.
        skipped = [m for m in msgs[40:70]][:node.skipped_behind]
        assert all(not (header_ns(m) < st <= _end_ns(m)) for m in skipped for st in stamps)
        assert all(header_ns(msgs[0]) < st <= max(ends) for st in stamps)
        assert len(set(stamps)) == len(stamps)
        assert any(st > _end_ns(msgs[70]) for st in stamps), "no estimate after catching up"
        assert header_ns(msgs[-1]) < max(stamps) <= _end_ns(msgs[-1])   # the newest block
        values = _diag(node)
        assert values["hops_skipped_behind"] == node.skipped_behind
    finally:
        node.destroy_node()


def test_a_source_whose_stamps_fall_behind_once_is_skipped_only_for_a_moment(rclpy_context):
    # scene_sim in real time, more than its catch-up behind, skips scene time: every later
    # block arrives at the stream's pace, 300 ms later than its stamp says. The node skips
    # them for STEP_AFTER_S, then estimates again (before: for the meter's 10 s window).
    from aslip_ros.lag import STEP_AFTER_S
    node, sent, lock, clock = _clocked_node(rclpy_context)
    try:
        msgs = _blocks(150)
        for k, m in enumerate(msgs):
            clock.t += 0.01 + (0.3 if k == 40 else 0.0)
            node._on_audio(m)
        assert 0 < node.skipped_behind <= STEP_AFTER_S / 0.01 + 1
        with lock:
            stamps = list(sent)
        assert sum(st > _end_ns(msgs[80]) for st in stamps) >= 60   # estimates again
        assert _diag(node)["lag_clock_steps"] == 1
    finally:
        node.destroy_node()


def test_a_node_on_time_skips_nothing(rclpy_context):
    node, sent, _, clock = _clocked_node(rclpy_context)
    try:
        rng = np.random.default_rng(1)
        t0 = clock.t
        for k, m in enumerate(_blocks(100)):
            clock.t = t0 + 0.01 * k + 0.04 * rng.random()   # jitter within max_lag_s
            node._on_audio(m)
        assert node.skipped_behind == 0 and len(sent) > 50
    finally:
        node.destroy_node()


def test_a_slow_window_model_supersedes_hops_and_keeps_their_stamps(rclpy_context):
    node, sent, lock = _node(rclpy_context, CNN)
    gate = threading.Event()
    run = node.est.run

    def slow_run(job):                       # the model thread waits until the test says
        gate.wait(10.0)
        return run(job)
    node.est.run = slow_run
    try:
        msgs = _blocks(60)
        for m in msgs:
            node._on_audio(m)
        # The model thread holds a window: not idle, however long one waits for it.
        assert not node.idle() and not node.wait_idle(0.05)
        gate.set()
        assert node.wait_idle(10.0) and node.idle()
        assert node.est.report()["values"]["hops_superseded"] > 0
        with lock:
            stamps = list(sent)
        ends = [_end_ns(m) for m in msgs]
        assert stamps and set(stamps) <= set(ends)    # each at the end of its own window
        assert stamps[-1] == ends[-1]                 # the newest window ran last
    finally:
        gate.set()              # a failed check must not leave the model thread held
        node.destroy_node()


def _wait(cond, timeout: float = 10.0) -> bool:
    """Poll ``cond`` until true (the model thread's own pace), at most ``timeout`` s."""
    import time
    pause = threading.Event()
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        pause.wait(0.01)
    return False


def _diag(node) -> dict:
    got = {}
    orig = node.diag.publish

    def keep(level, message, values):
        got.update(values)
        orig(level, message, values)
    node.diag.publish = keep
    node._diagnose()
    return got
