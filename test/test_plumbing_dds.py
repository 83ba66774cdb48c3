"""Two separate processes exchange AudioFrame and SlipVector over DDS.

The publisher is a child process; the subscriber is this test process. Both sit on a
ROS_DOMAIN_ID reserved for the test, with localhost-only discovery.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from conftest import HELPERS
from helpers.aslip_samples import REQUIRED_FIELDS, fill, to_plain

from aslip_ros.util import die_with_parent

pytestmark = pytest.mark.ros


def _start_publisher(env):
    """Start the child publisher and wait until it says it is publishing.

    Started by path (not ``-m``) so the repository root is not put on the child's
    sys.path, where the source tree would shadow the built package.
    """
    proc = subprocess.Popen([sys.executable, str(HELPERS / "pub_samples.py")], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=die_with_parent)
    line = proc.stdout.readline()
    if "publisher ready" not in line:
        proc.kill()
        raise AssertionError("publisher failed to start:\n" + line + proc.stdout.read())
    return proc


def _receive(context, types_topics, timeout_s=20.0):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    node = rclpy.create_node("aslip_plumbing_listener", context=context)
    got: dict[str, object] = {}
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    for msg_type, topic in types_topics:
        node.create_subscription(msg_type, topic,
                                 lambda m, t=topic: got.setdefault(t, m), qos)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    deadline = time.monotonic() + timeout_s
    while len(got) < len(types_topics) and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.1)
    ex.shutdown()
    node.destroy_node()
    return got


def test_messages_round_trip_between_processes(rclpy_context, ros_env):
    from aslip_ros.msg import AudioFrame, SlipVector

    proc = _start_publisher(ros_env)
    try:
        got = _receive(rclpy_context, [(AudioFrame, "/aslip/audio"),
                                       (SlipVector, "/aslip/slip")])
    finally:
        proc.terminate()
        out = proc.communicate(timeout=10)[0]
    assert set(got) == {"/aslip/audio", "/aslip/slip"}, f"not delivered; child said:\n{out}"
    for topic, msg_type in (("/aslip/audio", AudioFrame), ("/aslip/slip", SlipVector)):
        received = to_plain(got[topic])
        expected = to_plain(fill(msg_type()))
        assert received == expected, topic
        assert REQUIRED_FIELDS[msg_type.__name__] <= set(received), "contract field missing"


def test_other_domain_receives_nothing(ros_env, python_exe):
    """Isolation: a listener on another domain must not see the test's publisher."""
    from domain_coordinator import domain_id

    import rclpy
    from rclpy.context import Context

    from aslip_ros.msg import SlipVector

    proc = _start_publisher(ros_env)
    try:
        with domain_id() as other:
            assert str(other) != ros_env["ROS_DOMAIN_ID"]
            ctx = Context()
            rclpy.init(context=ctx, domain_id=other)
            try:
                got = _receive(ctx, [(SlipVector, "/aslip/slip")], timeout_s=3.0)
            finally:
                rclpy.try_shutdown(context=ctx)
    finally:
        proc.terminate()
        proc.communicate(timeout=10)
    assert got == {}


@pytest.mark.parametrize("type_name", ["AudioFrame", "SlipVector"])
def test_comparison_detects_any_lost_field(type_name):
    """The round-trip check cannot pass with a field lost: resetting any single field of
    the sample to its default changes the comparison."""
    import aslip_ros.msg as m

    msg_type = getattr(m, type_name)
    full = to_plain(fill(msg_type()))
    assert REQUIRED_FIELDS[type_name] <= set(full)
    for field in msg_type.get_fields_and_field_types():
        broken = fill(msg_type())
        setattr(broken, field, getattr(msg_type(), field))
        assert to_plain(broken) != full, f"field {field} not covered by the sample"
