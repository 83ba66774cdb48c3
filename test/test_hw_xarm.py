"""xArm adapter against a fake XArmAPI: calls, codes, limits, workspace, unreachable arm."""

import math
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from aslip_ros.arm import Arm, ArmError
from aslip_ros.hw.xarm import (MODE_CARTESIAN_VELOCITY, STATE_STOP, XArmAdapter, XArmConfig,
                               XArmError, describe_code)
from fake_clock import FakeClock

ROOT = Path(__file__).resolve().parents[1]


class FakeXArmAPI:
    """Records calls; return codes can be overridden per method."""

    def __init__(self, ip, position_mm=(400.0, 0.0, 300.0), rpy=(math.pi, 0.0, 0.0)):
        self.ip = ip
        self.connected = False
        self.version_number = (2, 3, 0)
        self.calls = []
        self.codes = {}
        self.position = list(position_mm) + list(rpy)
        self.err_warn = [0, 0]
        self.connect_error = None
        self.connect_delay = 0.0

    def _rec(self, name, *args, **kwargs):
        self.calls.append((name, args, kwargs))
        return self.codes.get(name, 0)

    def connect(self):
        self.calls.append(('connect', (), {}))
        if self.connect_delay:
            time.sleep(self.connect_delay)
        if self.connect_error:
            raise self.connect_error
        self.connected = True

    def disconnect(self):
        self.calls.append(('disconnect', (), {}))
        self.connected = False

    def motion_enable(self, enable=True, servo_id=None):
        return self._rec('motion_enable', enable=enable)

    def set_mode(self, mode=0, detection_param=0):
        return self._rec('set_mode', mode)

    def set_state(self, state=0):
        return self._rec('set_state', state)

    def vc_set_cartesian_velocity(self, speeds, is_radian=None, is_tool_coord=False,
                                  duration=-1, **kwargs):
        return self._rec('vc_set_cartesian_velocity', list(speeds), is_radian=is_radian,
                         is_tool_coord=is_tool_coord, duration=duration)

    def get_position(self, is_radian=None):
        code = self._rec('get_position', is_radian=is_radian)
        return code, list(self.position)

    def get_err_warn_code(self, show=False, lang='en'):
        code = self._rec('get_err_warn_code')
        return code, list(self.err_warn)

    def clean_warn(self):
        self.err_warn[1] = 0
        return self._rec('clean_warn')

    def names(self):
        return [c[0] for c in self.calls]

    def velocity_calls(self):
        return [c for c in self.calls if c[0] == 'vc_set_cartesian_velocity']


class StreamingXArmAPI(FakeXArmAPI):
    """Also has the SDK's report stream; the test calls ``report`` to deliver a pose."""

    def __init__(self, ip, **kwargs):
        super().__init__(ip, **kwargs)
        self.report_cb = None

    def register_report_location_callback(self, callback=None, report_cartesian=True,
                                          report_joints=True):
        self.report_cb = callback
        return True

    def release_report_location_callback(self, callback=None):
        self.report_cb = None
        return True

    def report(self, position_mm=None, rpy=(math.pi, 0.0, 0.0)):
        pose = list(position_mm or self.position[:3]) + list(rpy)
        self.report_cb({'cartesian': pose})


def make(api=None, **cfg):
    clock = FakeClock(100.0)
    api = api or FakeXArmAPI('192.168.1.10')
    cfg.setdefault('ip', '192.168.1.10')
    cfg.setdefault('mode_settle_s', 0.0)
    arm = XArmAdapter(XArmConfig(**cfg), api_factory=lambda ip: api, clock=clock,
                      sleep=clock.sleep)
    return arm, api, clock


def connected(**cfg):
    arm, api, clock = make(**cfg)
    arm.connect()
    arm.enable_velocity_mode()
    return arm, api, clock


def test_satisfies_arm_protocol():
    arm, _, _ = make()
    assert isinstance(arm, Arm)


def test_connect_and_enable_sequence():
    arm, api, _ = connected()
    assert api.names()[:6] == ['connect', 'get_err_warn_code', 'motion_enable', 'set_mode',
                               'set_state', 'get_err_warn_code']
    assert api.calls[3][1] == (MODE_CARTESIAN_VELOCITY,)
    assert api.calls[4][1] == (0,)
    assert arm.velocity_mode_enabled


