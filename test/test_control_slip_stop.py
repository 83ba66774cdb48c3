"""Slip-stop (wall-push) state machine, driven by a kinematic arm and scripted slip."""

import numpy as np
import pytest

from aslip_ros.control.command import apply_command
from aslip_ros.control.slip_stop import (SlipStop, SlipStopConfig, State, StopReason)
from fake_clock import FakeClock

DT = 0.01


class KinematicArm:
    """Integrates commanded velocities; honours the command duration like the real arm."""

    def __init__(self, position):
        self.p = np.array(position, dtype=float)
        self.v = np.zeros(3)
        self.valid_until = 0.0
        self.stops = 0
        self.sent = []

    def connect(self):
        pass

    def enable_velocity_mode(self):
        pass

    def send_velocity(self, v, duration_s, now=0.0):
        self.v = np.asarray(v, dtype=float)
        self.valid_until = duration_s
        self.sent.append((self.v.copy(), duration_s))

    def stop(self):
        self.v = np.zeros(3)
        self.stops += 1

    def tcp_pose(self):
        return np.concatenate([self.p, [0, 0, 0, 1]])

    def close(self):
        pass

    def advance(self, dt):
        if self.valid_until > 0:
            self.p = self.p + self.v * dt
            self.valid_until -= dt
        else:
            self.v = np.zeros(3)


def run(task, arm, clock, slip_fn, steps, pose_ok=lambda t: True, slip_ok=lambda t: True):
    """Closed loop: feed pose + slip, step, apply, advance. Returns the commands."""
    cmds = []
    for _ in range(steps):
        clock.t += DT
        arm.advance(DT)
        if pose_ok(clock.t):
            task.on_tcp_pose(arm.tcp_pose())
        if slip_ok(clock.t):
            task.on_slip(slip_fn(clock.t, arm.p))
        cmd = task.step()
        cmds.append(cmd)
        apply_command(arm, cmd)
    return cmds


def make(cfg=None, wall_x=0.5):
    clock = FakeClock()
    cfg = cfg or SlipStopConfig(direction=(1, 0, 0), approach_speed_m_s=0.05,
                                retract_speed_m_s=0.1, settle_s=0.1, debounce_count=3)
    task = SlipStop(cfg, clock)
    arm = KinematicArm([wall_x, 0.0, 0.2])
    task.on_tcp_pose(arm.tcp_pose())
    task.on_slip(False)
    return task, arm, clock


def wall_slip(wall_x):
    return lambda t, p: p[0] >= wall_x + 0.002   # slips 2 mm past contact


def test_full_trial_stops_on_debounced_slip_and_reports_distance():
    task, arm, clock = make()
    task.start()
    assert task.state is State.RETRACTING
    cmds = run(task, arm, clock, wall_slip(0.5), 800)
    assert task.state is State.STOPPED
    assert task.reason is StopReason.SLIP
    res = task.result()
    assert res.success
    # Retracted ~10 cm, came back, slipped at +2 mm, stopped 3 estimates later.
    assert np.min([c.velocity[0] for c in cmds if c is not None and not c.stop]) < 0
    assert 0.002 <= res.stopping_distance_m <= 0.002 + 4 * 0.05 * DT + 1e-9
    assert res.approach_travel_m == pytest.approx(0.1 + res.command_distance_m, abs=0.006)
    halts = [c for c in cmds if c is not None and c.stop]
    assert len(halts) == 1 and halts[0].reason == 'slip'
    assert arm.stops == 1
    # Every motion command carries the configured duration.
    assert all(d == pytest.approx(0.1) for _, d in arm.sent)


def test_single_spurious_estimate_does_not_stop():
    task, arm, clock = make()
    task.start()
    run(task, arm, clock, lambda t, p: False, 150)   # retract + settle + some approach
    assert task.state is State.APPROACHING
    # One slipping estimate, then clean ones: debounce must swallow it.
    task.on_slip(True)
    task.on_slip(False)
    task.on_slip(True)
    task.on_slip(True)
    task.on_slip(False)
    assert task.state is State.APPROACHING
    task.on_slip(True)
    task.on_slip(True)
    task.on_slip(True)
    assert task.state is State.STOPPED and task.reason is StopReason.SLIP


def test_slip_during_retract_is_ignored():
    task, arm, clock = make()
    task.start()
    run(task, arm, clock, lambda t, p: True, 30)     # slipping all through the retract
    assert task.state is State.RETRACTING


