"""scene_sim's ``start_with_subscriber``: a finite simulated recording loses no scene
second to a recorder that starts late (a fresh clone's CI once recorded 0 audio blocks of a
3 s scene beside two CPU hogs: the scene had run before the recorder subscribed)."""

from __future__ import annotations

import time

import pytest
from rclpy.parameter import Parameter

pytestmark = pytest.mark.ros


def _wait(cond, timeout_s: float = 30.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return False


@pytest.mark.parametrize("hold", [True, False])
def test_the_scene_waits_for_its_recorder_only_when_asked(rclpy_context, hold):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from aslip_ros.msg import AudioFrame
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import SENSOR_QOS
    from aslip_ros.nodes.scene_sim import SceneSim

    sim = SceneSim(context=rclpy_context, parameter_overrides=[
        Parameter("start_with_subscriber", value=hold)])
    rec = Node("late_recorder", context=rclpy_context)
    got = []
    try:
        # No subscriber yet: the scene's timer fires (by hand here) for a while.
        t_end = time.monotonic() + 0.3
        while time.monotonic() < t_end:
            sim._tick()
        if not hold:
            assert sim.world.t > 0.0          # without the hold the scene runs unheard
            return
        assert sim.world.t == 0.0
        rec.create_subscription(AudioFrame, c.AUDIO_TOPIC, got.append, SENSOR_QOS)
        ex = SingleThreadedExecutor(context=rclpy_context)
        ex.add_node(rec)
        assert _wait(lambda: sim.pub_audio.get_subscription_count() > 0)

        def first_block_heard():
            sim._tick()
            ex.spin_once(timeout_sec=0.005)
            return bool(got)
        assert _wait(first_block_heard)
        # The recorder hears the scene from its start (best effort may drop a block).
        assert got[0].first_sample_index < 4800, got[0].first_sample_index
        ex.shutdown()
    finally:
        rec.destroy_node()
        sim.destroy_node()
