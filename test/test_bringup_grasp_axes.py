"""``aslip check grasp-axes``: the grasp plane measured, not assumed (#34, item 7).

Robot-induced labels are read in the TCP's grasp plane, external ones in the finger body's;
with the finger body turned on the gripper and both calibrations left at identity the two
data sets disagreed by that turn. After the procedure, a turned finger body labels the same
motion as an aligned one, and as the TCP does.
"""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from aslip_ros.bringup import grasp_axes as ga
from aslip_ros.bringup.cell_edit import set_cell_values
from aslip_ros.cell import CellError, load_cell
from aslip_ros.data.labels import PoseTrack, mocap_window_velocity, robot_window_velocity
from aslip_ros.poses import IDENTITY_POSE, compose
from conftest import ROOT

TURN_DEG = 90.0


def _turn(deg: float) -> np.ndarray:
    """The finger body's orientation in the grasp plane: turned about the pad normal (+y)."""
    return Rotation.from_rotvec([0.0, np.radians(deg), 0.0]).as_quat()


def _measured(deg: float, seed: int = 1) -> list:
    """``grasp_plane_in_finger`` after the procedure on the scene, finger body turned."""
    scene = ga.SceneCell(seed=seed, finger_mount=_turn(deg))
    v, values = ga.measure(scene.arm, scene, {}, out=io.StringIO(), clock=scene.clock,
                           sleep=scene.sleep)
    assert v.ok, v.problems
    return values["mocap_bridge"]["grasp_plane_in_finger"]


def _motion():
    """Two seconds of a gripper moving and turning in the world while the object slips and
    turns in the grasp: the TCP (= the grasp plane here) and the object, at 120 Hz."""
    t = np.arange(0.0, 2.0, 1.0 / 120.0)
    tcp = np.zeros((t.size, 7))
    tcp[:, 0], tcp[:, 2] = 0.3 + 0.02 * t, 0.2 + 0.01 * np.sin(3 * t)
    tcp[:, 3:] = (Rotation.from_euler("z", 20, degrees=True)
                  * Rotation.from_rotvec(np.outer(0.2 * t, [0, 1, 0]))).as_quat()
    slip = np.zeros((t.size, 7))
    slip[:, 0], slip[:, 2] = 0.01 * t, -0.005 * t ** 2           # in the grasp plane
    slip[:, 3:] = Rotation.from_rotvec(np.outer(0.3 * t, [0, 1, 0])).as_quat()
    return t, tcp, compose(tcp, slip)


def _labels(finger, obj, t, calib):
    t0 = np.arange(0.0, 1.8, 0.1)
    lab = mocap_window_velocity(PoseTrack(t, finger), PoseTrack(t, obj), t0, t0 + 0.2, calib)
    assert lab.valid.all()
    return np.column_stack([lab.vx, lab.vz, lab.angular])


def test_a_turned_finger_body_labels_the_same_motion_as_an_aligned_one():
    t, tcp, obj = _motion()
    aligned = _labels(tcp, obj, t, IDENTITY_POSE)
    turned_body = compose(tcp, np.concatenate([np.zeros((len(t), 3)),
                                               np.tile(_turn(TURN_DEG), (len(t), 1))], 1))
    # Before: identity assumed, the turn swaps the axes (what the issue found).
    before = _labels(turned_body, obj, t, IDENTITY_POSE)
    assert np.max(np.abs(before[:, :2] - aligned[:, :2])) > 0.005
    # After the procedure: the same labels, to the scene's motion-capture noise.
    after = _labels(turned_body, obj, t, _measured(TURN_DEG))
    np.testing.assert_allclose(after, aligned, atol=2e-4)


def test_after_the_procedure_robot_and_mocap_labels_agree():
    """A probe fixed in the world, the gripper sweeping: the TCP's labels (pretraining) and
    the turned finger body's (training) are the same numbers."""
    t, tcp, _ = _motion()
    tcp[:, 3:] = np.tile(tcp[0, 3:], (len(t), 1))            # the sweeps translate
    probe = np.tile([0.5, 0.1, 0.2, 0, 0, 0, 1.0], (len(t), 1))
    turned_body = compose(tcp, np.concatenate([np.zeros((len(t), 3)),
                                               np.tile(_turn(-TURN_DEG), (len(t), 1))], 1))
    t0 = np.arange(0.0, 1.8, 0.1)
    robot = robot_window_velocity(PoseTrack(t, tcp), t0, t0 + 0.2, IDENTITY_POSE)
    mocap = _labels(turned_body, probe, t, _measured(-TURN_DEG))
    np.testing.assert_allclose(mocap[:, :2], np.column_stack([robot.vx, robot.vz]), atol=2e-4)


