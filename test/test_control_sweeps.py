"""Robot-induced sweeps (aslip_ros.control.sweeps), closed loop on a kinematic arm and a fake
clock: bounds for many seeds, the grasp plane, the return to start, the stops."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros.arm import ArmError
from aslip_ros.control.command import apply_command
from aslip_ros.control.frames import grasp_to_base
from aslip_ros.control.limits import ArmLimits, LimitedArm
from aslip_ros.control.sweeps import (SweepConfig, SweepEnd, SweepState, SweepTask,
                                      braking_speed, room_in_ball, room_in_box)
from fake_clock import FakeClock

DT = 0.01
START = (0.4, 0.0, 0.3)
LEVEL = (0.0, 0.0, 0.0, 1.0)


class KinematicArm:
    """Moves at the commanded velocity until the command expires (as every arm must)."""

    def __init__(self, position, quat=LEVEL):
        self.p = np.array(position, dtype=float)
        self.q = np.array(quat, dtype=float)
        self.v = np.zeros(3)
        self.left = 0.0
        self.calls = []

    def connect(self):
        pass

    def enable_velocity_mode(self):
        pass

    def send_velocity(self, v, duration_s):
        self.v = np.asarray(v, dtype=float).copy()
        self.left = float(duration_s)
        self.calls.append(("velocity", self.v.copy()))

    def stop(self):
        self.v = np.zeros(3)
        self.left = 0.0
        self.calls.append(("stop", None))

    def tcp_pose(self):
        return np.concatenate([self.p, self.q])

    def close(self):
        pass

    def advance(self, dt):
        moving = min(dt, self.left)
        self.p = self.p + self.v * moving
        self.left -= moving


def run(task, arm, clock, seconds, feed=lambda t: True, hook=None):
    """Closed loop at 100 Hz; returns (commands, TCP positions after each step)."""
    cmds, path = [], []
    for _ in range(int(round(seconds / DT))):
        clock.t += DT
        arm.advance(DT)
        path.append(arm.p.copy())
        if feed(clock.t):
            task.on_tcp_pose(arm.tcp_pose())
        cmd = task.step()
        cmds.append(cmd)
        apply_command(arm, cmd)
        if hook is not None:
            hook(clock.t)
    return cmds, np.array(path)


def started(cfg, position=START, quat=LEVEL):
    clock = FakeClock()
    task = SweepTask(cfg, clock)
    arm = KinematicArm(position, quat)
    task.on_tcp_pose(arm.tcp_pose())
    task.start()
    return task, arm, clock


def velocities(cmds):
    return [c.velocity for c in cmds if c is not None and not c.stop]


# ------------------------------------------------------------------------- bounds

@pytest.mark.parametrize("seed", range(24))
def test_every_seed_stays_inside_returns_and_stops(seed):
    cfg = SweepConfig(seed=seed, duration_s=12.0)
    task, arm, clock = started(cfg)
    cmds, path = run(task, arm, clock, 12.0 + cfg.return_timeout_s)
    offsets = np.linalg.norm(path - START, axis=1)
    assert offsets.max() <= cfg.sweep_radius_m + 1e-9
    assert np.all(path >= np.array(cfg.workspace_min_m)) and \
        np.all(path <= np.array(cfg.workspace_max_m))
    speeds = [np.linalg.norm(v) for v in velocities(cmds)]
    assert max(speeds) <= cfg.max_speed_m_s + 1e-12
    assert max(speeds) > 0.003 and task.sweeps >= 2         # it did sweep, more than once
    # Pauses between the sweeps: zero commands while the run was still sweeping.
    assert any(np.linalg.norm(v) == 0.0 for v in velocities(cmds[:1100]))
    # The end: back at the start, one stop, then nothing.
    assert task.state is SweepState.STOPPED and task.end_reason is SweepEnd.DONE
    assert np.linalg.norm(arm.p - START) <= cfg.return_tolerance_m
    stops = [i for i, c in enumerate(cmds) if c is not None and c.stop]
    assert len(stops) == 1 and all(c is None for c in cmds[stops[0] + 1:])
    assert arm.calls[-1] == ("stop", None)


def test_sweep_statistics_and_speed_limit_follow_the_config():
    """A lower speed limit caps the drawn sweeps too; the radius binds the excursion."""
    cfg = SweepConfig(seed=5, duration_s=30.0, max_speed_m_s=0.02, sweep_radius_m=0.01)
    task, arm, clock = started(cfg)
    cmds, path = run(task, arm, clock, 30.0)
    speeds = np.array([np.linalg.norm(v) for v in velocities(cmds)])
    assert speeds.max() <= 0.02 + 1e-12
    assert np.linalg.norm(path - START, axis=1).max() <= 0.01 + 1e-9
    assert task.max_offset_m > 0.005          # it used the room it has


def test_near_a_workspace_wall_and_through_the_arm_limits():
    """Started 5 mm below the box's top, behind the arm's own limiter (its acceleration
    limit included): the TCP never leaves the box nor the ball."""
    limits = ArmLimits()
    start = (0.4, 0.0, limits.workspace_max_m[2] - 0.005)
    # Grasp plane x, z along base x, z: sweeps push straight at the top wall.
    cfg = SweepConfig(seed=2, duration_s=20.0)
    clock = FakeClock()
    inner = KinematicArm(start)
    arm = LimitedArm(inner, limits, clock=clock, sleep=clock.sleep)
    task = SweepTask(cfg, clock)
    task.on_tcp_pose(arm.tcp_pose())
    task.start()
    path = []
    for _ in range(int(30.0 / DT)):
        clock.t += DT
        inner.advance(DT)
        path.append(inner.p.copy())
        task.on_tcp_pose(arm.tcp_pose())
        apply_command(arm, task.step())
    path = np.array(path)
    assert path[:, 2].max() <= limits.workspace_max_m[2] + 1e-9
    assert np.linalg.norm(path - start, axis=1).max() <= cfg.sweep_radius_m + 1e-4
    assert path[:, 2].max() > limits.workspace_max_m[2] - 1e-3      # the wall did bind
    assert task.end_reason is SweepEnd.DONE


def test_sweeps_lie_in_the_grasp_plane_of_a_turned_gripper():
    """TCP turned and a grasp-plane calibration: every sweep velocity is a combination of
    the grasp plane's x and z axes in link_base, never along its normal (y)."""
    quat = Rotation.from_euler("xyz", [150, 20, -60], degrees=True).as_quat()
    calib = tuple([0.0, 0.0, 0.05] + list(Rotation.from_euler("z", 30, degrees=True)
                                          .as_quat()))
    cfg = SweepConfig(seed=7, duration_s=15.0, grasp_plane_in_tcp=calib)
    task, arm, clock = started(cfg, quat=quat)
    cmds, _ = run(task, arm, clock, 15.0)
    pose = np.concatenate([START, quat])
    normal = grasp_to_base([0.0, 1.0, 0.0], pose, calib)
    moving = [v for v in velocities(cmds) if np.linalg.norm(v) > 0]
    assert len(moving) > 100
    assert max(abs(float(v @ normal)) for v in moving) < 1e-12
    # Both in-plane axes are used.
    for axis in ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]):
        a = grasp_to_base(axis, pose, calib)
        assert max(abs(float(v @ a)) for v in moving) > 1e-3