def test_bounded_travel_without_slip():
    cfg = SlipStopConfig(direction=(0, 1, 0), approach_speed_m_s=0.1, retract_speed_m_s=0.1,
                         retract_distance_m=0.05, settle_s=0.0, max_approach_distance_m=0.08)
    task, arm, clock = make(cfg)
    y0 = arm.p[1]
    task.start()
    run(task, arm, clock, lambda t, p: False, 600)
    assert task.reason is StopReason.MAX_TRAVEL
    assert not task.result().success
    assert arm.p[1] - (y0 - 0.05) <= 0.08 + 0.1 * DT + 1e-9
    assert arm.stops == 1


def test_stale_slip_stops_and_latches():
    task, arm, clock = make()
    task.start()
    run(task, arm, clock, lambda t, p: False, 150)
    assert task.state is State.APPROACHING
    cmds = run(task, arm, clock, lambda t, p: False, 20, slip_ok=lambda t: False)
    assert task.reason is StopReason.STALE_SLIP
    halts = [c for c in cmds if c is not None and c.stop]
    assert len(halts) == 1
    # Stays stopped even when estimates come back.
    cmds = run(task, arm, clock, lambda t, p: True, 20)
    assert all(c is None for c in cmds)
    assert task.state is State.STOPPED


def test_stale_pose_stops():
    task, arm, clock = make()
    task.start()
    run(task, arm, clock, lambda t, p: False, 20, pose_ok=lambda t: False)
    assert task.reason is StopReason.STALE_POSE


def test_fault_and_shutdown_stop():
    task, arm, clock = make()
    task.start()
    run(task, arm, clock, lambda t, p: False, 5)
    task.fault('ArmError: code 1')
    cmd = task.step()
    assert cmd.stop and cmd.reason == 'error'
    assert task.step() is None
    task2, arm2, clock2 = make()
    task2.start()
    task2.shutdown()
    assert task2.step().stop
    assert task2.reason is StopReason.SHUTDOWN


def test_shutdown_when_idle_still_commands_stop():
    task, _, _ = make()
    task.shutdown()
    cmd = task.step()
    assert cmd.stop and cmd.reason == 'shutdown'
    assert task.step() is None


def test_start_requires_fresh_pose_and_not_running():
    clock = FakeClock()
    task = SlipStop(SlipStopConfig(), clock)
    with pytest.raises(RuntimeError):
        task.start()
    task.on_tcp_pose([0, 0, 0, 0, 0, 0, 1])
    clock.t = 1.0
    with pytest.raises(RuntimeError):
        task.start()           # pose is stale
    task.start(contact_pose=[0, 0, 0, 0, 0, 0, 1])
    with pytest.raises(RuntimeError):
        task.start(contact_pose=[0, 0, 0, 0, 0, 0, 1])


def test_retract_timeout_when_arm_does_not_move():
    task, arm, clock = make()
    task.start()
    for _ in range(400):
        clock.t += DT
        task.on_tcp_pose(arm.tcp_pose())   # the arm ignores commands
        task.on_slip(False)
        cmd = task.step()
        if cmd is not None and cmd.stop:
            break
    assert task.reason is StopReason.TIMEOUT


def test_bad_pose_rejected_not_crashing():
    task, _, _ = make()
    assert not task.on_tcp_pose([np.nan] * 7)
    assert not task.on_tcp_pose([0, 0, 0, 0, 0, 0, 0])
    assert not task.on_tcp_pose([1, 2, 3])
    assert task.rejected_inputs == 3


def test_result_uses_final_resting_pose():
    task, arm, clock = make()
    task.start()
    run(task, arm, clock, wall_slip(0.5), 800)
    before = task.result().stopping_distance_m
    arm.p[0] += 0.001          # the arm coasts 1 mm while decelerating
    task.on_tcp_pose(arm.tcp_pose())
    res = task.result()
    assert res.stopping_distance_m == pytest.approx(before + 0.001)
    assert res.command_distance_m == pytest.approx(before)


@pytest.mark.parametrize('kwargs', [
    dict(direction=(0, 0, 0)),
    dict(direction=(np.nan, 0, 0)),
    dict(approach_speed_m_s=0.0),
    dict(retract_distance_m=-0.1),
    dict(max_approach_distance_m=0.05),        # shorter than the retract
    dict(debounce_count=0),
    dict(debounce_count=1.5),
    dict(slip_timeout_s=float('inf')),
    dict(settle_s=-1.0),
])
def test_bad_config_rejected(kwargs):
    with pytest.raises(ValueError):
        SlipStopConfig(**kwargs)


def test_direction_is_normalised():
    cfg = SlipStopConfig(direction=(0, 3, 4))
    assert np.allclose(cfg.unit_direction, [0, 0.6, 0.8])
