"""Slip labels against analytically known motions (aslip_ros.data.labels)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros.data import labels as L


def pose(xyz, euler_deg):
    return np.concatenate([xyz, Rotation.from_euler("xyz", euler_deg, degrees=True).as_quat()])


FINGER = pose([0.4, -0.1, 0.3], [25.0, -35.0, 110.0])
CALIB = pose([0.01, 0.015, -0.02], [0.0, 90.0, 0.0])


def inv(p):
    r = Rotation.from_quat(p[3:]).inv()
    return np.concatenate([-r.apply(p[:3]), r.as_quat()])


def external_tracks(v_grasp, rate=120.0, duration=2.0, finger_vel=(0.0, 0.0, 0.0),
                    finger_spin_deg_s=0.0, drop=()):
    """Finger at FINGER (optionally moving/spinning), object slipping at v_grasp in G."""
    t = np.arange(0.0, duration + 1e-9, 1.0 / rate)
    keep = np.ones(t.size, bool)
    for a, b in drop:
        keep &= ~((t >= a) & (t < b))
    t = t[keep]
    fp, op = [], []
    for ti in t:
        spin = Rotation.from_euler("z", finger_spin_deg_s * ti, degrees=True)
        f = FINGER.copy()
        f[:3] += np.asarray(finger_vel) * ti
        f[3:] = (spin * Rotation.from_quat(FINGER[3:])).as_quat()
        g = L.compose(f, CALIB)
        o = g[:3] + Rotation.from_quat(g[3:]).apply(np.asarray(v_grasp) * ti)
        fp.append(f)
        op.append(np.concatenate([o, [0, 0, 0, 1.0]]))
    return L.PoseTrack(t, fp, "finger"), L.PoseTrack(t, op, "object")


def windows(duration=2.0, w=0.2, hop=0.1):
    t0 = np.arange(0.0, duration - w + 1e-9, hop)
    return t0, t0 + w


def test_pure_x_slip_gives_vector_and_magnitude():
    f, o = external_tracks([0.03, 0.0, 0.0])
    t0, t1 = windows()
    lab = L.mocap_window_velocity(f, o, t0, t1, CALIB)
    assert lab.valid.all()
    np.testing.assert_allclose(lab.vx, 0.03, atol=1e-9)
    np.testing.assert_allclose(lab.vz, 0.0, atol=1e-9)
    np.testing.assert_allclose(lab.speed, 0.03, atol=1e-9)


def test_general_slip_moving_spinning_finger_and_y_dropped():
    v = np.array([0.02, 0.007, -0.015])
    # The finger translates and spins; relative slip in the grasp plane stays v.
    f, o = external_tracks(v, finger_vel=(0.1, -0.05, 0.02), finger_spin_deg_s=0.0)
    t0, t1 = windows()
    lab = L.mocap_window_velocity(f, o, t0, t1, CALIB)
    np.testing.assert_allclose(lab.velocity, np.tile(v, (t0.size, 1)), atol=1e-9)
    np.testing.assert_allclose(lab.speed, np.hypot(v[0], v[2]), atol=1e-9)


def test_spinning_finger_relative_velocity_in_rotating_frame():
    # Object fixed in the (rotating) grasp plane frame: no slip even though it moves in world.
    f, o = external_tracks([0.0, 0.0, 0.0], finger_spin_deg_s=45.0)
    lab = L.mocap_window_velocity(f, o, *windows(), CALIB)
    assert lab.valid.all()
    np.testing.assert_allclose(lab.speed, 0.0, atol=1e-9)


def test_calibration_matters():
    f, o = external_tracks([0.03, 0.0, 0.0])
    lab = L.mocap_window_velocity(f, o, *windows(), L.IDENTITY_POSE)
    # Without the 90 deg pitch calibration the slip appears along the finger's z axis.
    assert np.all(np.abs(lab.vx) < 1e-6)
    np.testing.assert_allclose(np.abs(lab.vz), 0.03, atol=1e-6)


def test_robot_state_labels_are_minus_tcp_velocity_in_grasp_plane():
    v_rel = np.array([-0.04, 0.0, 0.01])
    t = np.arange(0.0, 2.0 + 1e-9, 0.01)
    g0 = L.compose(FINGER, CALIB)
    rg = Rotation.from_quat(g0[3:])
    tcp = [L.compose(np.concatenate([g0[:3] - rg.apply(v_rel * ti), g0[3:]]), inv(CALIB))
           for ti in t]
    lab = L.robot_window_velocity(L.PoseTrack(t, tcp), *windows(), CALIB)
    assert lab.valid.all()
    np.testing.assert_allclose(lab.velocity, np.tile(v_rel, (lab.vx.size, 1)), atol=1e-9)


def test_pure_x_robot_sweep_with_rotated_tcp():
    # TCP pointing down (180 deg about x), moving +x in the world: the fixed probe moves
    # -x relative to the fingers, along the grasp plane's x axis.
    rot = Rotation.from_euler("x", 180, degrees=True).as_quat()
    t = np.arange(0.0, 1.0 + 1e-9, 0.004)
    tcp = [np.concatenate([[0.3 + 0.05 * ti, 0.0, 0.2], rot]) for ti in t]
    lab = L.robot_window_velocity(L.PoseTrack(t, tcp), [0.2], [0.4])
    np.testing.assert_allclose(lab.velocity[0], [-0.05, 0.0, 0.0], atol=1e-9)


def test_dropout_within_limit_is_interpolated():
    f, o = external_tracks([0.02, 0.0, 0.01], drop=[(0.51, 0.55)])   # ~40 ms gap
    lab = L.mocap_window_velocity(f, o, *windows(), CALIB, max_gap_s=0.05)
    assert lab.valid.all()
    np.testing.assert_allclose(lab.vx, 0.02, atol=1e-9)


def test_dropout_beyond_limit_drops_overlapping_windows_only():
    f, o = external_tracks([0.02, 0.0, 0.01], drop=[(0.51, 0.62)])   # ~120 ms gap
    t0, t1 = windows()
    lab = L.mocap_window_velocity(f, o, t0, t1, CALIB, max_gap_s=0.05)
    overlaps = (t0 < 0.625) & (t1 > 0.50)
    assert np.array_equal(lab.reason == L.GAP, overlaps)
    assert lab.valid[~overlaps].all()
    assert np.all(lab.velocity[~lab.valid] == 0)


def test_outside_span_is_coverage_not_extrapolated():
    f, o = external_tracks([0.02, 0.0, 0.0], duration=1.0)
    lab = L.mocap_window_velocity(f, o, [0.5, 0.9, -0.1], [0.7, 1.1, 0.1], CALIB)
    assert list(lab.reason) == [L.OK, L.COVERAGE, L.COVERAGE]


def test_bad_inputs():
    with pytest.raises(ValueError, match="7 finite"):
        L.as_pose([0, 0, 0, 1])
    with pytest.raises(ValueError, match="zero quaternion"):
        L.as_pose([0, 0, 0, 0, 0, 0, 0])
    with pytest.raises(ValueError, match="stamps"):
        L.PoseTrack([0.0, 1.0], np.zeros((3, 7)))
    f, o = external_tracks([0.0, 0, 0])
    with pytest.raises(ValueError, match="t1 > t0"):
        L.mocap_window_velocity(f, o, [0.5], [0.5])
    # Zero quaternions and duplicate stamps are cleaned, not fatal.
    tr = L.PoseTrack([0.0, 0.1, 0.1, 0.2], [[0, 0, 0, 0, 0, 0, 1], [0, 0, 0, 0, 0, 0, 0],
                                            [1, 0, 0, 0, 0, 0, 2], [2, 0, 0, 0, 0, 0, 1]])
    assert len(tr) == 3 and np.allclose(tr.quat[1], [0, 0, 0, 1])


def calibration_poses(n=200, pos_noise_m=0.0, rot_noise_deg=0.0, seed=3):
    """Finger poses all over the place, the object rigidly at CALIB's origin in the finger
    frame (any orientation); measured with the given position and finger-rotation noise."""
    rng = np.random.default_rng(seed)
    rot = Rotation.random(n, random_state=seed)
    f = np.concatenate([rng.uniform(-0.5, 0.5, (n, 3)), rot.as_quat()], axis=1)
    o = np.concatenate([L.compose(f, CALIB)[:, :3],
                        Rotation.random(n, random_state=seed + 1).as_quat()], axis=1)
    f[:, :3] += rng.normal(0.0, pos_noise_m, (n, 3))
    o[:, :3] += rng.normal(0.0, pos_noise_m, (n, 3))
    jitter = Rotation.from_rotvec(np.deg2rad(rng.normal(0.0, rot_noise_deg, (n, 3))))
    f[:, 3:] = (rot * jitter).as_quat()
    return f, o


def test_invert_is_the_inverse_pose():
    f, _ = calibration_poses(n=5)
    np.testing.assert_allclose(L.compose(L.invert(f), f)[:, :3], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(L.compose(f, L.invert(f))[:, 6]), 1.0, atol=1e-12)
    np.testing.assert_allclose(L.invert(L.invert(FINGER)), FINGER, atol=1e-12)


def test_measure_grasp_plane_recovers_the_object_offset():
    f, o = calibration_poses()
    np.testing.assert_allclose(L.measure_grasp_plane(f, o, CALIB[3:]), CALIB, atol=1e-12)
    # The orientation is taken as given (normalised), whatever the poses say.
    got = L.measure_grasp_plane(f, o, [0.0, 0.0, 0.0, 2.0])
    np.testing.assert_allclose(got, np.r_[CALIB[:3], 0, 0, 0, 1], atol=1e-12)
    # A world-frame difference would be metres off: the finger rotation is undone.
    assert np.linalg.norm(np.mean(o[:, :3] - f[:, :3], axis=0) - CALIB[:3]) > 0.01


def test_measure_grasp_plane_with_noisy_poses():
    # 0.5 mm position noise on both bodies and 0.2 deg on the finger's orientation.
    f, o = calibration_poses(pos_noise_m=5e-4, rot_noise_deg=0.2)
    got = L.measure_grasp_plane(f, o, CALIB[3:])
    np.testing.assert_allclose(got[:3], CALIB[:3], atol=2e-4)
    np.testing.assert_allclose(got[3:], CALIB[3:], atol=1e-12)
    assert np.linalg.norm(got[:3] - CALIB[:3]) > 1e-7       # the noise did reach it


def test_measure_grasp_plane_degenerate_input():
    f, o = calibration_poses(n=4)
    with pytest.raises(ValueError, match="at least 3 pose pairs, got 2"):
        L.measure_grasp_plane(f[:2], o[:2])
    with pytest.raises(ValueError, match="at least 10 pose pairs, got 4"):
        L.measure_grasp_plane(f, o, min_pairs=10)
    with pytest.raises(ValueError, match="at least 1 pose pairs, got 0"):
        L.measure_grasp_plane(np.zeros((0, 7)), np.zeros((0, 7)), min_pairs=0)
    with pytest.raises(ValueError, match=r"\(N, 7\)"):
        L.measure_grasp_plane(f, o[:3])
    with pytest.raises(ValueError, match=r"\(N, 7\)"):
        L.measure_grasp_plane(f[:, :3], o[:, :3])
    for body in (f, o):
        for bad in (np.nan, np.inf):
            saved = body[1, 2]
            body[1, 2] = bad
            with pytest.raises(ValueError, match="NaN or Inf"):
                L.measure_grasp_plane(f, o)
            body[1, 2] = saved
    o[2, 3:] = 0.0
    with pytest.raises(ValueError, match="zero quaternion"):
        L.measure_grasp_plane(f, o)
    f, o = calibration_poses(n=4)
    with pytest.raises(ValueError, match="zero quaternion"):
        L.measure_grasp_plane(f, o, [0.0, 0.0, 0.0, 0.0])
    assert np.isfinite(L.measure_grasp_plane(f, o)).all()
