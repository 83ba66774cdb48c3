"""Rotational slip labels (issue #21) against analytically known motions and the scene.

The label ``wy`` is the object's angular velocity relative to the finger about the pad
normal (+y of the grasp plane); the planar label is the velocity of the object's material
point at the pad centre, ``v_c = dr/dt - w x r``, which is today's ``dr/dt`` whenever the
object does not turn relative to the finger.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros import slip
from aslip_ros.data import labels as L
from aslip_ros.data import stream_labels as S
from aslip_ros.data.labels import DEFAULT_LABEL_SMOOTHING_S

FINGER = np.concatenate([[0.4, -0.1, 0.3],
                         Rotation.from_euler("xyz", [25.0, -35.0, 110.0],
                                             degrees=True).as_quat()])
CALIB = np.concatenate([[0.01, 0.015, -0.02],
                        Rotation.from_euler("xyz", [0.0, 90.0, 0.0], degrees=True).as_quat()])
#: The object's own orientation in the grasp plane at rest (its rigid body is not aligned).
Q_OBJ = Rotation.from_euler("xyz", [10.0, -20.0, 5.0], degrees=True)
RATE = 120.0
DURATION = 2.0


def ry(angle):
    return Rotation.from_rotvec(np.outer(np.atleast_1d(angle), [0.0, 1.0, 0.0]))


def finger_pose(t, moving=True):
    """The finger translates and tumbles in the world (all three axes) when ``moving``."""
    f = FINGER.copy()
    if moving:
        f[:3] += np.array([0.05, -0.02, 0.03]) * t + 0.01 * np.sin(3 * t)
        f[3:] = (Rotation.from_rotvec([0.3 * t, -0.2 * t, 0.5 * np.sin(t)])
                 * Rotation.from_quat(FINGER[3:])).as_quat()
    return f


def tracks(rel, t=None, moving=True):
    """Finger and object tracks for a relative motion ``rel(t) -> (r (3,), Q Rotation)``: the
    object's position and orientation in the grasp plane."""
    t = np.arange(0.0, DURATION + 1e-9, 1.0 / RATE) if t is None else t
    fp, op = [], []
    for ti in t:
        f = finger_pose(ti, moving)
        g = L.compose(f, CALIB)
        rg = Rotation.from_quat(g[3:])
        r, q = rel(ti)
        fp.append(f)
        op.append(np.concatenate([g[:3] + rg.apply(r), (rg * q).as_quat()]))
    return L.PoseTrack(t, fp, "finger"), L.PoseTrack(t, op, "object")


def windows(w=0.2, hop=0.1):
    t0 = np.arange(0.0, DURATION - w + 1e-9, hop)
    return t0, t0 + w


def labels(rel, moving=True, **kw):
    f, o = tracks(rel, moving=moving)
    lab = L.mocap_window_velocity(f, o, *windows(), CALIB, **kw)
    assert lab.valid.all()
    return lab


# --------------------------------------------------------------------------- the quantity

def test_constants_are_the_planar_threshold_at_the_reference_radius():
    assert slip.ANGULAR_COMPONENT == "wy" and slip.ANGULAR_UNIT == "rad/s"
    assert "xyz"[slip.ANGULAR_AXIS] == "y"
    assert slip.ROTATION_EPSILON_RAD_S * slip.ROTATION_RADIUS_M == \
        pytest.approx(L.DEFAULT_EPSILON_M_S)
    assert slip.rim_speed(-2.0) == pytest.approx(0.02)
    assert slip.slip_kind(0.01, 2.0) == "rotation"          # 20 mm/s rim > 10 mm/s
    assert slip.slip_kind(0.03, -2.0) == "translation"
    assert slip.slip_kind(0.0, 0.0) == "translation"
    np.testing.assert_array_equal(slip.is_rotation(np.array([0.01, 0.03]),
                                                   np.array([-2.0, 2.0])), [True, False])


# --------------------------------------------------------------------------- unchanged