def test_the_same_seed_gives_the_same_sweeps():
    def commands(seed):
        task, arm, clock = started(SweepConfig(seed=seed, duration_s=8.0))
        cmds, _ = run(task, arm, clock, 10.0)
        return np.array([c.velocity for c in cmds if c is not None])
    a, b, other = commands(11), commands(11), commands(12)
    assert a.shape == b.shape and np.array_equal(a, b)
    assert a.shape != other.shape or not np.array_equal(a, other)


# ------------------------------------------------------------------------- endings

def test_until_stopped_then_finish_returns_to_the_start():
    cfg = SweepConfig(seed=1, duration_s=0.0)
    task, arm, clock = started(cfg)
    run(task, arm, clock, 40.0)
    assert task.state is SweepState.SWEEPING          # 0 = no end of its own
    task.finish()
    assert task.state is SweepState.RETURNING
    cmds, _ = run(task, arm, clock, cfg.return_timeout_s)
    assert task.end_reason is SweepEnd.DONE
    assert np.linalg.norm(arm.p - START) <= cfg.return_tolerance_m
    assert [c.stop for c in cmds if c is not None][-1] is True


def test_a_stale_pose_stops_at_once_and_for_good():
    cfg = SweepConfig(seed=3, duration_s=20.0)
    task, arm, clock = started(cfg)
    cmds, _ = run(task, arm, clock, 3.0, feed=lambda t: t < 2.0)
    assert task.end_reason is SweepEnd.STALE_POSE
    stop = next(i for i, c in enumerate(cmds) if c is not None and c.stop)
    # Stale after pose_timeout_s: the stop is the first step past it.
    assert stop * DT + DT == pytest.approx(2.0 + cfg.pose_timeout_s, abs=1.5 * DT)
    assert all(c is None for c in cmds[stop + 1:])
    # Fresh poses do not restart a stopped run.
    cmds, _ = run(task, arm, clock, 1.0)
    assert all(c is None for c in cmds)