def test_send_velocity_units_frame_and_duration():
    arm, api, _ = connected(max_acc_m_s2=1000.0)
    arm.send_velocity(np.array([0.01, -0.02, 0.005]), 0.1)
    (name, args, kwargs), = api.velocity_calls()
    assert args[0] == pytest.approx([10.0, -20.0, 5.0, 0.0, 0.0, 0.0])
    assert kwargs == dict(is_radian=True, is_tool_coord=False, duration=0.1)


def test_duration_always_set_and_capped():
    arm, api, clock = connected(max_duration_s=0.2)
    arm.send_velocity([0.01, 0, 0], 5.0)
    for bad in (0.0, -1.0, float('nan'), float('inf')):
        arm.enable_velocity_mode()
        clock.t += 1.0
        with pytest.raises(XArmError):
            arm.send_velocity([0.01, 0, 0], bad)
    for _, _, kwargs in api.velocity_calls():
        assert 0.0 < kwargs['duration'] <= 0.2
    assert api.velocity_calls()[0][2]['duration'] == pytest.approx(0.2)


def test_non_zero_code_stops_and_raises_with_meaning():
    arm, api, _ = connected()
    api.codes['vc_set_cartesian_velocity'] = 9
    with pytest.raises(XArmError) as info:
        arm.send_velocity([0.01, 0, 0], 0.1)
    assert info.value.code == 9
    assert 'not ready' in str(info.value)
    assert isinstance(info.value, ArmError)
    assert ('set_state', (STATE_STOP,), {}) in api.calls
    assert not arm.velocity_mode_enabled
    with pytest.raises(XArmError):      # needs re-enabling after a stop
        arm.send_velocity([0.01, 0, 0], 0.1)


def test_controller_error_code_is_reported():
    arm, api, _ = connected()
    api.codes['get_position'] = 1
    api.err_warn = [22, 0]
    with pytest.raises(XArmError) as info:
        arm.send_velocity([0.01, 0, 0], 0.1)
    assert info.value.controller_error == 22
    assert 'controller error 22' in str(info.value)


def test_enable_refused_when_controller_holds_an_error():
    arm, api, _ = make()
    arm.connect()
    api.err_warn = [11, 0]
    with pytest.raises(XArmError) as info:
        arm.enable_velocity_mode()
    assert info.value.controller_error == 11
    assert not arm.velocity_mode_enabled


def test_enable_failure_raises():
    arm, api, _ = make()
    arm.connect()
    api.codes['set_mode'] = -2
    with pytest.raises(XArmError) as info:
        arm.enable_velocity_mode()
    assert info.value.code == -2


def test_speed_clipped_direction_kept():
    arm, api, clock = connected(max_speed_m_s=0.05, max_acc_m_s2=1000.0)
    arm.send_velocity([0.3, 0.4, 0.0], 0.1)
    speeds = np.array(api.velocity_calls()[0][1][0][:3]) / 1000.0
    assert np.linalg.norm(speeds) == pytest.approx(0.05)
    assert speeds[0] / speeds[1] == pytest.approx(0.75)
    assert arm.commands_clipped == 1


def test_acceleration_limited_but_stop_not_delayed():
    arm, api, clock = connected(max_speed_m_s=0.5, max_acc_m_s2=1.0, max_rate_hz=100.0)
    arm.send_velocity([0.1, 0, 0], 0.1)           # from rest: at most 1 m/s^2 * 10 ms
    first = api.velocity_calls()[-1][1][0][0] / 1000.0
    assert first == pytest.approx(0.01)
    clock.t += 0.01
    arm.send_velocity([0.1, 0, 0], 0.1)
    assert api.velocity_calls()[-1][1][0][0] / 1000.0 == pytest.approx(0.02)
    clock.t += 0.01
    arm.send_velocity([0.0, 0, 0], 0.1)           # zero passes unlimited
    assert api.velocity_calls()[-1][1][0][:3] == [0.0, 0.0, 0.0]