def old_mocap(finger, obj, t0, t1, calib):
    """The planar label before issue #21: (r(t1) - r(t0)) / (t1 - t0)."""
    ends = []
    for tq in (t0, t1):
        pf, rf = finger.interpolate(tq)
        rc = Rotation.from_quat(calib[3:])
        pg, rg = pf + rf.apply(calib[:3]), rf * rc
        po, _ = obj.interpolate(tq)
        ends.append(rg.inv().apply(po - pg))
    return (ends[1] - ends[0]) / (t1 - t0)[:, None]


def old_robot(tcp, t0, t1, calib):
    """The robot-state label before issue #21: -R_G(t_mid)^T (p_G(t1) - p_G(t0)) / dt."""
    rc = Rotation.from_quat(calib[3:])

    def g(tq):
        p, r = tcp.interpolate(tq)
        return p + r.apply(calib[:3]), r * rc
    (p0, _), (p1, _), (_, rmid) = g(t0), g(t1), g(0.5 * (t0 + t1))
    return -rmid.inv().apply(p1 - p0) / (t1 - t0)[:, None]


def test_planar_label_unchanged_without_relative_rotation():
    # Any motion of the object in the grasp plane (curved, accelerating) while it keeps its
    # orientation relative to the finger, which itself moves and tumbles in the world.
    def rel(t):
        return (np.array([0.02 * t + 0.01 * np.sin(5 * t), 0.003 * t, -0.015 * t ** 2]),
                Q_OBJ)
    f, o = tracks(rel)
    t0, t1 = windows()
    lab = L.mocap_window_velocity(f, o, t0, t1, CALIB)
    np.testing.assert_allclose(lab.velocity, old_mocap(f, o, t0, t1, CALIB), atol=1e-12)
    np.testing.assert_allclose(lab.angular, 0.0, atol=1e-12)
    assert np.abs(lab.speed).max() > 0.01


def test_robot_label_unchanged_for_a_translating_gripper():
    t = np.arange(0.0, DURATION + 1e-9, 0.004)
    rot = Rotation.from_euler("x", 180, degrees=True).as_quat()
    tcp = [np.concatenate([[0.3 + 0.05 * ti + 0.01 * np.sin(4 * ti), 0.02 * ti ** 2, 0.2],
                           rot]) for ti in t]
    track = L.PoseTrack(t, tcp)
    t0, t1 = windows()
    lab = L.robot_window_velocity(track, t0, t1, CALIB)
    np.testing.assert_allclose(lab.velocity, old_robot(track, t0, t1, CALIB), atol=1e-12)
    np.testing.assert_array_equal(lab.angular, 0.0)


def test_labels_without_omega_default_to_no_rotation():
    lab = L.WindowLabels(np.ones((3, 3)), np.zeros(3, np.uint8))
    np.testing.assert_array_equal(lab.angular, 0.0)
    assert lab.omega.shape == (3, 3)


# --------------------------------------------------------------------------- rotation

@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.03, 0.004, -0.02)])
def test_pure_rotation_about_the_pad_centre(offset):
    """The object turns about the pad normal through the pad centre: wy exact, planar ~0,
    wherever the object's own (rigid-body) origin lies."""
    wy = 1.5
    r0 = np.asarray(offset)

    def rel(t):
        return ry(wy * t).apply(r0)[0], ry(wy * t)[0] * Q_OBJ
    lab = labels(rel)
    np.testing.assert_allclose(lab.angular, wy, atol=1e-9)
    np.testing.assert_allclose(lab.velocity, 0.0, atol=1e-9)
    np.testing.assert_allclose(lab.omega[:, [0, 2]], 0.0, atol=1e-9)
    assert not (lab.speed > L.DEFAULT_EPSILON_M_S).any()       # slip stays planar


def test_pure_translation_has_no_rotation():
    v = np.array([0.02, 0.001, -0.03])
    lab = labels(lambda t: (np.array([0.01, 0.0, 0.02]) + v * t, Q_OBJ))
    np.testing.assert_allclose(lab.angular, 0.0, atol=1e-12)
    np.testing.assert_allclose(lab.velocity, np.tile(v, (lab.vx.size, 1)), atol=1e-12)


