"""mocap_bridge on mocap4r2's RigidBodies, in one process: the bridge and a stand-in of the
OptiTrack driver (one message of every body, reliable depth 1000, published only while
someone subscribes, frame ``map``, stamped receive time minus latency, bodies named by
their Motive ID as text) on one executor."""

from __future__ import annotations

import time

import numpy as np
import pytest

from node_support import driver_msgs

pytestmark = pytest.mark.ros

TRUTH = "/aslip/slip_truth"
RATE_HZ = 120.0
LATENCY_NS = 4_000_000       # NatNet's latency, taken off the receive time


def _sliding(t):
    """Finger yawed 90 deg and moving; the object slides 0.02 m/s along the fingers (+x of
    the grasp plane) and 0.01 m/s down (-z) relative to it."""
    from scipy.spatial.transform import Rotation
    q = Rotation.from_euler("z", 90, degrees=True)
    p_f = np.array([0.4 + 0.05 * t, 0.0, 0.3])
    p_o = p_f + q.apply([0.02 * t, 0.0, -0.01 * t])
    quat = q.as_quat()
    return np.concatenate([p_f, quat]), np.concatenate([p_o, quat])


class OptiTrack:
    """Publishes like mocap4r2's OptiTrack driver: ``rigid_bodies`` at QoS depth 1000
    (rclpy's default profile: reliable, volatile), only while it has a subscriber; every
    body of the frame in one message; ``names`` say which bodies a frame holds."""

    def __init__(self, context, motion, names=lambda k: ("1", "3", "5")) -> None:
        import rclpy
        from rclpy.qos import QoSProfile
        msgs = driver_msgs("mocap4r2_msgs")
        self.msgs = msgs
        self.node = rclpy.create_node("optitrack_stand_in", context=context)
        self.pub = self.node.create_publisher(msgs.RigidBodies, "rigid_bodies",
                                              QoSProfile(depth=1000))
        self.motion, self.names = motion, names
        self.k = 0
        self.start = None
        self.t0_ns = None

    def step(self) -> None:
        """Publish every frame due by now (at RATE_HZ from the first call)."""
        if self.pub.get_subscription_count() == 0:
            return                                   # the driver sends nothing then
        now = time.monotonic()
        if self.start is None:
            self.start, self.t0_ns = now, time.time_ns() - LATENCY_NS
        while self.k <= (now - self.start) * RATE_HZ:
            self.pub.publish(self.frame(self.k))
            self.k += 1

    def frame(self, k: int):
        m = self.msgs
        t = k / RATE_HZ
        finger, obj = self.motion(t)
        pose_of = {"3": finger, "5": obj, "1": np.array([1.0, 2.0, 0.0, 0, 0, 0, 1.0])}
        msg = m.RigidBodies()
        msg.header.frame_id = "map"
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(self.t0_ns + int(t * 1e9),
                                                                10**9)
        msg.frame_number = k
        for name in self.names(k):
            body = m.RigidBody(rigid_body_name=name)
            p = pose_of[name]
            pos, q = body.pose.position, body.pose.orientation
            pos.x, pos.y, pos.z = (float(v) for v in p[:3])
            q.x, q.y, q.z, q.w = (float(v) for v in p[3:])
            msg.rigidbodies.append(body)
        return msg


class Loop:
    """The bridge, the driver stand-in and a listener of the truth on one executor."""

    def __init__(self, context, params: dict, driver: OptiTrack) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter

        from aslip_ros.msg import SlipVector
        from aslip_ros.runtime.qos import RELIABLE_QOS
        from aslip_ros.nodes.mocap_bridge import MocapBridge
        self.bridge = MocapBridge(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.driver = driver
        self.listener = rclpy.create_node("truth_listener", context=context)
        self.truth = []
        self.listener.create_subscription(SlipVector, TRUTH, self.truth.append,
                                          RELIABLE_QOS)
        self.ex = SingleThreadedExecutor(context=context)
        for n in (self.bridge, driver.node, self.listener):
            self.ex.add_node(n)

    def until(self, predicate, what: str, timeout: float = 30.0):
        """Spin (publishing what is due) until ``predicate()``; the deadline stops a hang."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return
            self.driver.step()
            self.ex.spin_once(timeout_sec=0.002)
        raise AssertionError(f"no {what} within {timeout:g} s")

    def close(self) -> None:
        self.ex.shutdown()
        for n in (self.bridge, self.driver.node, self.listener):
            n.destroy_node()


PARAMS = {"pose_source": "rigid_bodies", "finger_body": "3", "object_body": "5",
          "window_s": 0.1}


def test_the_bodies_chosen_by_id_give_their_slip(rclpy_context):
    """Bodies 3 and 5 out of three per message (a third, 1, stands still): the truth is the
    slip of 5 relative to 3, stamped by the messages' own stamps."""
    loop = Loop(rclpy_context, PARAMS, OptiTrack(rclpy_context, _sliding))
    try:
        loop.until(lambda: len(loop.truth) >= 20, "slip truth")
        assert loop.bridge.state == "running"
        assert loop.bridge.body_tally.missing == {}
        for m in loop.truth[3:]:
            assert m.slipping and m.source == "mocap_truth"
            assert (m.velocity.x, m.velocity.y, m.velocity.z) == pytest.approx(
                (0.02, 0.0, -0.01), abs=1e-6)
        stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in loop.truth]
        assert np.all(np.diff(stamps) > 0) and stamps[0] >= loop.driver.t0_ns
        assert (stamps[-1] - loop.driver.t0_ns) * RATE_HZ / 1e9 == pytest.approx(
            round((stamps[-1] - loop.driver.t0_ns) * RATE_HZ / 1e9), abs=1e-3)
    finally:
        loop.close()


