"""slip_inference starved of CPU catches up on the audio that queued meanwhile: in one process.

A busy host stops the node's executor for a while; DDS keeps receiving the best-effort
audio into the subscription's queue (``slip_inference.AUDIO_QOS``, 1 s of 10 ms blocks).
Once the executor runs again the node must take every queued block: no gap, so no window
restart and no estimate-free stretch for the controllers' stale-input watchdog.

Here the node, the audio source and the listener share one process and one executor,
which the test simply does not spin while the blocks are sent: the starved executor, with
nothing left to scheduling. (The former version froze a node process with SIGSTOP: that
also froze its DDS threads, and under load the transport dropped the frozen reader's
samples, which no node can catch up on; it failed in a flake hunt beside two CPU hogs.)
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from node_support import SCENE_NAMES, header_ns, make_checkpoint

pytestmark = pytest.mark.ros

#: Blocks sent while the executor does not run: 0.3 s of audio, 3x the old 10-deep queue.
STARVED_BLOCKS = 30


class Graph:
    """slip_inference and a peer (audio source, estimate listener) on one executor."""

    def __init__(self, context, checkpoint) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter

        from aslip_ros.msg import AudioFrame, SlipVector
        from aslip_ros.nodes import common as c
        from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
        from aslip_ros.nodes.slip_inference import SlipInference
        self.node = SlipInference(context=context, parameter_overrides=[
            Parameter("checkpoint", value=str(checkpoint))])
        self.peer = rclpy.create_node("audio_source", context=context)
        self.estimates: list = []
        self.peer.create_subscription(SlipVector, c.SLIP_TOPIC, self.estimates.append,
                                      RELIABLE_QOS)
        self.pub = self.peer.create_publisher(AudioFrame, c.AUDIO_TOPIC, SENSOR_QOS)
        self.ex = SingleThreadedExecutor(context=context)
        self.ex.add_node(self.node)
        self.ex.add_node(self.peer)
        self.index, self.stamp_ns = 0, 1_000_000_000_000
        self.rng = np.random.default_rng(0)

    def send(self) -> int:
        """Publish the next 10 ms block; returns its end stamp."""
        from aslip_ros.nodes import convert
        block = (0.01 * self.rng.standard_normal((480, len(SCENE_NAMES)))).astype(np.float32)
        self.pub.publish(convert.audio_to_msg(self.index, self.stamp_ns, 48000.0,
                                              SCENE_NAMES, block, "4mic"))
        self.index += 480
        self.stamp_ns += 10_000_000
        return self.stamp_ns

    def until(self, predicate, what: str, timeout: float = 30.0) -> None:
        """Spin until ``predicate()``; the deadline only stops a hang."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                raise AssertionError(f"no {what} within {timeout:g} s; node counts: "
                                     f"gaps {self.node.est.stats.gaps}, accepted "
                                     f"{self.node.est.stats.blocks_ok}")
            self.ex.spin_once(timeout_sec=0.02)

    def estimated(self, end_ns: int) -> bool:
        return any(header_ns(m) == end_ns for m in self.estimates)

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()
        self.peer.destroy_node()


def _starve(context, checkpoint) -> tuple[int, int, bool]:
    """Settle a stream, send STARVED_BLOCKS without spinning, spin again. Returns the gaps
    and accepted blocks the starved stretch added, and whether its last block got an
    estimate."""
    g = Graph(context, checkpoint)
    try:
        g.until(lambda: g.pub.get_subscription_count() > 0, "audio subscription match")
        # A healthy stream first, one block at a time, until the newest one is estimated.
        end = g.send()
        g.until(lambda: len(g.estimates) > 0 or g.send() is None, "a first estimate")
        end = g.send()
        g.until(lambda: g.estimated(end), "an estimate on the newest block")
        gaps0, ok0 = g.node.est.stats.gaps, g.node.est.stats.blocks_ok
        for _ in range(STARVED_BLOCKS):          # the executor is not spun meanwhile
            last = g.send()
        g.until(lambda: g.node.est.stats.blocks_ok - ok0 >= STARVED_BLOCKS or
                g.node.est.stats.gaps > gaps0, "the queued blocks taken")
        got_last = False
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and g.node.est.stats.gaps == gaps0:
            if g.estimated(last):
                got_last = True
                break
            g.ex.spin_once(timeout_sec=0.02)
        return g.node.est.stats.gaps - gaps0, g.node.est.stats.blocks_ok - ok0, got_last
    finally:
        g.close()


@pytest.fixture(scope="module")
def known_checkpoint(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("ckpt") / "known.pt", slip_logit=4.0,
                           velocity=(0.02, -0.01))


def test_a_node_starved_of_cpu_loses_no_audio(rclpy_context, known_checkpoint):
    gaps, accepted, got_last = _starve(rclpy_context, known_checkpoint)
    assert gaps == 0
    assert accepted == STARVED_BLOCKS
    assert got_last                               # the newest window is estimated


def test_a_queue_shorter_than_the_backlog_would_lose_it(rclpy_context, known_checkpoint,
                                                        monkeypatch):
    """What the test above tells apart: with a 10-deep audio queue (the node's before), the
    same starved stretch loses blocks and restarts the window."""
    from rclpy.qos import QoSProfile

    from aslip_ros.nodes import slip_inference
    q = slip_inference.AUDIO_QOS
    monkeypatch.setattr(slip_inference, "AUDIO_QOS", QoSProfile(
        history=q.history, depth=10, reliability=q.reliability, durability=q.durability))
    gaps, accepted, _ = _starve(rclpy_context, known_checkpoint)
    assert gaps == 1 and accepted < STARVED_BLOCKS