def test_rate_limit_delays_fast_commands():
    arm, api, clock = connected(max_rate_hz=200.0, max_acc_m_s2=1000.0)
    for _ in range(5):
        arm.send_velocity([0.01, 0, 0], 0.1)      # back to back, no time passing
    assert arm.commands_delayed == 4
    assert all(s == pytest.approx(0.005) for s in clock.sleeps)
    assert len(api.velocity_calls()) == 5


def test_rate_above_controller_limit_rejected():
    with pytest.raises(ValueError):
        XArmConfig(ip='1.2.3.4', max_rate_hz=300.0)


def test_workspace_clips_component_at_the_wall():
    # TCP at x = 0.695 m, box ends at 0.70: in 0.1 s at most 0.05 m/s towards the wall.
    api = FakeXArmAPI('x', position_mm=(695.0, 0.0, 300.0))
    arm, api, _ = connected(api=api, max_acc_m_s2=1000.0)
    arm.send_velocity([0.09, 0.02, 0.0], 0.1)
    v = np.array(api.velocity_calls()[0][1][0][:3]) / 1000.0
    assert v[0] == pytest.approx(0.05)
    assert v[1] == pytest.approx(0.02)


def test_leaving_workspace_stops_and_raises():
    arm, api, _ = connected()
    api.position[2] = 10.0        # z = 1 cm, below the 2 cm floor
    with pytest.raises(XArmError) as info:
        arm.send_velocity([0.01, 0, 0], 0.1)
    assert 'outside the workspace' in str(info.value)
    assert ('set_state', (STATE_STOP,), {}) in api.calls
    assert api.velocity_calls()[-1][1][0] == [0.0] * 6


def test_non_finite_velocity_refused():
    arm, api, _ = connected()
    with pytest.raises(XArmError):
        arm.send_velocity([np.nan, 0, 0], 0.1)
    assert all(c[1][0] == [0.0] * 6 for c in api.velocity_calls())


def test_tcp_pose_in_metres_and_quaternion():
    arm, api, _ = connected()
    pose = arm.tcp_pose()
    assert pose[:3] == pytest.approx([0.4, 0.0, 0.3])
    # roll = pi: gripper pointing down, quaternion (1, 0, 0, 0) up to sign.
    assert abs(pose[3]) == pytest.approx(1.0)


def test_stop_is_safe_anytime():
    arm, api, _ = make()
    arm.stop()                       # never connected: no-op
    arm.connect()
    arm.stop()
    api.codes['vc_set_cartesian_velocity'] = 9
    arm.stop()                       # one way accepted is enough
    api.codes['set_state'] = 1
    arm.stop()                       # controller error: already halted
    api.codes['set_state'] = 3
    with pytest.raises(XArmError):
        arm.stop()                   # no way accepted: the caller must know
    arm.close()
    arm.close()
    assert api.names().count('disconnect') == 1


def test_unreachable_arm_raises_quickly():
    api = FakeXArmAPI('x')
    api.connect_error = Exception('connect socket failed')
    arm, _, _ = make(api=api)
    with pytest.raises(XArmError) as info:
        arm.connect()
    assert 'connect socket failed' in str(info.value)
    assert not arm.connected
    arm.stop()                        # still safe
    with pytest.raises(XArmError):
        arm.send_velocity([0.01, 0, 0], 0.1)


def test_hanging_connect_times_out():
    api = FakeXArmAPI('x')
    api.connect_delay = 0.5
    arm, _, _ = make(api=api, connect_timeout_s=0.1)
    t0 = time.monotonic()
    with pytest.raises(XArmError) as info:
        arm.connect()
    assert time.monotonic() - t0 < 0.4
    assert 'did not answer' in str(info.value)
    assert not arm.connected
    # The late connection is torn down by the abandoned worker, not leaked.
    deadline = time.monotonic() + 3.0
    while 'disconnect' not in api.names() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert 'disconnect' in api.names() and not api.connected


def test_old_firmware_refused():
    api = FakeXArmAPI('x')
    api.version_number = (1, 7, 9)
    arm, _, _ = make(api=api)
    with pytest.raises(XArmError) as info:
        arm.connect()
    assert 'duration' in str(info.value)
    assert 'disconnect' in api.names()


