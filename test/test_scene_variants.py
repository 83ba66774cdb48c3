"""The held-out scene variants (scene/variants.py): each moves what it claims, within its
sourced range, and the default scene is what it was."""

import numpy as np
import pytest

from aslip_ros.scene import World
from aslip_ros.scene import scenarios as sc
from aslip_ros.scene import variants as va
from aslip_ros.scene.layouts import OBJECTS

RATE = 16000.0


def render(scn):
    w = World(scn)
    chunks = list(w.stream(block_frames=1600))
    return w, np.concatenate([c.audio for c in chunks]), np.concatenate([c.v_rel for c in chunks])


def slip_angles(scn, n_trials=6):
    out = []
    for k in range(n_trials):
        s = scn.with_(seed=100 + k)
        _, _, v = render(s)
        vw = v[: v.shape[0] // 3200 * 3200].reshape(-1, 3200, 2).mean(axis=1)
        moving = np.hypot(*vw.T) > 0.005
        d = np.arctan2(vw[moving, 1], vw[moving, 0]) - s.one_sided_direction_rad
        out.append(np.angle(np.exp(1j * d)))
    return np.concatenate(out)


def test_coupling_variant_draws_new_gains_per_grasp_within_a_wider_range():
    base = sc.external_induced(seed=1, duration_s=1.0, sample_rate=RATE)
    assert base.one_sided_fraction == 0.0
    default_db = base.acoustics.gain_mismatch_db
    assert sc.COUPLING_DB >= 2.0 * max(default_db, 1.0)        # wider than the scene's own

    def gains(make):
        return np.array([20 * np.log10(World(make(base.with_(seed=s))).synth.gain)
                         for s in range(10)])
    g, g0 = gains(sc.coupling_variant), gains(lambda s: s)
    assert np.all(np.abs(g) <= sc.COUPLING_DB) and np.abs(g).max() > default_db
    assert g.std() > 1.5 * g0.std() and not np.allclose(g[0], g[1])
    flat = World(sc.coupling_variant(base, 0.0, 0.0)).synth.gain
    np.testing.assert_array_equal(flat, np.ones(4))


def test_handling_noise_path_makes_the_background_not_quite_common_mode():
    # Touches without slip only: slip_fraction 0 cannot be set, so read rest-of-slip windows.
    def background_levels(path_db):
        scn = sc.coupling_variant(sc.external_induced(seed=4, duration_s=8.0,
                                                      sample_rate=RATE), 0.0, path_db)
        w, a, v = render(scn)
        quiet = np.hypot(*v.T) == 0.0
        loud = quiet & (np.abs(a).max(axis=1) > 0.004)
        return 10 * np.log10((a[loud] ** 2).mean(axis=0)), w
    flat, _ = background_levels(0.0)
    tilted, w = background_levels(1.0)
    assert np.ptp(flat) < 0.3
    expected = 20 * np.log10(w.synth._handling_path)
    np.testing.assert_allclose(tilted - tilted.mean(), expected - expected.mean(), atol=0.3)


def test_one_sided_variant_keeps_most_slip_in_one_sector():
    base = sc.external_induced(seed=0, duration_s=20.0, sample_rate=RATE)
    one = slip_angles(sc.one_sided_variant(base))
    every = slip_angles(base)
    inside = np.mean(np.abs(one) <= np.pi / 6 + 1e-9)
    assert 0.7 <= inside <= 0.95
    assert np.mean(np.abs(every) <= np.pi / 6) < 0.35     # about 1/6 for uniform directions


def test_default_scene_is_unchanged_by_the_new_knobs():
    base = sc.external_induced(seed=3, duration_s=2.0, sample_rate=RATE)
    ac = base.acoustics
    explicit = sc.coupling_variant(base, ac.gain_mismatch_db, ac.handling_path_db).with_(
        one_sided_fraction=0.0, no_slip_touch_fraction=0.2)
    _, a, v = render(base)
    _, b, u = render(explicit)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(v, u)


@pytest.mark.parametrize("kw", [{"one_sided_fraction": 1.5}, {"one_sided_fraction": -0.1},
                                {"one_sided_spread_rad": 4.0}])
def test_bad_variant_parameters_are_refused(kw):
    with pytest.raises(ValueError, match="one_sided"):
        sc.external_induced(seed=0, **kw)


def slip_level_pattern(scn, seeds):
    """Per trial, each channel's slip level against the channel mean [dB] (a fixed push)."""
    out = []
    for s in seeds:
        w, a, v = render(scn.with_(seed=s))
        m = np.hypot(*v.T) > 0
        lv = 10 * np.log10((a[m] ** 2).mean(axis=0))
        out.append(lv - lv.mean())
    return np.array(out)


def test_contact_variant_seats_the_object_off_centre():
    # No coupling, one scripted push along +x: only the contact position moves the pattern.
    flat = sc.scripted(0, [(0.2, 2.8, 0.02, 0.0)], duration_s=3.0, sample_rate=RATE)
    flat = sc.coupling_variant(flat, 0.0, 0.0)
    off = sc.contact_variant(flat)
    assert off.acoustics.contact_wander_m == va.CONTACT_OFFSET_M > flat.acoustics.contact_wander_m
    assert off.acoustics.gain_mismatch_db == 0.0
    seeds = range(8)
    spread_default = slip_level_pattern(flat, seeds).std(axis=0).mean()
    spread_off = slip_level_pattern(off, seeds).std(axis=0).mean()
    assert spread_off > 1.5 * spread_default


def count_touches(scn, t_end=200.0):
    slip, touch = sc.agent_pushes(scn, np.random.default_rng(7))
    t = np.arange(0.0, t_end, 1e-3)
    s = np.hypot(*slip.evaluate(t).T) > 0
    on = touch.evaluate(t)[:, 0] > 0
    starts = np.flatnonzero(on[1:] & ~on[:-1]) + 1
    ends = np.r_[np.flatnonzero(~on[1:] & on[:-1]) + 1, t.size]
    slipped = [s[a:b].any() for a, b in zip(starts, ends)]
    return 1.0 - np.mean(slipped), len(slipped)


def test_confounders_variant_touches_without_slip_and_louder():
    base = sc.external_induced(seed=2, duration_s=None)
    conf = sc.confounders_variant(base)
    share0, n0 = count_touches(base)
    share1, n1 = count_touches(conf)
    assert n0 > 100 and n1 > 100
    assert abs(share0 - 0.2) < 0.08 and abs(share1 - va.NO_SLIP_TOUCH_FRACTION) < 0.1
    a0, a1 = base.acoustics, conf.acoustics
    assert a1.handling_level == 2 * a0.handling_level and a1.robot_level == 2 * a0.robot_level
    assert a1.click_rate_touch == 2 * a0.click_rate_touch
    assert a1.gain_mismatch_db == a0.gain_mismatch_db      # the scene's coupling is kept


@pytest.mark.parametrize("value", [1.0, -0.1, 2.0])
def test_bad_no_slip_touch_fraction_is_refused(value):
    with pytest.raises(ValueError, match="no_slip_touch_fraction"):
        sc.external_induced(seed=0, no_slip_touch_fraction=value)


def test_every_variant_is_named_and_keeps_the_grasp():
    assert set(sc.VARIANTS) == {"coupling", "one_sided", "contact", "confounders", "mocap",
                                "rate", "speed", "path"}
    base = sc.external_induced(seed=5)
    for name, make in sc.VARIANTS.items():
        v = make(base)
        assert v != base, name
        assert (v.seed, v.object, v.layout, v.pad, v.condition) == \
            (base.seed, base.object, base.layout, base.pad, base.condition)
        # One variant, one axis: the coupling stays the scene's unless the variant is it.
        if name != "coupling":
            assert v.acoustics.gain_mismatch_db == base.acoustics.gain_mismatch_db, name


def test_rate_variant_records_at_a_sound_cards_rate():
    scn = sc.VARIANTS["rate"](sc.external_induced(seed=1, duration_s=0.5))
    assert scn.sample_rate == va.LAB_RATE_HZ == 44100.0
    w = World(scn)
    audio = np.concatenate([c.audio for c in w.stream(block_frames=441)])
    assert audio.shape == (22050, 4) and w.metadata()["sample_rate"] == 44100.0


def test_speed_variant_gives_each_object_its_own_exponent_within_its_range():
    lo, hi = va.SPEED_EXPONENT_RANGE
    assert lo < 0.75 < hi                                   # around the reported 0.75
    exps = {}
    for obj in sorted(OBJECTS):
        base = sc.external_induced(seed=1, object=obj)
        assert base.acoustics.speed_exponent == 0.75       # the default scene: one for all
        v = sc.speed_variant(base)
        exps[obj] = v.acoustics.speed_exponent
        assert lo <= exps[obj] <= hi
        # One object, one exponent: the same in every grasp; nothing else moves.
        assert sc.speed_variant(base.with_(seed=9)).acoustics.speed_exponent == exps[obj]
        assert v.with_(acoustics=base.acoustics) == base
    assert len(set(exps.values())) == len(exps) and np.ptp(list(exps.values())) > 0.3
    with pytest.raises(ValueError, match="speed exponent"):
        va.object_speed_exponent("chips_can", 1.0, 0.5)


def test_default_scene_is_unchanged_by_the_speed_variant_at_its_default_exponent():
    base = sc.external_induced(seed=3, duration_s=2.0, sample_rate=RATE)
    same = sc.speed_variant(base, 0.75, 0.75)
    assert same == base
    _, a, v = render(base)
    _, b, u = render(same)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(v, u)


def level_speed_slope(scn, speeds=(0.005, 0.01, 0.02, 0.04, 0.08), seg_s=0.3):
    """Slope of log slip RMS against log speed over scripted pushes along +x, one per speed."""
    segs = [(0.1 + k * (seg_s + 0.1), 0.1 + k * (seg_s + 0.1) + seg_s, s, 0.0)
            for k, s in enumerate(speeds)]
    scn = scn.with_(kind="scripted", script=tuple(segs), duration_s=segs[-1][1] + 0.1)
    w, a, v = render(scn)
    fs = w.fs
    rms = []
    for t0, t1, _, _ in segs:
        i0, i1 = int((t0 + 0.05) * fs), int((t1 - 0.02) * fs)     # settled inside the push
        rms.append(np.sqrt(np.mean(a[i0:i1] ** 2)))
    return np.polyfit(np.log(speeds), np.log(rms), 1)[0]


def test_speed_variant_changes_how_loudness_follows_speed_per_object():
    # No coupling, the arm off, a textured pad: the slip alone above the noise floor. The slow
    # force variation moves a grasp's fitted slope by about 0.1, alike for every exponent
    # with one seed, so each variant slope is read against the default's on the same grasp.
    def scene(obj, seed):
        base = sc.scripted(seed, [(0.0, 0.1, 0.01, 0.0)], object=obj, sample_rate=RATE)
        return sc.coupling_variant(base, 0.0, 0.0)
    objs = ("chips_can", "pla_rod")                    # exponents 0.50 and 1.04
    for seed in (0, 1):
        slopes = {o: level_speed_slope(sc.speed_variant(scene(o, seed))) for o in objs}
        default = {o: level_speed_slope(scene(o, seed)) for o in objs}
        assert abs(default["pla_rod"] - default["chips_can"]) < 0.02   # one law for all
        assert abs(default["chips_can"] - 0.75) < 0.2
        for o in objs:
            moved = va.object_speed_exponent(o) - 0.75
            assert abs(slopes[o] - default[o] - moved) < 0.02, (o, seed, slopes, default)
        assert slopes["pla_rod"] - slopes["chips_can"] > 0.4


def test_path_variant_sends_the_hand_and_the_arm_by_paths_of_their_own():
    base = sc.external_induced(seed=6, duration_s=1.0, sample_rate=RATE,
                               condition="robot_moving")
    v = sc.VARIANTS["path"](base)
    assert base.acoustics.handling_path_db == base.acoustics.robot_path_db == 1.0
    assert v.acoustics.handling_path_db == v.acoustics.robot_path_db == va.PATH_DB == 6.0
    assert v.with_(acoustics=base.acoustics) == base                  # nothing else moves
    w0, w1 = World(base).synth, World(v).synth
    np.testing.assert_array_equal(w0.gain, w1.gain)                   # the same coupling
    # The grasp's own draws, scaled: the variant draws nothing the default scene does not.
    for name in ("_handling_path", "_robot_coupling"):
        p0, p1 = (20 * np.log10(getattr(w, name).astype(float)) for w in (w0, w1))
        np.testing.assert_allclose(p1, 6.0 * p0, atol=1e-4)
        assert np.all(np.abs(p1) <= 6.0) and np.ptp(p1) > 2.0, (name, p1)
    # The arm's noise reaches each microphone through its path: its level pattern is it.
    n = 16000
    z = np.random.default_rng(0).standard_normal((n, 18)).astype(np.float32)
    robot = w1._robot(z, np.tile([0.05, 0.0, 0.0], (n, 1)))
    level = 10 * np.log10((robot.astype(float) ** 2).mean(axis=0))
    path = 20 * np.log10(w1._robot_coupling)
    np.testing.assert_allclose(level - level.mean(), path - path.mean(), atol=1e-3)


def test_default_scene_is_unchanged_by_the_path_variant_at_the_default_paths():
    base = sc.external_induced(seed=3, duration_s=2.0, sample_rate=RATE,
                               condition="robot_moving")
    same = sc.path_variant(base, 1.0, 1.0)
    assert same == base
    _, a, v = render(base)
    _, b, u = render(same)
    assert np.abs(a).max() > 0.0
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(v, u)
