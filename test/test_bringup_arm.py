"""aslip check arm against a fake XArmAPI whose TCP follows the velocity commands: the 1 cm
test move within the speed limit and back, and every refusal before anything moves."""

import io

import numpy as np
import pytest

from aslip_ros.bringup.arm_check import arm_config, check_arm
from aslip_ros.hw.xarm_config import XArmConfig
from fake_clock import FakeClock
from test_hw_xarm import FakeXArmAPI

IP = '192.168.1.10'


class MovingXArmAPI(FakeXArmAPI):
    """The TCP moves at the commanded Cartesian velocity for the command's duration."""

    def __init__(self, clock, position_mm=(400.0, 0.0, 300.0)):
        super().__init__(IP, position_mm=position_mm)
        self.clock = clock
        self._v = np.zeros(3)
        self._until = self._t = clock()

    def _advance(self):
        now = self.clock()
        end = min(now, self._until)
        if end > self._t:
            self.position[:3] = list(np.asarray(self.position[:3]) + self._v * (end - self._t))
        self._t = now

    def vc_set_cartesian_velocity(self, speeds, is_radian=None, is_tool_coord=False,
                                  duration=-1, **kwargs):
        self._advance()
        self._v = np.asarray(speeds[:3], dtype=float)
        self._until = self.clock() + duration
        return super().vc_set_cartesian_velocity(speeds, is_radian, is_tool_coord, duration)

    def set_state(self, state=0):
        self._advance()
        if state == 4:
            self._v = np.zeros(3)
        return super().set_state(state)

    def get_position(self, is_radian=None):
        self._advance()
        return super().get_position(is_radian)


def run(position_mm=(400.0, 0.0, 300.0), answer=True, speed=0.01, **cfg):
    clock = FakeClock(100.0)
    api = MovingXArmAPI(clock, position_mm)
    out = io.StringIO()
    questions = []

    def confirm(q):
        questions.append(q)
        return answer

    config = XArmConfig(ip=IP, mode_settle_s=0.0, **cfg)
    rc = check_arm(config, speed, 0.01, None, out, confirm, api_factory=lambda ip: api,
                   clock=clock, sleep=clock.sleep)
    return rc, api, out.getvalue(), questions


def _speeds_mm_s(api):
    return [np.asarray(args[0][:3]) for _, args, _ in api.velocity_calls()]


def test_one_centimetre_up_and_back_within_the_speed_limit():
    rc, api, out, questions = run()
    assert rc == 0, out
    assert questions == ['move the TCP 1 cm along +z at 1 cm/s and back?']
    speeds = _speeds_mm_s(api)
    assert max(np.linalg.norm(s) for s in speeds) <= 10.0 + 1e-9
    moving = [s for s in speeds if np.any(s)]
    assert all(s[0] == 0 and s[1] == 0 for s in moving)
    signs = [np.sign(s[2]) for s in moving]
    n_up = signs.count(1.0)
    assert n_up > 0 and signs == [1.0] * n_up + [-1.0] * (len(signs) - n_up)  # out, then back
    for _, args, kwargs in api.velocity_calls():
        if any(args[0]):
            assert 0.0 < kwargs['duration'] <= 0.1 + 1e-9
    assert api.position[2] == pytest.approx(300.0, abs=0.5)
    assert 'out: moved 10.' in out or 'out: moved 9.9' in out
    assert out.rstrip().endswith('verdict: OK')
    assert api.names()[-3:] == ['vc_set_cartesian_velocity', 'set_state', 'disconnect']


def test_tcp_outside_the_workspace_fails_and_nothing_moves():
    rc, api, out, questions = run(position_mm=(100.0, 0.0, 300.0))     # x below 0.15 m
    assert rc == 1
    assert 'verdict: FAIL: the TCP [0.1, 0.0, 0.3] m is outside the workspace' in out
    assert not questions
    assert not any(np.any(s) for s in _speeds_mm_s(api))
    assert 'set_mode' not in api.names() and 'motion_enable' not in api.names()
    assert ('set_state', (4,), {}) in api.calls          # stopped all the same