def test_arm_in_error_state_refused_at_connect():
    api = FakeXArmAPI('x')
    api.err_warn = [31, 0]
    arm, _, _ = make(api=api)
    with pytest.raises(XArmError) as info:
        arm.connect()
    assert info.value.controller_error == 31


def test_factory_failure_is_arm_error():
    def boom(ip):
        raise OSError('no sdk')
    arm = XArmAdapter(XArmConfig(ip='1.2.3.4'), api_factory=boom)
    with pytest.raises(ArmError):
        arm.connect()


def test_concurrent_stop_and_send_do_not_interleave():
    arm, api, _ = connected(max_acc_m_s2=1000.0)
    errors = []

    def sender():
        for _ in range(200):
            try:
                arm.send_velocity([0.01, 0, 0], 0.1)
            except XArmError:
                try:
                    arm.enable_velocity_mode()
                except XArmError as exc:
                    errors.append(exc)

    t = threading.Thread(target=sender)
    t.start()
    for _ in range(50):
        arm.stop()
    t.join()
    assert not errors


@pytest.mark.parametrize('kwargs', [
    dict(ip=''), dict(ip='1.2.3.4', max_speed_m_s=0.0), dict(ip='1.2.3.4', max_acc_m_s2=-1),
    dict(ip='1.2.3.4', workspace_min_m=(0, 0, 0), workspace_max_m=(1, 1, 0)),
    dict(ip='1.2.3.4', workspace_min_m=(0, 0, np.nan)),
    dict(ip='1.2.3.4', connect_timeout_s=float('inf')),
])
def test_bad_config_rejected(kwargs):
    with pytest.raises(ValueError):
        XArmConfig(**kwargs)


def test_describe_code():
    assert describe_code(-9) == 'emergency stop'
    assert describe_code(12345) == 'unknown code'


def test_real_sdk_unreachable_arm_is_contained(tmp_path):
    """The real SDK, a closed port on localhost: ArmError, no stdout noise, timeout restored.

    Runs in a child process so the SDK's import-time print and socket default are observed
    on a clean interpreter.
    """
    pytest.importorskip('xarm')
    code = (
        'import socket, sys\n'
        'from aslip_ros.hw.xarm import XArmAdapter, XArmConfig\n'
        'from aslip_ros.arm import ArmError\n'
        'arm = XArmAdapter(XArmConfig(ip="127.0.0.1", connect_timeout_s=5.0))\n'
        'try:\n'
        '    arm.connect()\n'
        'except ArmError as exc:\n'
        '    sys.stderr.write("ARMERROR %s\\n" % exc)\n'
        'sys.stderr.write("TIMEOUT %r\\n" % socket.getdefaulttimeout())\n'
        'arm.stop()\n'
    )
    t0 = time.monotonic()
    # HOME in tmp_path: the SDK creates ~/.UFACTORY/log at import.
    env = dict(os.environ, HOME=str(tmp_path), PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=30, env=env, cwd=str(ROOT))
    assert proc.returncode == 0, proc.stderr
    assert time.monotonic() - t0 < 15.0
    assert 'ARMERROR' in proc.stderr
    assert 'TIMEOUT None' in proc.stderr
    assert proc.stdout == ''         # no version banner, no SDK log lines on stdout
    assert socket.getdefaulttimeout() is None


