"""mocap_bridge as a separate process: known motion -> known slip; stale poses -> silence."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from node_support import Bus, NodeProcess

pytestmark = pytest.mark.ros

TRUTH = "/aslip/slip_truth"


class PoseStreamer:
    """Publishes finger and object poses at 120 Hz from a motion function of time."""

    def __init__(self, bus, motion, rate_hz: float = 120.0) -> None:
        from geometry_msgs.msg import PoseStamped

        from aslip_ros.nodes import common as c
        from aslip_ros.runtime.qos import SENSOR_QOS
        self.motion = motion
        self.pub_f = bus.node.create_publisher(PoseStamped, c.FINGER_TOPIC, SENSOR_QOS)
        self.pub_o = bus.node.create_publisher(PoseStamped, c.OBJECT_TOPIC, SENSOR_QOS)
        self.period = 1.0 / rate_hz
        self.running = threading.Event()
        self.running.set()
        self.alive = True
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.t0_ns = time.time_ns()
        self.thread.start()

    def _run(self) -> None:
        from aslip_ros.nodes import convert
        k = 0
        start = time.monotonic()
        while self.alive:
            if self.running.is_set():
                t = k * self.period
                finger, obj = self.motion(t)
                stamp = self.t0_ns + int(t * 1e9)
                self.pub_f.publish(convert.pose_to_msg(finger, stamp, "world"))
                self.pub_o.publish(convert.pose_to_msg(obj, stamp, "world"))
            k += 1
            delay = start + k * self.period - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def close(self) -> None:
        """Stop the thread before the publishers go."""
        self.alive = False
        self.thread.join(2)


@pytest.fixture
def pose_streamer(rclpy_context):
    """Makes PoseStreamers and stops their threads before the test's context shuts down,
    also when a check failed (a thread left publishing raises into a later test)."""
    made = []

    def make(bus, motion, rate_hz: float = 120.0) -> PoseStreamer:
        made.append(PoseStreamer(bus, motion, rate_hz))
        return made[-1]
    yield make
    for streamer in made:
        streamer.close()


def _yawed_grasp(t):
    """Finger yawed 90 deg about z, moving; object slides 0.02 m/s along the fingers
    (grasp-plane +x) and 0.01 m/s down (-z) relative to it."""
    from scipy.spatial.transform import Rotation
    q = Rotation.from_euler("z", 90, degrees=True)
    p_f = np.array([0.4 + 0.05 * t, 0.0, 0.3])                   # the arm moves too
    rel = np.array([0.02 * t, 0.0, -0.01 * t])
    p_o = p_f + q.apply(rel)
    quat = q.as_quat()
    return np.concatenate([p_f, quat]), np.concatenate([p_o, quat])


def test_known_motion_gives_known_slip_then_stale_gives_silence(rclpy_context, ros_env,
                                                                pose_streamer):
    from std_msgs.msg import String

    from aslip_ros.msg import SlipVector
    from aslip_ros.runtime.qos import RELIABLE_QOS
    bus = Bus(rclpy_context)
    bus.listen(SlipVector, TRUTH, RELIABLE_QOS)
    bus.listen(String, "/aslip/diagnostics", RELIABLE_QOS)
    with NodeProcess("mocap_bridge", ros_env, {"window_s": 0.1}) as node:
        node.wait_ready()
        streamer = pose_streamer(bus, _yawed_grasp)
        assert bus.wait(lambda: len(bus.messages(TRUTH)) >= 30, 20), node.output
        got = bus.messages(TRUTH)[5:]
        for m in got:
            assert m.slipping and m.source == "mocap_truth"
            assert (m.velocity.x, m.velocity.y, m.velocity.z) == pytest.approx(
                (0.02, 0.0, -0.01), abs=1e-6)
            assert m.window_length == pytest.approx(0.1)
        # Stamps are the window ends: the newest motion-capture instants.
        stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in got])
        assert np.all(np.diff(stamps) > 0)
        assert stamps[0] >= streamer.t0_ns

        streamer.running.clear()                 # motion capture goes silent
        # The bridge's stale verdict first: windows it made before the silence may still be
        # on their way to this process's executor, and must not count as made after it.
        assert bus.wait(lambda: any(d["message"] == "stale" and d["level"] == 3
                                    for d in bus.diagnostics("mocap_bridge")), 10)
        assert node.wait_for("motion capture stale", 10), node.output
        bus.clear(TRUTH)
        time.sleep(0.5)                          # an absence: nothing in half a second
        assert bus.messages(TRUTH) == []
    streamer.close()
    bus.close()


def _turning(t):
    """Finger yawed 90 deg about z; the object turns at 1.5 rad/s about the pad normal
    (grasp-plane +y) through the pad centre, its own origin 3 cm off it."""
    from scipy.spatial.transform import Rotation
    q = Rotation.from_euler("z", 90, degrees=True)
    turn = Rotation.from_rotvec([0.0, 1.5 * t, 0.0])
    p_f = np.array([0.4, 0.0, 0.3])
    p_o = p_f + q.apply(turn.apply([0.03, 0.0, 0.0]))
    return np.concatenate([p_f, q.as_quat()]), np.concatenate([p_o, (q * turn).as_quat()])


def test_turning_object_publishes_its_angular_velocity(rclpy_context, ros_env, pose_streamer):
    """A pure rotation: the truth carries angular_velocity (rad/s about +y of the grasp
    plane) while the planar decision says not slipping."""
    from aslip_ros.msg import SlipVector
    from aslip_ros.runtime.qos import RELIABLE_QOS
    bus = Bus(rclpy_context)
    bus.listen(SlipVector, TRUTH, RELIABLE_QOS)
    with NodeProcess("mocap_bridge", ros_env, {"window_s": 0.1}) as node:
        node.wait_ready()
        streamer = pose_streamer(bus, _turning)
        assert bus.wait(lambda: len(bus.messages(TRUTH)) >= 15, 20), node.output
    streamer.close()
    bus.close()
    for m in bus.messages(TRUTH)[5:]:
        assert m.angular_velocity == pytest.approx(1.5, abs=1e-5)
        assert m.angular_velocity_sigma == -1.0
        assert not m.slipping and m.speed == 0.0


def test_still_object_is_not_slipping_and_bad_params_refused(rclpy_context, ros_env,
                                                             pose_streamer):
    from aslip_ros.msg import SlipVector
    from aslip_ros.runtime.qos import RELIABLE_QOS
    bus = Bus(rclpy_context)
    bus.listen(SlipVector, TRUTH, RELIABLE_QOS)

    def still(t):
        f = np.array([0.4, 0.1 * t, 0.3, 0, 0, 0, 1.0])
        return f, f + np.array([0, 0, 0.001, 0, 0, 0, 0])

    with NodeProcess("mocap_bridge", ros_env) as node:
        node.wait_ready()
        streamer = pose_streamer(bus, still)
        assert bus.wait(lambda: len(bus.messages(TRUTH)) >= 10, 20), node.output
        m = bus.messages(TRUTH)[-1]
        assert not m.slipping and m.speed == 0.0 and m.probability == 0.0
        res = bus.set_params("mocap_bridge", {"window_s": -1.0})
        assert not res[0].successful and "window_s" in res[0].reason
    streamer.close()
    bus.close()
    proc = NodeProcess("mocap_bridge", ros_env, {"grasp_plane_in_finger": [0.0] * 7})
    assert proc.proc.wait(30) == 2
    assert "zero quaternion" in proc.stop()


HELD_AT = np.array([0.01, -0.02, 0.05])      # object origin in the finger frame [m]


class HeldThenSliding:
    """Finger still (yawed and rolled) holding the object at HELD_AT; from ``slide_from``
    (motion time [s], set by the test once the bridge has calibrated, so that a bridge
    slow to discover the poses still measures the held object) the arm moves and the
    object slides 0.02 m/s along the finger's x axis."""

    def __init__(self) -> None:
        self.slide_from = float("inf")

    def __call__(self, t):
        return _held_then_sliding(t, self.slide_from)