@pytest.mark.parametrize("deg", [0.0, 37.0])
def test_the_measured_orientation_is_the_inverse_of_the_mount(deg):
    q = _measured(deg, seed=2)[3:]
    err = (Rotation.from_quat(q) * Rotation.from_quat(_turn(deg))).magnitude()
    assert np.degrees(err) < 0.5


class _Still:
    """A finger body that does not move with the arm (on another gripper, or untracked)."""

    def mean_pose(self, seconds):
        return np.array([0.1, 0.2, 0.3, 0, 0, 0, 1.0])


def test_a_finger_body_that_does_not_follow_the_arm_fails_and_writes_nothing():
    scene = ga.SceneCell(seed=3)
    v, values = ga.measure(scene.arm, _Still(), {}, out=io.StringIO(), clock=scene.clock,
                           sleep=scene.sleep)
    assert not v.ok and values is None
    assert "did it move" in v.line()


def test_legs_of_different_lengths_fail():
    legs = [ga.Leg("+x", np.array([0.02, 0, 0]), np.array([0.01, 0, 0])),
            ga.Leg("+z", np.array([0, 0, 0.02]), np.array([0, 0, 0.02]))]
    v = ga.verdict(ga.solve(legs), legs, 0.02)
    assert "finger body moved 10.0 mm, the TCP 20.0 mm" in v.line()


def test_the_check_writes_the_cell_and_keeps_the_rest(tmp_path):
    """The command on the scene: the orientation written into the cell, the origin that
    aslip check grasp-plane measured kept, every other line (comments too) as it was."""
    from aslip_ros.cli import main
    cell = tmp_path / "cell.yaml"
    text = (ROOT / "config" / "cell_example.yaml").read_text().replace(
        "grasp_plane_in_finger: [0.0, 0.0, 0.0,", "grasp_plane_in_finger: [0.012, -0.003, 0.045,")
    cell.write_text(text)
    rc = main(["check", "grasp-axes", "--setup", str(cell), "--scene",
               "--scene-finger-turn-deg", str(TURN_DEG)])
    assert rc == 0
    after = cell.read_text()
    changed = [(a, b) for a, b in zip(text.splitlines(), after.splitlines()) if a != b]
    assert len(changed) == 1 and len(text.splitlines()) == len(after.splitlines())
    written = load_cell(str(cell)).get("mocap_bridge", "grasp_plane_in_finger")
    assert written[:3] == [0.012, -0.003, 0.045]
    err = (Rotation.from_quat(written[3:]) * Rotation.from_quat(_turn(TURN_DEG))).magnitude()
    assert np.degrees(err) < 0.5
    assert not [p for p in tmp_path.iterdir() if p.name != "cell.yaml"]      # atomic


def test_cell_edit_adds_what_is_missing_and_refuses_what_it_cannot_edit(tmp_path):
    cell = tmp_path / "cell.yaml"
    cell.write_text("# my cell\nrobot_sweeps: {}   # defaults\naudio_capture:\n"
                    "  device: x  # the interface\n")
    set_cell_values(cell, {"mocap_bridge": {"grasp_plane_in_finger": [0, 0, 0, 0, 0, 0, 1.0]},
                           "robot_sweeps": {"grasp_plane_in_tcp_x": 1.5}})
    doc = yaml.safe_load(cell.read_text())
    assert doc["mocap_bridge"]["grasp_plane_in_finger"] == [0, 0, 0, 0, 0, 0, 1.0]
    assert doc["robot_sweeps"] == {"grasp_plane_in_tcp_x": 1.5}
    assert "# the interface" in cell.read_text() and "# my cell" in cell.read_text()
    cell.write_text("mocap_bridge:\n  grasp_plane_in_finger:\n    - 0\n    - 0\n")
    with pytest.raises(CellError, match="several lines"):
        set_cell_values(cell, {"mocap_bridge": {"grasp_plane_in_finger": [0] * 6 + [1.0]}})
    assert cell.read_text().endswith("- 0\n")


# ------------------------------------------------- mocap4r2: the finger's body of RigidBodies

class _Unreachable:
    """An xArm that cannot be reached: the check stops after choosing its finger poses."""

    def __init__(self, config):
        pass

    def connect(self):
        from aslip_ros.arm import ArmError
        raise ArmError("unreachable (test)")

    def close(self):
        pass


