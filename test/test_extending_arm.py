"""Extending: an arm added in test code alone (test/helpers/fake_arm.py), driven by the real
slip_track node process (docs/design.md, "Extending")."""

from __future__ import annotations

import json
import signal
import threading
import time

import numpy as np
import pytest

from node_support import Bus, NodeProcess

pytestmark = pytest.mark.ros


def _calls(path):
    if not path.exists():
        return []
    lines = path.read_text().splitlines()
    return [json.loads(line) for line in lines if line.endswith("}")]


def test_an_arm_from_test_code_is_driven_within_the_limits(rclpy_context, ros_env, tmp_path):
    from geometry_msgs.msg import PoseStamped

    from aslip_ros.msg import SlipVector
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
    from aslip_ros.nodes import convert
    log = tmp_path / "arm.jsonl"
    env = dict(ros_env, FAKE_ARM_LOG=str(log))
    bus = Bus(rclpy_context)
    bus.listen(PoseStamped, c.TCP_TOPIC, SENSOR_QOS)
    pub = bus.node.create_publisher(SlipVector, c.SLIP_TOPIC, RELIABLE_QOS)
    alive = threading.Event()
    alive.set()

    def slip():
        # A steady slip along grasp-plane x while the arm moves: the object outruns the
        # arm, so the law asks for more and more speed, up to its own 5 cm/s.
        while alive.is_set():
            pub.publish(convert.slip_to_msg(0.02, 0.0, 0.9, True, 0.5, time.time_ns(), 0.1,
                                            "test"))
            time.sleep(0.01)

    t = threading.Thread(target=slip, daemon=True)
    t.start()
    # The watchdogs at their most lenient (1 s): a stale-input stop latches, and this test
    # is about the arm, not the watchdog (test_nodes_control.py). At 0.1 s a publisher
    # thread starved for 0.33 s on a loaded CI machine stopped the arm before it moved.
    params = {"arm": "fake_arm:make_arm", "arm_max_speed_m_s": 0.01,
              "slip_timeout_s": 1.0, "pose_timeout_s": 1.0}
    try:
        with NodeProcess("slip_track", env, params) as ctl:
            ctl.wait_ready()
            moving = lambda: [k for k in _calls(log) if k["call"] == "velocity" and  # noqa: E731
                              np.linalg.norm(k["v"]) > 0.0099]
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and len(moving()) < 5:
                time.sleep(0.05)
            assert len(moving()) >= 5, ctl.output
            # The node republishes the TCP the arm measured (polled on the arm thread).
            assert bus.wait(lambda: len(bus.messages(c.TCP_TOPIC)) > 5, 10), ctl.output
            ctl.proc.send_signal(signal.SIGINT)
            assert ctl.proc.wait(10) == 0, ctl.output
    finally:
        alive.clear()           # also when a check failed: no thread left publishing
        t.join(2)
    bus.close()
    calls = _calls(log)
    names = [k["call"] for k in calls]
    assert names[:2] == ["connect", "enable"], names[:5]
    speeds = [np.linalg.norm(k["v"]) for k in calls if k["call"] == "velocity"]
    # The limits wrapper held every command to arm_max_speed_m_s (the law wanted 5 cm/s).
    assert max(speeds) == pytest.approx(0.01, rel=1e-6)
    assert all(k["duration"] <= 0.5 for k in calls if k["call"] == "velocity")
    # Shutdown: a stop, the arm released, and no velocity command after the first stop.
    first_stop = names.index("stop")
    assert "velocity" not in names[first_stop:] and names[-1] == "close", names[-5:]


def test_an_unknown_or_unimportable_arm_is_refused(ros_env):
    for name in ("ur5", "no_such_module_anywhere:make_arm", "fake_arm:nothing"):
        proc = NodeProcess("slip_track", ros_env, {"arm": name})
        assert proc.proc.wait(30) == 2
        out = proc.stop()
        assert "refused to start" in out and name in out, out