def _held_then_sliding(t, slide_from):
    from scipy.spatial.transform import Rotation
    q = Rotation.from_euler("zx", [90, 30], degrees=True)
    moving = max(0.0, t - slide_from)
    p_f = np.array([0.4 + 0.05 * moving, 0.1, 0.3])
    p_o = p_f + q.apply(HELD_AT + [0.02 * moving, 0.0, 0.0])
    return np.concatenate([p_f, q.as_quat()]), np.concatenate([p_o, [0, 0, 0, 1.0]])


def test_measured_calibration_is_the_held_objects_offset(rclpy_context, ros_env, pose_streamer):
    """calibration=measure: silent while calibrating, then the object's position in the
    finger frame with the parameter's orientation, which orients the published slip."""
    from scipy.spatial.transform import Rotation
    from std_msgs.msg import String

    from aslip_ros.msg import SlipVector
    from aslip_ros.runtime.qos import RELIABLE_QOS
    q_param = Rotation.from_euler("y", 90, degrees=True)
    param = [0.5, 0.5, 0.5] + list(q_param.as_quat())        # position: not used
    bus = Bus(rclpy_context)
    bus.listen(SlipVector, TRUTH, RELIABLE_QOS)
    bus.listen(String, "/aslip/diagnostics", RELIABLE_QOS)
    params = {"calibration": "measure", "calibration_s": 0.4, "window_s": 0.1,
              "grasp_plane_in_finger": param}
    with NodeProcess("mocap_bridge", ros_env, params) as node:
        node.wait_ready()
        motion = HeldThenSliding()
        streamer = pose_streamer(bus, motion)

        def motion_s(m):
            return (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                    - streamer.t0_ns) * 1e-9
        assert node.wait_for("grasp-plane calibration measured", 30), node.output
        motion.slide_from = (time.time_ns() - streamer.t0_ns) * 1e-9 + 0.2
        slide_s = motion.slide_from + 0.1 + 0.02     # windows ending later lie in the slide
        assert bus.wait(lambda: sum(motion_s(m) > slide_s for m in bus.messages(TRUTH)) >= 10,
                        30), node.output
        assert bus.wait(lambda: any("grasp_plane_in_finger" in d["values"] for d in
                                    bus.diagnostics("mocap_bridge")), 10)
    streamer.close()
    bus.close()
    got = bus.messages(TRUTH)
    # Nothing before the calibration time has passed (param mode starts after window_s).
    assert motion_s(got[0]) >= 0.35
    calib = [json.loads(d["values"]["grasp_plane_in_finger"])
             for d in bus.diagnostics("mocap_bridge") if "grasp_plane_in_finger" in d["values"]]
    np.testing.assert_allclose(calib[-1][:3], HELD_AT, atol=2e-6)
    np.testing.assert_allclose(calib[-1][3:], q_param.as_quat(), atol=2e-6)
    held = [m for m in got if motion_s(m) < motion.slide_from]
    assert held and not any(m.slipping for m in held)
    v = q_param.inv().apply([0.02, 0.0, 0.0])                 # the slide, in the grasp plane
    for m in (m for m in got if motion_s(m) > slide_s):
        assert m.slipping
        assert (m.velocity.x, m.velocity.z) == pytest.approx((v[0], v[2]), abs=1e-6)


def test_a_bridge_without_poses_says_which_streams_it_waits_for(ros_env):
    """Issue #34: mocap_bridge logged nothing while no pose arrived, so a lab with a wrong
    topic name saw a silent node. It names the streams it still waits for (every
    ``WAITING_LOG_S``), and stops once both arrive (the other tests here feed them)."""
    params = {"finger_topic": "/lab/finger_body/pose", "object_topic": "/lab/object_body/pose"}
    with NodeProcess("mocap_bridge", ros_env, params) as node:
        node.wait_ready()
        assert node.wait_for("waiting for poses on /lab/finger_body/pose (finger) and "
                             "/lab/object_body/pose (object)", 30.0), node.output
