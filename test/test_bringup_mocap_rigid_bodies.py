"""aslip check mocap on mocap4r2's RigidBodies: the listener on messages published
in-process as the OptiTrack driver sends them, and the verdict on a missing body."""

from __future__ import annotations

import time

import pytest

from aslip_ros import cli
from aslip_ros.bringup.mocap_stats import mocap_verdict, stream_stats

MS = 1_000_000
BODIES = {"finger": "3", "object": "5"}


def _frame(msgs, k: int, stamp_ns: int, names):
    msg = msgs.RigidBodies()
    msg.header.frame_id = "map"
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.frame_number = k
    for name in names:
        body = msgs.RigidBody(rigid_body_name=name)
        body.pose.orientation.w = 1.0
        msg.rigidbodies.append(body)
    return msg


def _listen(context, names, n: int = 120):
    """Publish ``n`` frames at 100 Hz (stamped their send time minus 2 ms) from a
    reliable depth-1000 publisher once the check listens; ``names(k)`` are frame k's
    bodies. The check's samples per body and its missing-bodies text."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile

    from aslip_ros.nodes.mocap_check import MocapCheck
    from node_support import driver_msgs
    msgs = driver_msgs("mocap4r2_msgs")
    node = MocapCheck([], ("/rigid_bodies", BODIES), context=context)
    driver = rclpy.create_node("optitrack_stand_in", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.add_node(driver)
    pub = driver.create_publisher(msgs.RigidBodies, "rigid_bodies", QoSProfile(depth=1000))
    deadline = time.monotonic() + 30.0
    while pub.get_subscription_count() == 0:
        assert time.monotonic() < deadline, "the listener was never discovered"
        executor.spin_once(timeout_sec=0.05)
    start = driver.get_clock().now().nanoseconds - 2 * MS
    for k in range(n):                  # each frame when it is due: the latency is real
        while driver.get_clock().now().nanoseconds < start + k * 10 * MS + 2 * MS:
            executor.spin_once(timeout_sec=0.001)
        pub.publish(_frame(msgs, k, start + k * 10 * MS, names(k)))
    while node.tally.messages < n * 0.9 and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    samples, missing = node.samples(), node.missing_bodies()
    executor.shutdown()
    node.destroy_node()
    driver.destroy_node()
    return samples, missing


@pytest.mark.ros
def test_both_bodies_of_the_rigid_bodies_at_the_published_rate(rclpy_context):
    samples, missing = _listen(rclpy_context, lambda k: ("1", "5", "3"))
    assert missing == ""
    assert sorted(samples) == ["/rigid_bodies body '3' (finger)",
                               "/rigid_bodies body '5' (object)"]
    stats = {t: stream_stats(t, *s) for t, s in samples.items()}
    for s in stats.values():
        assert s.count >= 100 and s.rate_hz == pytest.approx(100.0, rel=1e-6)
        assert s.frame_ids == ("map",) and s.dropouts == 0
        assert 0.0 < s.latency_median_s < 0.5
    assert mocap_verdict(stats, missing_bodies=missing).line() == "verdict: OK"


@pytest.mark.ros
def test_a_body_missing_from_messages_fails_naming_the_bodies_present(rclpy_context):
    """Body 5 is lost for 20 frames: a dropout of its stream and a FAIL that names it with
    the bodies the messages do hold."""
    samples, missing = _listen(rclpy_context,
                               lambda k: ("1", "3") if 50 <= k < 70 else ("1", "3", "5"))
    assert "rigid body '5' (object) is missing from 20 of the" in missing
    assert missing.endswith("bodies present: '1', '3', '5'")
    stats = {t: stream_stats(t, *s) for t, s in samples.items()}
    assert stats["/rigid_bodies body '5' (object)"].dropouts == 1
    line = mocap_verdict(stats, missing_bodies=missing).line()
    assert line.startswith("verdict: FAIL") and "rigid body '5' (object)" in line


def test_a_body_in_no_message_fails_with_the_bodies_present():
    """The verdict on what a check saw of a body named wrong (7): no stream, and the text
    that names the bodies there are."""
    from aslip_ros.rigid_bodies import BodyTally, select_bodies
    from test_rigid_bodies import rigid_bodies
    tally = BodyTally({"finger": "3", "object": "7"})
    for k in range(10):
        tally.add(select_bodies(rigid_bodies(k, ["1", "3", "5"]), tally.bodies))
    stats = {"/rigid_bodies body '7' (object)": stream_stats("x", [], [])}
    line = mocap_verdict(stats, missing_bodies=tally.text()).line()
    assert "rigid body '7' (object) is in none of the 10 RigidBodies messages; bodies " \
        "present: '1', '3', '5'" in line


def test_one_body_alone_is_refused(capsys):
    assert cli.main(["check", "mocap", "--finger-body", "3", "--seconds", "0.1"]) == 1
    assert "--finger-body and --object-body go together" in capsys.readouterr().err


def test_a_rigid_bodies_cell_chooses_the_bodies_and_the_topic(tmp_path, capsys):
    """aslip check mocap --setup: the cell's mocap_bridge keys, options overriding them."""
    import argparse

    from aslip_ros.bringup.check import add_arguments
    from aslip_ros.bringup.mocap_source import resolve
    from aslip_ros.cell import load_cell
    cell = tmp_path / "cell.yaml"
    cell.write_text("mocap_bridge:\n  pose_source: rigid_bodies\n  finger_body: 3\n"
                    "  object_body: 5\n  rigid_bodies_topic: /optitrack/rigid_bodies\n")
    parser = argparse.ArgumentParser()
    add_arguments(parser)

    def source(*flags):
        args = parser.parse_args(["mocap", "--setup", str(cell), *flags])
        return resolve(args, load_cell(args.setup))
    s = source()
    assert s.rigid and s.bodies == BODIES and s.rigid_bodies_topic == "/optitrack/rigid_bodies"
    assert source("--finger-body", "4", "--object-body", "6").bodies == \
        {"finger": "4", "object": "6"}
    assert source("--finger-topic", "/f", "--object-topic", "/o").topics == \
        {"finger": "/f", "object": "/o"}
    assert cli.main(["check", "mocap", "--finger-body", "3", "--object-body", "5",
                     "--finger-topic", "/f"]) == 1
    assert "exclude each other" in capsys.readouterr().err
