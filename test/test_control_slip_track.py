"""Slip-track: shaping (deadband, saturation, low-pass), frame mapping, hold, staleness."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros.control.slip_track import (SlipTrack, SlipTrackConfig, TrackState,
                                          shape_slip)

DT = 0.01
LEVEL = [0.4, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0]    # TCP axes aligned with link_base


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def make(**kw):
    clock = Clock()
    kw.setdefault('hold_s', 0.05)
    ctl = SlipTrack(SlipTrackConfig(**kw), clock)
    ctl.on_tcp_pose(LEVEL)
    ctl.on_slip((0.0, 0.0), False)
    ctl.start()
    return ctl, clock


def tick(ctl, clock, slip, slipping=None, pose=LEVEL):
    clock.t += DT
    if pose is not None:
        ctl.on_tcp_pose(pose)
    if slip is not None:
        ctl.on_slip(slip, slipping)
    return ctl.step()


def test_shape_deadband_and_saturation_keep_direction():
    assert np.all(shape_slip((0.001, 0.001), 1.0, 0.002, 0.05) == 0)
    v = shape_slip((0.03, 0.04), 2.0, 0.002, 0.05)       # 0.1 m/s -> saturated to 0.05
    assert np.linalg.norm(v) == pytest.approx(0.05)
    assert v[1] == 0.0
    assert v[0] / v[2] == pytest.approx(0.75)
    assert np.allclose(shape_slip((0.01, 0.0), 1.5, 0.002, 0.05), [0.015, 0, 0])


def test_tracks_slip_in_identity_frame():
    ctl, clock = make(gain=1.0)
    cmd = tick(ctl, clock, (0.01, -0.02), True)
    assert ctl.state is TrackState.TRACKING
    assert np.allclose(cmd.velocity, [0.01, 0.0, -0.02])
    assert cmd.duration_s == pytest.approx(0.1) and not cmd.stop


def test_frame_mapping_through_tcp_pose_and_calibration():
    # TCP yawed 90 deg about base z; calibration rotates the grasp plane 90 deg about TCP x.
    tcp_rot = Rotation.from_euler('z', 90, degrees=True)
    calib_rot = Rotation.from_euler('x', 90, degrees=True)
    tcp = np.concatenate([[0.3, 0.1, 0.2], tcp_rot.as_quat()])
    calib = np.concatenate([[0.0, 0.0, 0.1], calib_rot.as_quat()])
    ctl, clock = make(grasp_plane_in_tcp=tuple(calib))
    cmd = tick(ctl, clock, (0.01, 0.02), True, pose=tcp)
    expected = (tcp_rot * calib_rot).apply([0.01, 0.0, 0.02])
    assert np.allclose(cmd.velocity, expected)
    # Spelled out: grasp x -> tcp x -> base y; grasp z -> tcp -y -> base +x.
    assert np.allclose(cmd.velocity, [0.02, 0.01, 0.0])


def test_deadband_means_no_motion():
    ctl, clock = make(deadband_m_s=0.005)
    cmd = tick(ctl, clock, (0.001, 0.002))       # decision derived from deadband
    assert cmd is None
    assert ctl.state is TrackState.WAITING


def test_slip_end_holds_zero_then_waits_then_resumes():
    ctl, clock = make(hold_s=0.05)
    tick(ctl, clock, (0.02, 0.0), True)
    cmds = [tick(ctl, clock, (0.0, 0.0), False) for _ in range(10)]
    holding = [c for c in cmds if c is not None]
    assert 4 <= len(holding) <= 6
    assert all(np.all(c.velocity == 0) and not c.stop for c in holding)
    assert cmds[-1] is None and ctl.state is TrackState.WAITING
    cmd = tick(ctl, clock, (0.0, 0.02), True)
    assert np.allclose(cmd.velocity, [0, 0, 0.02])


def test_stop_on_slip_end_latches():
    ctl, clock = make(hold_s=0.02, stop_on_slip_end=True)
    tick(ctl, clock, (0.02, 0.0), True)
    cmds = [tick(ctl, clock, (0.0, 0.0), False) for _ in range(6)]
    halts = [c for c in cmds if c is not None and c.stop]
    assert len(halts) == 1 and 'slip ended' in halts[0].reason
    assert ctl.state is TrackState.STOPPED
    assert tick(ctl, clock, (0.02, 0.0), True) is None
    with pytest.raises(RuntimeError):
        ctl.start()
    ctl.reset()
    ctl.start()
    assert tick(ctl, clock, (0.02, 0.0), True).velocity[0] == pytest.approx(0.02)


def test_stale_slip_stops_once_and_latches():
    ctl, clock = make()
    tick(ctl, clock, (0.02, 0.0), True)
    cmds = [tick(ctl, clock, None) for _ in range(15)]
    halts = [c for c in cmds if c is not None and c.stop]
    assert len(halts) == 1 and 'stale slip' in halts[0].reason
    # Moving commands before the watchdog fired are at most 100 ms worth.
    moving = [c for c in cmds[:cmds.index(halts[0])] if c is not None]
    assert len(moving) <= 10
    assert tick(ctl, clock, (0.02, 0.0), True) is None
    assert ctl.state is TrackState.STOPPED


def test_stale_pose_stops():
    ctl, clock = make()
    cmds = [tick(ctl, clock, (0.02, 0.0), True, pose=None) for _ in range(15)]
    assert any(c is not None and c.stop and 'stale pose' in c.reason for c in cmds)


def test_lowpass_converges_and_is_rate_independent():
    results = []
    for dt in (0.01, 0.005):
        clock = [0.0]
        ctl = SlipTrack(SlipTrackConfig(lowpass_tau_s=0.05), lambda: clock[0])
        ctl.on_tcp_pose(LEVEL)
        ctl.on_slip((0.02, 0.0), True)
        ctl.start()
        ctl.step()
        n = int(round(0.05 / dt))
        for _ in range(n):
            clock[0] += dt
            ctl.on_tcp_pose(LEVEL)
            ctl.on_slip((0.02, 0.0), True)
            cmd = ctl.step()
        results.append(cmd.velocity[0])
    # After one time constant: 1 - 1/e of the target, whatever the rate.
    assert results[0] == pytest.approx(0.02 * (1 - np.exp(-1)), rel=1e-6)
    assert results[1] == pytest.approx(results[0], rel=1e-6)


def test_nan_slip_rejected_and_does_not_feed_watchdog():
    ctl, clock = make()
    assert not ctl.on_slip((np.nan, 0.0), True)
    assert not ctl.on_slip((0.0, 0.0, 0.0), True)
    assert ctl.rejected_inputs == 2
    for _ in range(12):
        clock.t += DT
        ctl.on_tcp_pose(LEVEL)
        ctl.on_slip((np.inf, 0.0), True)
        cmd = ctl.step()
        assert cmd is None or cmd.stop or np.all(np.isfinite(cmd.velocity))
    assert ctl.state is TrackState.STOPPED


def test_fault_and_shutdown():
    ctl, clock = make()
    tick(ctl, clock, (0.02, 0.0), True)
    ctl.fault('ArmError')
    cmd = ctl.step()
    assert cmd.stop and 'ArmError' in cmd.reason
    ctl2, clock2 = make()
    ctl2.shutdown()
    assert ctl2.step().stop


def test_idle_sends_nothing():
    clock = Clock()
    ctl = SlipTrack(SlipTrackConfig(), clock)
    ctl.on_tcp_pose(LEVEL)
    ctl.on_slip((0.02, 0.0), True)
    assert ctl.step() is None


@pytest.mark.parametrize('kwargs', [
    dict(gain=0.0), dict(gain=float('nan')), dict(deadband_m_s=-0.1),
    dict(max_speed_m_s=0.0), dict(lowpass_tau_s=-1.0), dict(hold_s=float('inf')),
    dict(grasp_plane_in_tcp=(0, 0, 0, 0, 0, 0, 0)), dict(grasp_plane_in_tcp=(0, 0, 0)),
    dict(slip_timeout_s=0.0), dict(command_duration_s=-0.1),
])
def test_bad_config_rejected(kwargs):
    with pytest.raises(ValueError):
        SlipTrackConfig(**kwargs)
