"""Scene variants for per-grasp calibration: coupling per grasp and one-sided slip."""

import numpy as np
import pytest

from aslip_ros.scene import World
from aslip_ros.scene import scenarios as sc

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


def test_coupling_variant_draws_new_gains_per_grasp_within_range():
    base = sc.external_induced(seed=1, duration_s=1.0, sample_rate=RATE)
    assert base.acoustics.gain_mismatch_db == 0.0 and base.one_sided_fraction == 0.0
    gains = [20 * np.log10(World(sc.coupling_variant(base.with_(seed=s))).synth.gain)
             for s in range(8)]
    g = np.array(gains)
    assert np.all(np.abs(g) <= sc.COUPLING_DB) and g.std() > 1.0
    assert not np.allclose(g[0], g[1])
    np.testing.assert_array_equal(World(base).synth.gain, np.ones(4))


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
    explicit = sc.coupling_variant(base, 0.0, 0.0).with_(one_sided_fraction=0.0)
    _, a, v = render(base)
    _, b, u = render(explicit)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(v, u)


@pytest.mark.parametrize("kw", [{"one_sided_fraction": 1.5}, {"one_sided_fraction": -0.1},
                                {"one_sided_spread_rad": 4.0}])
def test_bad_variant_parameters_are_refused(kw):
    with pytest.raises(ValueError, match="one_sided"):
        sc.external_induced(seed=0, **kw)