@pytest.mark.parametrize("how", ["fault", "shutdown"])
def test_a_fault_or_shutdown_stops_once(how):
    task, arm, clock = started(SweepConfig(seed=4))
    run(task, arm, clock, 2.0)
    getattr(task, how)()
    first, second = task.step(), task.step()
    assert first.stop and first.reason == how.replace("fault", "error")
    assert second is None
    assert task.end_reason is {"fault": SweepEnd.ERROR, "shutdown": SweepEnd.SHUTDOWN}[how]


def test_a_return_that_does_not_arrive_times_out():
    """An arm that ignores commands: the return gives up after return_timeout_s."""
    cfg = SweepConfig(seed=0, duration_s=1.0, return_timeout_s=0.5)
    clock = FakeClock()
    task = SweepTask(cfg, clock)
    stuck = np.array(list(START) + list(LEVEL))
    task.on_tcp_pose(stuck)
    task.start()
    stuck[0] += 0.01      # say the TCP sits 1 cm away and stays there
    ends = []
    for _ in range(300):
        clock.t += DT
        task.on_tcp_pose(stuck)
        cmd = task.step()
        if cmd is not None and cmd.stop:
            ends.append(clock.t)
    assert task.end_reason is SweepEnd.RETURN_TIMEOUT and "10.0 mm" in task.detail
    assert ends == [pytest.approx(1.0 + 0.5 + DT, abs=1.5 * DT)]


def test_start_needs_a_fresh_pose_inside_the_workspace():
    clock = FakeClock()
    task = SweepTask(SweepConfig(), clock)
    with pytest.raises(RuntimeError, match="fresh TCP pose"):
        task.start()
    task.on_tcp_pose(list(START) + list(LEVEL))
    clock.t += 1.0
    with pytest.raises(RuntimeError, match="fresh TCP pose"):
        task.start()
    task.on_tcp_pose([0.9, 0.0, 0.3] + list(LEVEL))
    with pytest.raises(ValueError, match="outside the workspace"):
        task.start()
    assert task.step() is None and task.state is SweepState.IDLE
    assert not task.on_tcp_pose([np.nan] * 7) and task.rejected_inputs == 1


def test_arm_errors_surface_through_the_worker_not_here():
    """The task never calls the arm: a failing arm is the caller's to report (fault)."""
    class Failing(KinematicArm):
        def send_velocity(self, v, duration_s):
            raise ArmError("boom")
    task, _, clock = started(SweepConfig(seed=0))
    clock.t += DT
    task.on_tcp_pose(list(START) + list(LEVEL))
    with pytest.raises(ArmError):
        apply_command(Failing(START), task.step())
    task.fault("boom")
    assert task.step().stop and task.detail == "boom"


# ------------------------------------------------------------------------- pieces

def test_braking_and_room():
    s = braking_speed(0.01, 0.1, 1.0)
    assert s * 0.1 + s * s / 2.0 == pytest.approx(0.01)
    assert braking_speed(0.0, 0.1, 1.0) == 0.0
    x = np.array([1.0, 0.0, 0.0])
    assert room_in_ball(np.zeros(3), x, 0.02) == pytest.approx(0.02)
    assert room_in_ball(np.array([0.03, 0, 0]), x, 0.02) == 0.0          # outward, outside
    assert room_in_ball(np.array([0.03, 0, 0]), -x, 0.02) == pytest.approx(0.05)   # back in
    lo, hi = np.zeros(3), np.ones(3)
    assert room_in_box(np.full(3, 0.5), x, lo, hi) == pytest.approx(0.5)
    assert room_in_box(np.array([1.2, 0.5, 0.5]), x, lo, hi) == 0.0


@pytest.mark.parametrize("bad,match", [
    (dict(sweep_radius_m=0.0), "sweep_radius_m"),
    (dict(duration_s=-1.0), "duration_s"),
    (dict(seed=-1), "seed"),
    (dict(return_tolerance_m=0.05), "return_tolerance_m"),
    (dict(workspace_min_m=None), "both workspace corners"),
    (dict(workspace_min_m=(1.0, 0.0, 0.0), workspace_max_m=(0.0, 1.0, 1.0)), "below"),
    (dict(grasp_plane_in_tcp=(0.0,) * 7), "quaternion"),
])
def test_config_is_validated(bad, match):
    with pytest.raises(ValueError, match=match):
        SweepConfig(**bad)


def test_sweep_statistics_are_the_scenes():
    """Defaults defined once: the run's length, the speed and acceleration limits."""
    from aslip_ros.scene.scenarios import Scenario
    cfg = SweepConfig()
    assert cfg.duration_s == Scenario.duration_s
    assert (cfg.max_speed_m_s, cfg.max_acc_m_s2) == (ArmLimits.max_speed_m_s,
                                                     ArmLimits.max_acc_m_s2)