@pytest.mark.parametrize("wy", [-3.0, 0.8, 6.0])
def test_rotation_about_an_off_centre_point_gives_both(wy):
    """A planar turn about a fixed point c of the pad (a pivot off the pad centre): the pad
    centre's material point moves on a circle, v_c = -w x c = (-wy cz, wy cx)."""
    c = np.array([0.025, 0.0, -0.04])
    b = np.array([0.01, 0.002, 0.03])            # the object's origin at t = 0

    def rel(t):
        q = ry(wy * t)[0]
        return c + q.apply(b - c), q * Q_OBJ
    lab = labels(rel)
    np.testing.assert_allclose(lab.angular, wy, atol=1e-9)
    np.testing.assert_allclose(lab.vx, -wy * c[2], atol=1e-9)
    np.testing.assert_allclose(lab.vz, wy * c[0], atol=1e-9)
    np.testing.assert_allclose(lab.velocity[:, 1], 0.0, atol=1e-9)


def test_rotation_and_translation_of_the_pad_centre_point():
    """Constant twist: the pad centre's material point slides at v_c while the object turns
    about it (integrated numerically, independent of the labels' closed form)."""
    wy, v_c = 2.5, np.array([0.015, 0.0, -0.01])
    w = np.array([0.0, wy, 0.0])
    t = np.arange(0.0, DURATION + 1e-9, 1.0 / RATE)
    # Material point b(t) of the object: db/dt = v_c + w x b, by RK4 on a fine grid.
    every = 80
    h, b, traj = 1.0 / (RATE * every), np.array([0.02, 0.0, 0.01]), {}
    steps = int(round(DURATION / h))
    f = (lambda p: v_c + np.cross(w, p))
    for k in range(steps + 1):
        if k % every == 0:
            traj[k // every] = b.copy()
        k1 = f(b)
        k2 = f(b + 0.5 * h * k1)
        k3 = f(b + 0.5 * h * k2)
        k4 = f(b + h * k3)
        b = b + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    index = {round(ti * RATE): k for k, ti in enumerate(t)}

    def rel(ti):
        return traj[index[round(ti * RATE)]], ry(wy * ti)[0] * Q_OBJ
    lab = labels(rel)
    np.testing.assert_allclose(lab.angular, wy, atol=1e-9)
    np.testing.assert_allclose(lab.vx, v_c[0], atol=1e-8)
    np.testing.assert_allclose(lab.vz, v_c[2], atol=1e-8)
    # Today's label would have been the object origin's velocity: wrong by w x r.
    f_, o_ = tracks(rel)
    old = old_mocap(f_, o_, *windows(), CALIB)
    assert np.abs(old[:, [0, 2]] - v_c[[0, 2]]).max() > 0.01


@pytest.mark.parametrize("smoothing_s", [0.0, DEFAULT_LABEL_SMOOTHING_S])
def test_time_varying_rate_is_the_mean_over_the_window(smoothing_s):
    # theta(t) = a t + b t^2 / 2 about the pad normal, the pad centre sliding with constant
    # acceleration: the mean rates over [t0, t1], from raw poses and from poses smoothed by a
    # quadratic fit (exact for a quadratic motion: smoothing takes noise, not the motion).
    a, b, v0, acc = 1.0, 2.0, np.array([0.01, 0.0, -0.02]), np.array([0.02, 0.0, 0.01])

    def rel(t):
        return v0 * t + 0.5 * acc * t ** 2, ry(a * t + 0.5 * b * t ** 2)[0] * Q_OBJ
    lab = labels(rel, smoothing_s=smoothing_s)
    t0, t1 = windows()
    np.testing.assert_allclose(lab.angular, a + 0.5 * b * (t0 + t1), atol=1e-6)
    if smoothing_s:
        raw = labels(rel)
        np.testing.assert_allclose(lab.slip_velocity, raw.slip_velocity, atol=1e-6)


def test_finger_turning_with_the_object_is_no_rotation():
    # The whole grasp turns in the world (finger tumbles), the object held: no slip at all.
    lab = labels(lambda t: (np.array([0.01, 0.0, -0.02]), Q_OBJ))
    np.testing.assert_allclose(lab.angular, 0.0, atol=1e-12)
    np.testing.assert_allclose(lab.velocity, 0.0, atol=1e-12)


def test_world_fixed_object_seen_from_a_turning_finger():
    # The finger turns about its pad normal through the pad centre at 0.7 rad/s; the object
    # stays still in the world: relative to the finger it turns at -0.7 rad/s.
    t = np.arange(0.0, DURATION + 1e-9, 1.0 / RATE)
    g0 = L.compose(FINGER, CALIB)
    obj = np.concatenate([g0[:3] + [0.01, 0.02, 0.0], [0.0, 0.0, 0.0, 1.0]])
    fp = []
    for ti in t:
        g = np.concatenate([g0[:3], (Rotation.from_quat(g0[3:]) * ry(0.7 * ti)[0]).as_quat()])
        fp.append(L.compose(g, L.invert(CALIB)))
    lab = L.mocap_window_velocity(L.PoseTrack(t, fp), L.PoseTrack(t, [obj] * t.size),
                                  *windows(), CALIB)
    np.testing.assert_allclose(lab.angular, -0.7, atol=1e-9)
    np.testing.assert_allclose(lab.velocity, 0.0, atol=1e-9)     # pad centre fixed in world


def test_robot_labels_turning_gripper():
    """World-fixed probe: wy is minus the gripper's rate about its grasp-plane y; the planar
    label is minus the pad centre's velocity in the grasp plane (constant body twist)."""
    omega, v_body = 0.9, np.array([0.03, 0.0, -0.01])
    t = np.arange(0.0, DURATION + 1e-9, 0.004)
    g0 = L.compose(FINGER, CALIB)
    r0 = Rotation.from_quat(g0[3:])
    tcp = []
    for ti in t:
        # Constant body twist (v_body, omega about y): p' = R v_body, R' = R [w]x.
        th = omega * ti
        # In the body frame at t=0 the pad centre traces the integral of Ry(th) v_body.
        if abs(omega) > 0:
            s, c = np.sin(th), np.cos(th)
            x = (s * v_body[0] + (1 - c) * v_body[2]) / omega
            z = (-(1 - c) * v_body[0] + s * v_body[2]) / omega
        disp = np.array([x, 0.0, z])
        g = np.concatenate([g0[:3] + r0.apply(disp), (r0 * ry(th)[0]).as_quat()])
        tcp.append(L.compose(g, L.invert(CALIB)))
    lab = L.robot_window_velocity(L.PoseTrack(t, tcp), *windows(), CALIB)
    assert lab.valid.all()
    np.testing.assert_allclose(lab.angular, -omega, atol=1e-9)
    np.testing.assert_allclose(lab.velocity, np.tile(-v_body, (lab.vx.size, 1)), atol=1e-9)


def test_gap_rules_drop_the_angular_label_too():
    wy = 1.0
    t = np.arange(0.0, DURATION + 1e-9, 1.0 / RATE)
    t = t[~((t >= 0.51) & (t < 0.62))]                   # ~120 ms without poses
    f, o = tracks(lambda ti: (np.zeros(3), ry(wy * ti)[0] * Q_OBJ), t=t)
    t0, t1 = windows()
    lab = L.mocap_window_velocity(f, o, t0, t1, CALIB, max_gap_s=0.05)
    overlaps = (t0 < 0.625) & (t1 > 0.50)
    assert np.array_equal(lab.reason == L.GAP, overlaps)
    assert np.all(lab.angular[~lab.valid] == 0) and np.all(lab.omega[~lab.valid] == 0)
    np.testing.assert_allclose(lab.angular[lab.valid], wy, atol=1e-9)
    # A shorter dropout is bridged by Slerp and the rate stays exact.
    t = np.arange(0.0, DURATION + 1e-9, 1.0 / RATE)
    t = t[~((t >= 0.51) & (t < 0.55))]
    f, o = tracks(lambda ti: (np.zeros(3), ry(wy * ti)[0] * Q_OBJ), t=t)
    lab = L.mocap_window_velocity(f, o, t0, t1, CALIB, max_gap_s=0.05)
    assert lab.valid.all()
    np.testing.assert_allclose(lab.angular, wy, atol=1e-9)


# --------------------------------------------------------------------------- streaming

def stream_track(rel):
    f, o = tracks(rel)
    return S.relative_track("mocap", f, CALIB, o)


def test_streaming_labels_carry_wy_and_the_pad_centre_velocity():
    wy = -2.0
    c = np.array([0.02, 0.0, 0.03])

    def rel(t):
        q = ry(wy * t)[0]
        return c + q.apply(np.array([0.01, 0.0, 0.0]) - c), q * Q_OBJ
    tr = stream_track(rel)
    assert tr.shape[1] == S.TRACK_COLUMNS == 7
    sr = 48000.0
    samples = np.column_stack([tr[:, 0] * sr, tr[:, 1:]])
    ends = np.array([0.5, 1.0, 1.5]) * sr
    lab = S.frame_labels(samples, ends, sr, L.DEFAULT_EPSILON_M_S)
    assert lab["valid"].all()
    np.testing.assert_allclose(lab["wy"], wy, atol=1e-4)
    # The Savitzky-Golay fit's own bias on a circular path: well under 1 % here.
    np.testing.assert_allclose(lab["v"][:, 0], -wy * c[2], rtol=0.01)
    np.testing.assert_allclose(lab["v"][:, 1], wy * c[0], rtol=0.01)
    # The same rotation about the pad centre: no planar slip in the streaming labels either.
    tr = stream_track(lambda t: (ry(wy * t).apply([0.03, 0.0, -0.02])[0],
                                 ry(wy * t)[0] * Q_OBJ))
    lab = S.frame_labels(np.column_stack([tr[:, 0] * sr, tr[:, 1:]]), ends, sr, 0.005)
    # The object's origin moves at 72 mm/s; the pad centre's point within the fit's bias.
    np.testing.assert_allclose(lab["v"], 0.0, atol=5e-4)
    np.testing.assert_allclose(lab["wy"], wy, atol=1e-4)
    assert not lab["slip"].any()


def test_accumulated_rotation_does_not_wrap():
    q = ry(np.linspace(0.0, 4 * np.pi, 200))
    a = S.accumulated_rotation(q)
    np.testing.assert_allclose(a[:, 1], np.linspace(0.0, 4 * np.pi, 200), atol=1e-9)
    assert S.accumulated_rotation(ry([0.3])).shape == (1, 3)


def test_streaming_labels_of_an_old_track_have_no_wy():
    v = np.array([0.02, 0.0, -0.01])
    tr = stream_track(lambda t: (v * t, Q_OBJ))
    sr = 48000.0
    full = np.column_stack([tr[:, 0] * sr, tr[:, 1:]])
    old = full[:, :S.OLD_TRACK_COLUMNS]
    ends = np.array([0.5, 1.0]) * sr
    new, before = (S.frame_labels(x, ends, sr, 0.005) for x in (full, old))
    assert np.isnan(before["wy"]).all()
    np.testing.assert_allclose(new["wy"], 0.0, atol=1e-9)
    np.testing.assert_allclose(new["v"], before["v"], atol=1e-7)
    np.testing.assert_allclose(before["v"], [[0.02, -0.01]] * 2, atol=1e-5)
    assert (new["slip"] == before["slip"]).all()


def test_load_track_accepts_old_and_new_shapes(tmp_path):
    for k, cols in enumerate((4, 7)):
        S.write_track(tmp_path, k, np.zeros((5, cols)))
        assert S.load_track(tmp_path, k).shape == (5, cols)
    S.write_track(tmp_path, 2, np.zeros((5, 5)))
    with pytest.raises(ValueError, match=r"\(N, 7\) or \(N, 4\)"):
        S.load_track(tmp_path, 2)


# --------------------------------------------------------------------------- the scene

class _TruthTap:
    """A World streamed to a bag while its true per-sample v_rel and w_rel are kept."""

    def __init__(self, world):
        self.world, self.v, self.w = world, [], []

    def metadata(self):
        return self.world.metadata()

    def stream(self, block_frames):
        for chunk in self.world.stream(block_frames=block_frames):
            self.v.append(chunk.v_rel)
            self.w.append(chunk.w_rel)
            yield chunk


def _exported_against_truth(tmp_path, noise: bool, smoothing_s: tuple):
    """A scripted scene trial (pure rotation, pure translation, then both) recorded once and
    exported with each label smoothing: per export the windows' labels and the mean of the
    scene's true pad-centre velocity and angular velocity over each window's samples."""
    from aslip_ros.data.dataset import Dataset
    from aslip_ros.data.export import ExportConfig, export
    from aslip_ros.scene.simulate import record_world
    from aslip_ros.scene import scenarios
    from aslip_ros.scene.world import World
    segments = [(0.5, 1.5, 0.0, 0.0, 2.0), (2.0, 3.0, 0.02, -0.01),
                (3.5, 4.5, 0.01, 0.0, -3.0)]
    scn = scenarios.scripted(0, segments, duration_s=5.0)
    if not noise:
        scn = scn.with_(mocap_noise_m=0.0, mocap_drop_prob=0.0)
    tap = _TruthTap(World(scn))
    record_world(tap, tmp_path / "bags" / "t")
    out = []
    for s in smoothing_s:
        export([tmp_path / "bags"], tmp_path / f"ds{s}",
               ExportConfig(label_smoothing_s=s, progress=False))
        ds = Dataset(tmp_path / f"ds{s}")
        assert ds.manifest["label_smoothing_s"] == s
        w = np.asarray(ds.windows)
        n = ds.n_window_samples
        first = w["start"] + ds.trials[0]["first_sample_index"]
        cv = np.concatenate([np.zeros((1, 2)), np.cumsum(np.concatenate(tap.v), axis=0)])
        cw = np.concatenate([[0.0], np.cumsum(np.concatenate(tap.w))])
        v_true, w_true = (cv[first + n] - cv[first]) / n, (cw[first + n] - cw[first]) / n
        assert len(w) >= 45 and (w_true.min(), w_true.max()) == pytest.approx((-3.0, 2.0))
        out.append((w, np.column_stack([w["vx"], w["vz"]]) - v_true, w_true))
    return out


def test_exported_raw_labels_match_the_scenes_truth(tmp_path):
    """From the raw poses (no smoothing) and without motion-capture noise, the labels agree
    with the truth to the interpolation; pure rotation gives turning windows with no planar
    slip."""
    (w, err_v, w_true), = _exported_against_truth(tmp_path, False, (0.0,))
    np.testing.assert_allclose(w["wy"], w_true, atol=1e-3)
    np.testing.assert_allclose(err_v, 0.0, atol=1e-5)
    turning = np.abs(w_true) > slip.ROTATION_EPSILON_RAD_S
    assert (turning & ~w["slip"]).sum() >= 5


def test_smoothed_labels_carry_less_of_the_motion_captures_noise(tmp_path):
    """With the scene's noise (0.15 mm, no orientation noise) the planar label from the raw
    poses carries ~2 mm/s of it; from the poses smoothed over the default 150 ms it carries
    under 0.6 of that, and wy stays within the blur of the steps (a quadratic over 150 ms
    spreads each step by 75 ms either side; 0 elsewhere)."""
    (_, raw_v, _), (w, smooth_v, w_true) = _exported_against_truth(
        tmp_path, True, (0.0, DEFAULT_LABEL_SMOOTHING_S))
    rms = [np.sqrt((e ** 2).sum(1).mean()) for e in (raw_v, smooth_v)]
    assert rms[0] < 2.5e-3 and rms[1] < 0.6 * rms[0]
    err_w = np.abs(w["wy"] - w_true)
    assert err_w.max() < 0.2 and np.median(err_w) < 1e-3
