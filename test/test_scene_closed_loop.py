"""Closed loop: the simulated arm, the wall push and the external drag."""

import numpy as np
import pytest

from aslip_ros.arm import Arm, ArmError
from aslip_ros.scene import World, scenarios

FS = 48000


def _ready(world):
    world.arm.connect()
    world.arm.enable_velocity_mode()
    return world.arm


def test_sim_arm_satisfies_protocol_and_guards_order():
    world = World(scenarios.wall_push(seed=0))
    assert isinstance(world.arm, Arm)
    with pytest.raises(ArmError, match="enable_velocity_mode"):
        world.arm.send_velocity(np.zeros(3), 0.1)
    arm = _ready(world)
    with pytest.raises(ValueError, match="3 finite"):
        arm.send_velocity([0.0, 0.0], 0.1)
    with pytest.raises(ValueError, match="duration_s"):
        arm.send_velocity([0.0, 0.0, 0.0], 0.0)
    with pytest.raises(ArmError, match="exceeds"):
        arm.send_velocity([2.0, 0.0, 0.0], 0.1)
    robot = World(scenarios.robot_induced(seed=0, duration_s=1.0))
    with pytest.raises(ArmError, match="robot_induced"):
        _ready(robot).send_velocity([0.01, 0.0, 0.0], 0.1)


def test_arm_stops_after_duration_timeout_with_lag():
    world = World(scenarios.wall_push(seed=0, wall_distance_m=1.0))
    arm = _ready(world)
    p0 = arm.tcp_pose()[:3]
    arm.send_velocity([0.05, 0.0, 0.0], duration_s=0.1)
    world.step(480)                                    # 10 ms: still accelerating (lag)
    assert 0.0 < world.arm.v[0] < 0.05
    world.step(int(0.5 * FS))
    assert np.linalg.norm(world.arm.v) < 1e-6           # stopped by itself
    moved = arm.tcp_pose()[0] - p0[0]
    assert moved == pytest.approx(0.05 * 0.1, rel=0.05)  # ~5 mm, nothing after timeout
    before = arm.tcp_pose()
    world.step(4800)
    assert np.allclose(before, arm.tcp_pose())
    arm.send_velocity([0.0, 0.0, 0.05], 1.0)
    world.step(2400)
    arm.stop()
    world.step(9600)                                   # 10 lag time constants
    assert np.linalg.norm(world.arm.v) < 1e-5


def test_wall_push_makes_slip_and_reports_contact():
    scn = scenarios.wall_push(seed=1, object="chips_can", wall_distance_m=0.03)
    world = World(scn)
    arm = _ready(world)
    n = world.wall_normal()
    slip_audio = []
    for _ in range(150):                                # 1.5 s at 40 mm/s: 60 mm of travel
        arm.send_velocity(0.04 * n, duration_s=0.05)
        ch = world.step(480)
        slip_audio.append(ch.audio)
    assert world.wall_contact_time == pytest.approx(0.03 / 0.04, abs=0.05)
    travel = (world.wall_contact_tcp_position - world.trajectory()["tcp"][0]) @ n
    assert travel == pytest.approx(0.03, abs=1e-3)
    assert world.slip_onset_time > world.wall_contact_time   # compliance first, then slip
    rel = world.relative_xz()
    # Everything the arm travelled beyond contact plus the compliance is slip backwards.
    slack = 2 * 0.6 * scn.grip_force_n / scn.wall_stiffness_n_m
    assert rel[0] == pytest.approx(-(0.06 - 0.03 - slack), abs=2e-3)
    traj = world.trajectory()
    obj_along = traj["object"] @ n
    assert np.ptp(obj_along[traj["t"] > world.slip_onset_time + 0.02]) < 1e-3  # object held
    loud = np.sqrt(np.mean(np.concatenate(slip_audio[-40:]) ** 2))
    quiet = np.sqrt(np.mean(np.concatenate(slip_audio[5:40]) ** 2))
    assert loud > quiet                                  # slipping is audible


def test_wall_retreat_does_not_pull_object_back():
    world = World(scenarios.wall_push(seed=2, wall_distance_m=0.0))
    arm = _ready(world)
    n = world.wall_normal()
    for _ in range(50):
        arm.send_velocity(0.04 * n, 0.05)
        world.step(480)
    arm.stop()
    world.step(9600)                                    # let the lagging arm settle
    r1 = world.relative_xz()
    for _ in range(50):
        arm.send_velocity(-0.04 * n, 0.05)
        world.step(480)
    assert np.allclose(world.relative_xz(), r1)
    assert world.wall_contact_time == 0.0               # started touching the wall
    for _ in range(100):                                # re-approach: a new contact onset
        arm.send_velocity(0.04 * n, 0.05)
        world.step(480)
    assert len(world.wall_contacts) == 2
    t2, p2 = world.wall_contacts[1]
    assert t2 > 1.0 and np.isfinite(p2).all()


def _drag(follow: bool, seed: int = 3) -> float:
    world = World(scenarios.external_drag(seed=seed))
    arm = _ready(world)
    rot = world._plane                                  # grasp-plane x, z axes in world
    for _ in range(400):                                # 4 s at 100 Hz
        if follow:
            # An oracle controller: command the object's own velocity (relative + arm).
            v_obj = rot @ world.slip_velocity() + world.arm.v
            arm.send_velocity(v_obj, duration_s=0.05)
        world.step(480)
    rel = world.trajectory()["rel"]
    return float(np.sqrt(np.mean(np.sum((rel - rel[0]) ** 2, axis=1))))


def test_drag_slips_unless_the_arm_follows():
    free, followed = _drag(False), _drag(True)
    assert free > 0.01                                  # centimetres of slip
    assert followed < 0.3 * free


def test_a_drag_hold_delays_the_agent_path_and_changes_nothing_else():
    """drag_hold_s: the agent holds the object still at the grasp, then pulls exactly as it
    would have without the hold, only later."""
    t = np.arange(0.0, 6.0, 0.005)
    paths = {}
    assert scenarios.external_drag(seed=5).drag_hold_s == 1.0     # the scene's default
    for hold in (0.0, 1.0):
        world = World(scenarios.external_drag(seed=5, drag_hold_s=hold))
        paths[hold] = world._drag.evaluate(t)
    assert not paths[1.0][t < 1.2].any()                       # still through the hold
    shift = int(round(1.0 / 0.005))
    np.testing.assert_allclose(paths[1.0][shift:], paths[0.0][:-shift], atol=1e-12)
    assert paths[0.0][t < 1.0].any()                           # without it, it pulls early
    with pytest.raises(ValueError, match="drag_hold_s"):
        scenarios.external_drag(seed=5, drag_hold_s=-1.0)
