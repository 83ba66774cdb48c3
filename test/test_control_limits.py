"""LimitedArm: the speed, acceleration, workspace and rate limits around any Arm."""

from __future__ import annotations

import numpy as np
import pytest

from aslip_ros.arm import Arm, ArmError
from aslip_ros.control.limits import ArmLimits, LimitedArm
from fake_clock import FakeClock


class RecordingArm:
    """A bare arm: records commands, reports a TCP the test sets, has an extra."""

    def __init__(self):
        self.pose = np.array([0.4, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0])
        self.sent = []
        self.stops = 0
        self.extra = "driver's own attribute"

    def connect(self):
        pass

    def enable_velocity_mode(self):
        pass

    def send_velocity(self, v, duration_s):
        self.sent.append((np.asarray(v).copy(), duration_s))

    def stop(self):
        self.stops += 1

    def tcp_pose(self):
        return self.pose.copy()

    def close(self):
        self.stop()


def limited(**kw):
    clock = FakeClock(100.0)
    kw.setdefault("max_acc_m_s2", 1000.0)
    arm = RecordingArm()
    wrapped = LimitedArm(arm, ArmLimits(**kw), clock=clock, sleep=clock.sleep)
    wrapped.enable_velocity_mode()
    return wrapped, arm, clock


def test_any_arm_wrapped_is_an_arm_and_keeps_its_extras():
    wrapped, arm, _ = limited()
    assert isinstance(wrapped, Arm)
    assert wrapped.extra == arm.extra and wrapped.wrapped is arm


def test_speed_clipped_with_direction_kept_and_duration_capped():
    wrapped, arm, _ = limited(max_speed_m_s=0.05, max_duration_s=0.2)
    wrapped.send_velocity([0.3, 0.4, 0.0], 1.0)
    v, duration = arm.sent[-1]
    assert np.linalg.norm(v) == pytest.approx(0.05) and v[0] / v[1] == pytest.approx(0.75)
    assert duration == pytest.approx(0.2) and wrapped.commands_clipped == 1


def test_acceleration_limited_from_rest_but_a_stop_passes():
    wrapped, arm, clock = limited(max_speed_m_s=0.5, max_acc_m_s2=1.0, max_rate_hz=100.0)
    wrapped.send_velocity([0.1, 0, 0], 0.1)
    assert arm.sent[-1][0][0] == pytest.approx(0.01)
    clock.t += 0.01
    wrapped.send_velocity([0.0, 0, 0], 0.1)
    assert list(arm.sent[-1][0]) == [0.0, 0.0, 0.0]


def test_fast_commands_wait_for_the_rate_limit():
    wrapped, arm, clock = limited(max_rate_hz=100.0)
    for _ in range(3):
        wrapped.send_velocity([0.01, 0, 0], 0.1)
    assert wrapped.commands_delayed == 2 and clock.sleeps == pytest.approx([0.01, 0.01])


def test_workspace_clips_at_the_wall_and_outside_stops_and_raises():
    wrapped, arm, _ = limited()
    arm.pose[0] = 0.695                       # the box ends at x = 0.70
    wrapped.send_velocity([0.09, 0.02, 0.0], 0.1)
    assert arm.sent[-1][0][:2] == pytest.approx([0.05, 0.02])
    arm.pose[2] = 0.01                        # below the 2 cm floor
    n = len(arm.sent)
    with pytest.raises(ArmError, match="outside the workspace"):
        wrapped.send_velocity([0.01, 0, 0], 0.1)
    assert arm.stops == 1 and len(arm.sent) == n


@pytest.mark.parametrize("v, duration", [([np.nan, 0, 0], 0.1), ([0.01, 0, 0], 0.0),
                                         ([0.01, 0, 0], float("inf")), ([0.01, 0], 0.1)])
def test_invalid_requests_stop_and_raise(v, duration):
    wrapped, arm, _ = limited()
    with pytest.raises(ArmError, match="refused"):
        wrapped.send_velocity(v, duration)
    assert arm.stops == 1 and arm.sent == []


def test_limits_are_validated():
    with pytest.raises(ValueError):
        ArmLimits(max_speed_m_s=0.0)
    with pytest.raises(ValueError):
        ArmLimits(workspace_min_m=(0.5, 0, 0), workspace_max_m=(0.4, 1, 1))