def test_a_missing_body_is_named_with_the_bodies_present(rclpy_context):
    """The object's body (5) is not tracked for the first 30 frames: no truth, no crash, and
    the warning and diagnostics name it with the bodies that are there; then it appears."""
    def names(k):
        return ("1", "3") if k < 30 else ("3", "1", "5")

    loop = Loop(rclpy_context, PARAMS, OptiTrack(rclpy_context, _sliding, names))
    try:
        loop.until(lambda: loop.bridge.body_tally.messages >= 10, "RigidBodies")
        assert loop.truth == [] and loop.bridge.state == "waiting for poses"
        assert loop.bridge.body_problem == (
            "rigid body '5' (object) is not in the RigidBodies on /rigid_bodies; bodies "
            "present: '1', '3'")
        tally = loop.bridge.body_tally.text()
        assert "rigid body '5' (object) is in none of the" in tally
        assert tally.endswith("bodies present: '1', '3'")
        loop.until(lambda: len(loop.truth) >= 5, "slip truth once the body is tracked")
        assert loop.bridge.body_problem == ""
        assert 0 < loop.bridge.body_tally.missing["object"] <= 30     # the first may be lost
        assert "(object) is missing from" in loop.bridge.body_tally.text()
    finally:
        loop.close()


@pytest.mark.parametrize("params, why", [
    ({"pose_source": "rigid_bodies", "finger_body": "3"}, "needs finger_body and object_body"),
    ({"pose_source": "rigid_bodies", "finger_body": "3", "object_body": "03"},
     "the same body"),
    ({"finger_body": "3"}, "only apply to pose_source rigid_bodies"),
    ({"pose_source": "mocap4r2"}, "pose_source"),
])
def test_an_incomplete_body_choice_is_refused(rclpy_context, params, why):
    from rclpy.parameter import Parameter

    from aslip_ros.runtime.process import ConfigError
    from aslip_ros.nodes.mocap_bridge import MocapBridge
    with pytest.raises(ConfigError, match=why):
        MocapBridge(context=rclpy_context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])


def test_the_recorder_records_the_rigid_bodies_from_the_start(rclpy_context, tmp_path):
    """bag_recorder with ``rigid_bodies_topics``: subscribed before the driver exists (the
    driver sends only to a subscriber), recorded with mocap4r2's installed definition, and
    the bag's messages decode to the bodies the driver sent."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from aslip_ros.data.bags import BagReader
    from aslip_ros.nodes.bag_recorder import Recorder
    from aslip_ros.rigid_bodies import RIGID_BODIES_TYPE, select_bodies
    # Without mocap4r2_msgs built there is no definition to record: skipped as the driver's
    # tests are (failed under ASLIP_REQUIRE_DRIVER_MSGS=1, as in CI), not failed below.
    driver_msgs("mocap4r2_msgs")
    bag = tmp_path / "bag"
    rec = Recorder(context=rclpy_context, parameter_overrides=[
        Parameter("output", value=str(bag)), Parameter("topics", value=["/rigid_bodies"]),
        Parameter("rigid_bodies_topics", value=["/rigid_bodies"])])
    assert rec.counts == {"/rigid_bodies": 0}          # no publisher yet, subscribed
    driver = OptiTrack(rclpy_context, _sliding)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(rec)
    ex.add_node(driver.node)
    try:
        deadline = time.monotonic() + 30.0
        while rec.counts["/rigid_bodies"] < 30:
            assert time.monotonic() < deadline, rec.counts
            driver.step()
            ex.spin_once(timeout_sec=0.002)
        rec.before_shutdown()
    finally:
        ex.shutdown()
        rec.destroy_node()
        driver.node.destroy_node()
    with BagReader(bag) as r:
        assert r.info.topics == {"/rigid_bodies": RIGID_BODIES_TYPE}
        got = [select_bodies(m.msg, {"finger": "3", "object": "5"}) for m in r.messages()]
    assert len(got) >= 30 and all(g.frame_id == "map" and not g.missing for g in got)
    assert all(g.present == ("1", "3", "5") for g in got)
    assert np.all(np.diff([g.stamp_ns for g in got]) > 0)
    t = (got[-1].stamp_ns - driver.t0_ns) * 1e-9
    np.testing.assert_allclose(got[-1].poses["object"], _sliding(t)[1], atol=1e-9)