class IntegratingXArmAPI(FakeXArmAPI):
    """A fake that moves its TCP by the commanded velocity (mm/s) for the command duration."""

    def __init__(self, clock, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.clock = clock
        self.v_mm = np.zeros(3)
        self.until = -1.0
        self.t_last = clock()

    def _advance(self):
        now = self.clock()
        active = max(0.0, min(now, self.until) - self.t_last)
        self.position[:3] = list(np.array(self.position[:3]) + self.v_mm * active)
        self.t_last = now

    def vc_set_cartesian_velocity(self, speeds, is_radian=None, is_tool_coord=False,
                                  duration=-1, **kwargs):
        self._advance()
        self.v_mm = np.array(speeds[:3], dtype=float)
        self.until = self.clock() + duration
        return super().vc_set_cartesian_velocity(speeds, is_radian, is_tool_coord, duration)

    def set_state(self, state=0):
        self._advance()
        if state == STATE_STOP:
            self.v_mm = np.zeros(3)
        return super().set_state(state)

    def get_position(self, is_radian=None):
        self._advance()
        return super().get_position(is_radian)


def test_slip_stop_trial_through_the_adapter():
    """Controller + adapter: mm/m conversion, limits and stop compose into a full trial."""
    from aslip_ros.control.command import apply_command
    from aslip_ros.control.slip_stop import SlipStop, SlipStopConfig, StopReason

    clock = FakeClock(100.0)
    api = IntegratingXArmAPI(clock, 'x', position_mm=(400.0, 0.0, 300.0))
    arm = XArmAdapter(XArmConfig(ip='x', mode_settle_s=0.0, max_acc_m_s2=2.0),
                      api_factory=lambda ip: api, clock=clock, sleep=clock.sleep)
    arm.connect()
    arm.enable_velocity_mode()
    task = SlipStop(SlipStopConfig(direction=(1, 0, 0), approach_speed_m_s=0.05,
                                   retract_speed_m_s=0.1, settle_s=0.1), clock)
    wall_x = 0.4
    task.on_tcp_pose(arm.tcp_pose())
    task.on_slip(False)
    task.start()
    for _ in range(1000):
        clock.t += 0.01
        pose = arm.tcp_pose()
        task.on_tcp_pose(pose)
        task.on_slip(bool(pose[0] > wall_x + 0.003))
        apply_command(arm, task.step())
        if task.state.value == 'stopped':
            break
    assert task.reason is StopReason.SLIP
    res = task.result()
    assert 0.003 < res.stopping_distance_m < 0.01
    assert not arm.velocity_mode_enabled          # arm.stop() went through
    assert all(c[2]['duration'] > 0 for c in api.velocity_calls())


def test_every_sdk_code_has_a_meaning():
    for code in (-10, -11, -12, 20, 21, 22, 23, 31, 32, 33, 34, 41, 100, 101, 102, 103):
        assert describe_code(code) != 'unknown code', code


def test_controller_warning_while_streaming_stops_and_raises():
    arm, api, clock = connected(status_period_s=0.1)
    arm.send_velocity([0.01, 0, 0], 0.1)
    # The SDK maps a warning to code 0 on motion commands, so only asking reveals it.
    api.err_warn = [0, 14]
    clock.t += 0.2
    with pytest.raises(XArmError) as info:
        arm.send_velocity([0.01, 0, 0], 0.1)
    assert info.value.controller_warning == 14
    assert 'controller warning 14' in str(info.value)
    assert ('set_state', (STATE_STOP,), {}) in api.calls
    assert not arm.velocity_mode_enabled


def test_left_over_warning_is_cleared_before_motion_not_refused():
    arm, api, _ = make()
    api.err_warn = [0, 11]
    arm.connect()
    arm.enable_velocity_mode()
    assert 'clean_warn' in api.names() and api.err_warn[1] == 0
    assert arm.velocity_mode_enabled


def test_report_stream_pose_replaces_the_round_trips():
    api = StreamingXArmAPI('192.168.1.10')
    arm, api, clock = connected(api=api, report_max_age_s=0.05)
    seen = []
    assert arm.set_pose_listener(lambda pose, t, ns: seen.append((pose, t, ns))) is True
    api.report([410.0, 5.0, 300.0])
    assert len(seen) == 1 and seen[0][1] == clock.t
    assert seen[0][0][:3] == pytest.approx([0.41, 0.005, 0.3])
    api.calls.clear()
    assert arm.tcp_pose()[:3] == pytest.approx([0.41, 0.005, 0.3])
    arm.send_velocity([0.01, 0, 0], 0.1)
    # One round trip per command: the velocity itself; the pose came from the stream.
    assert api.names() == ['vc_set_cartesian_velocity']
    clock.t += 0.2                      # the stream went quiet: ask the arm again
    api.calls.clear()
    arm.tcp_pose()
    assert api.names() == ['get_position']
    api.report_cb({'cartesian': [float('nan')] * 6})
    assert arm.reports_rejected == 1 and len(seen) == 1
    arm.close()
    assert api.report_cb is None