@pytest.mark.parametrize("cell_mocap, flags, watched", [
    ("  pose_source: rigid_bodies\n  finger_body: 3\n  object_body: 5\n", [],
     ("/rigid_bodies", "3")),
    ("  pose_source: rigid_bodies\n  finger_body: 3\n  object_body: 5\n"
     "  rigid_bodies_topic: /optitrack/rigid_bodies\n", ["--finger-body", "7"],
     ("/optitrack/rigid_bodies", "7")),
    ("  finger_topic: /vrpn_mocap/finger/pose\n", [], ("/vrpn_mocap/finger/pose",)),
    ("  finger_topic: /vrpn_mocap/finger/pose\n", ["--finger-body", "3"],
     ("/rigid_bodies", "3")),
])
def test_the_cell_chooses_the_finger_poses_as_mocap_bridge_does(
        tmp_path, monkeypatch, capsys, cell_mocap, flags, watched):
    """A cell with pose_source rigid_bodies needs no option: the check watches the finger's
    body of its RigidBodies topic (before: always a PoseStamped topic)."""
    from aslip_ros.cli import main
    from aslip_ros.hw import xarm
    from aslip_ros.nodes import finger_watch
    made = []

    class Watch:
        def __init__(self, *args):
            made.append(args)

        def close(self):
            pass
    monkeypatch.setattr(xarm, "XArmAdapter", _Unreachable)
    monkeypatch.setattr(finger_watch, "FingerWatch", Watch)
    cell = tmp_path / "cell.yaml"
    cell.write_text("arm:\n  xarm_ip: 192.0.2.1\nmocap_bridge:\n" + cell_mocap)
    assert main(["check", "grasp-axes", "--setup", str(cell), "--yes", *flags]) == 1
    assert made == [watched]
    assert "cannot connect: unreachable (test)" in capsys.readouterr().out


def test_a_rigid_bodies_cell_without_the_finger_body_is_refused(tmp_path, capsys):
    from aslip_ros.cli import main
    cell = tmp_path / "cell.yaml"
    cell.write_text("arm:\n  xarm_ip: 192.0.2.1\nmocap_bridge:\n  pose_source: rigid_bodies\n")
    assert main(["check", "grasp-axes", "--setup", str(cell), "--yes"]) == 1
    assert "mocap_bridge.pose_source rigid_bodies needs finger_body" in capsys.readouterr().err


def _driver(context, body_names, finger_pose):
    """A stand-in of mocap4r2's OptiTrack driver: RigidBodies at 100 Hz in frame ``map``,
    bodies named by their Motive ID; body 3 at ``finger_pose``, the others elsewhere. Returns
    (publisher node, stop)."""
    import threading

    import rclpy
    from node_support import driver_msgs
    msgs = driver_msgs("mocap4r2_msgs")
    node = rclpy.create_node("optitrack_stand_in", context=context)
    pub = node.create_publisher(msgs.RigidBodies, "rigid_bodies", 10)
    stop = threading.Event()

    def run():
        k = 0
        while not stop.wait(0.01):
            msg = msgs.RigidBodies()
            msg.header.frame_id = "map"
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.frame_number = k
            for name in body_names:
                p = finger_pose if name == "3" else [1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0]
                body = msgs.RigidBody(rigid_body_name=name)
                body.pose.position.x, body.pose.position.y, body.pose.position.z = p[:3]
                (body.pose.orientation.x, body.pose.orientation.y, body.pose.orientation.z,
                 body.pose.orientation.w) = p[3:]
                msg.rigidbodies.append(body)
            pub.publish(msg)
            k += 1
    thread = threading.Thread(target=run, daemon=True)
    thread.start()

    def close():
        stop.set()
        thread.join(5)
        node.destroy_node()
    return pub, close


@pytest.mark.ros
def test_the_finger_watch_averages_its_body_of_the_rigid_bodies(
        rclpy_context, ros_domain, monkeypatch):
    from aslip_ros.nodes.finger_watch import FingerWatch
    finger = [0.4, 0.1, 0.3, *Rotation.from_euler("z", 30, degrees=True).as_quat()]
    _, close = _driver(rclpy_context, ("1", "3", "5"), finger)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain))
    right, wrong = FingerWatch("/rigid_bodies", "3"), FingerWatch("/rigid_bodies", "7")
    try:
        deadline = time.monotonic() + 30
        while not (right.messages and wrong.messages):
            assert time.monotonic() < deadline, "no RigidBodies reached the watches"
            time.sleep(0.02)
        np.testing.assert_allclose(right.mean_pose(0.3), finger, atol=1e-9)
        with pytest.raises(ValueError) as err:
            wrong.mean_pose(0.3)
        assert "rigid body '7' (finger) is in none of the" in str(err.value)
        assert "bodies present: '1', '3', '5'" in str(err.value)
    finally:
        right.close()
        wrong.close()
        close()