def test_no_room_up_moves_down_and_no_room_at_all_refuses():
    top = XArmConfig(ip=IP).workspace_max_m[2] * 1000.0 - 8.0       # 8 mm below the top
    rc, api, out, questions = run(position_mm=(400.0, 0.0, top))
    assert rc == 0, out
    assert questions == ['move the TCP 1 cm along -z at 1 cm/s and back?']
    tight = dict(workspace_min_m=(0.395, -0.005, 0.295), workspace_max_m=(0.405, 0.005, 0.305))
    rc, api, out, _ = run(position_mm=(400.0, 0.0, 300.0), **tight)
    assert rc == 1 and 'would leave the workspace' in out
    assert not any(np.any(s) for s in _speeds_mm_s(api))


def test_unconfirmed_or_too_fast_moves_nothing():
    rc, api, out, _ = run(answer=False)
    assert rc == 1 and 'verdict: FAIL: not confirmed; nothing moved' in out
    assert not any(np.any(s) for s in _speeds_mm_s(api))
    rc, api, out, questions = run(speed=0.2)
    assert rc == 1 and 'above the arm\'s limit' in out and not questions
    assert not any(np.any(s) for s in _speeds_mm_s(api))


def test_a_move_that_falls_short_fails():
    clock = FakeClock(100.0)
    api = MovingXArmAPI(clock)
    original = api.vc_set_cartesian_velocity

    def half(speeds, **kwargs):          # an arm at a 50 % speed override
        return original([v / 2 for v in speeds], **kwargs)

    api.vc_set_cartesian_velocity = half
    out = io.StringIO()
    rc = check_arm(XArmConfig(ip=IP, mode_settle_s=0.0), 0.01, 0.01, None, out,
                   lambda q: True, api_factory=lambda ip: api, clock=clock, sleep=clock.sleep)
    assert rc == 1
    assert 'verdict: FAIL: the out move measured 4.9 mm, not 10.0 +- 3 mm' in out.getvalue()
    assert ('set_state', (4,), {}) in api.calls


def test_config_defaults_are_the_adapters_own():
    assert arm_config(IP) == XArmConfig(ip=IP)
    cfg = arm_config(IP, 0.05, (0.2, -0.1, 0.1), (0.5, 0.1, 0.4))
    assert (cfg.max_speed_m_s, cfg.workspace_min_m, cfg.workspace_max_m) == \
        (0.05, (0.2, -0.1, 0.1), (0.5, 0.1, 0.4))


def _parsed(*argv):
    import argparse

    from aslip_ros.bringup import check
    parser = argparse.ArgumentParser()
    check.add_arguments(parser)
    return check, parser.parse_args(['arm', *argv])


def test_setup_file_gives_the_arm_section_and_flags_override_it(tmp_path):
    pytest.importorskip('aslip_ros.cell')
    path = tmp_path / 'cell.yaml'
    path.write_text('arm:\n  xarm_ip: 10.0.0.7\n  arm_max_speed_m_s: 0.05\n'
                    '  arm_workspace_min_m: [0.2, -0.2, 0.1]\n'
                    '  arm_workspace_max_m: [0.6, 0.2, 0.5]\n')
    check, args = _parsed('--setup', str(path))
    cfg = check._arm_config(args)
    assert (cfg.ip, cfg.max_speed_m_s, cfg.workspace_min_m, cfg.workspace_max_m) == \
        ('10.0.0.7', 0.05, (0.2, -0.2, 0.1), (0.6, 0.2, 0.5))
    check, args = _parsed('--setup', str(path), '--ip', '10.0.0.9', '--max-speed', '0.02')
    cfg = check._arm_config(args)
    assert (cfg.ip, cfg.max_speed_m_s) == ('10.0.0.9', 0.02)
    assert cfg.workspace_max_m == (0.6, 0.2, 0.5)


def test_no_ip_anywhere_is_refused():
    check, args = _parsed()
    with pytest.raises(ValueError, match='--ip is needed'):
        check._arm_config(args)
