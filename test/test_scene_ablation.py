"""Each mechanism of the sound model, switched off, moves the number it exists for.

Proxy read-outs from ``aslip_ros.scene.ablation`` (k-nearest neighbours on band energies
and inter-channel level offsets); docs/scene.md records the full table.
"""

from dataclasses import replace
from functools import lru_cache

import pytest

from aslip_ros.scene.ablation import ProxyConfig, evaluate
from aslip_ros.scene.physics import UNCOUPLED, Acoustics

AC = Acoustics()
DIRN = ProxyConfig(windows_per_trial=40, slip_fraction=1.0, speed_range_m_s=(0.01, 0.1))


@lru_cache(maxsize=None)
def run(cfg: ProxyConfig) -> dict:
    return evaluate(cfg)


def test_texture_lines_give_the_slip_axis():
    textured, smooth = run(DIRN), run(replace(DIRN, pad="smooth"))
    assert smooth["fold_mae_deg"] > textured["fold_mae_deg"] + 4.0
    assert smooth["mag_rmse_mm"] > textured["mag_rmse_mm"]


def test_smooth_pad_spreads_the_source():
    """Without ridges the source is not pinned to the leading edge: the sign cue weakens."""
    smooth = run(replace(DIRN, pad="smooth"))
    pinned = run(replace(DIRN, pad="smooth", acoustics=replace(AC, smooth_edge_fraction=1.0)))
    assert smooth["dir_mae_deg"] > pinned["dir_mae_deg"] + 8.0
    assert smooth["flip_pct"] > pinned["flip_pct"] + 5.0
    assert smooth["dir_mae_deg"] > 1.5 * run(DIRN)["dir_mae_deg"]   # textured far better


def test_leading_edge_levels_give_the_sign():
    ref = run(DIRN)
    flat = run(replace(DIRN, acoustics=replace(AC, leading_edge_shift_m=0.0)))
    assert flat["flip_pct"] > ref["flip_pct"] + 15.0
    assert flat["dir_mae_deg"] > 1.8 * ref["dir_mae_deg"]


def test_layout_order_follows_the_baselines():
    mae = {lay: run(replace(DIRN, layout=lay))["dir_mae_deg"]
           for lay in ("4mic", "2mic_corners", "2mic_same_finger", "2mic_centered")}
    assert mae["4mic"] < mae["2mic_corners"] < mae["2mic_same_finger"] < mae["2mic_centered"]
    assert run(replace(DIRN, layout="2mic_centered"))["flip_pct"] > 25.0   # sign ambiguous


def test_tip_brightness_is_the_only_sign_cue_for_centered_mics():
    centred = replace(DIRN, layout="2mic_centered")
    without = run(replace(centred, acoustics=replace(AC, tip_brightness=0.0)))
    assert without["dir_mae_deg"] > run(centred)["dir_mae_deg"] + 10.0
    assert without["flip_pct"] > 40.0


def test_contact_wander_blurs_level_cues():
    still = run(replace(DIRN, acoustics=replace(AC, contact_wander_m=0.0)))
    assert still["dir_mae_deg"] < run(DIRN)["dir_mae_deg"] - 3.0


def test_robot_noise_gap_appears_only_with_robot_noise():
    gaps = {}
    for lay in ("4mic", "2mic_centered"):
        moving = replace(DIRN, layout=lay, condition="robot_moving")
        silent = replace(moving, acoustics=replace(AC, robot_level=0.0))
        gaps[lay] = run(moving)["dir_mae_deg"] - run(silent)["dir_mae_deg"]
    assert gaps["2mic_centered"] > 5.0
    assert gaps["2mic_centered"] > gaps["4mic"]


def test_handling_noise_defeats_an_energy_detector():
    slow = ProxyConfig(windows_per_trial=40, speed_range_m_s=(0.0005, 0.006))
    quiet = run(replace(slow, acoustics=replace(AC, handling_level=0.0, click_rate_touch=0.0)))
    assert run(slow)["energy_det_pct"] < quiet["energy_det_pct"] - 15.0


def test_force_variation_limits_magnitude_from_level():
    one = replace(DIRN, layout="1mic")
    steady = run(replace(one, acoustics=replace(AC, force_var_db=0.0)))
    assert run(one)["mag_rmse_mm"] > 1.2 * steady["mag_rmse_mm"]


@pytest.mark.parametrize("field", ["dir_mae_deg", "det_pct"])
def test_proxy_is_deterministic(field):
    small = replace(DIRN, n_trials=3, windows_per_trial=6)
    assert evaluate(small)[field] == evaluate(small)[field]


def test_per_grasp_coupling_breaks_level_cues_unless_calibrated_out():
    """The default scene couples each microphone differently per grasp: left in, the level
    pattern (the sign) is lost; divided out (a converged calibration), the direction is
    that of the scene without coupling, up to the hand's own path (+-1 dB)."""
    assert AC.gain_mismatch_db == 3.0 and AC.handling_path_db == 1.0
    calibrated, raw = run(DIRN), run(replace(DIRN, oracle_gains=False))
    none = run(replace(DIRN, acoustics=UNCOUPLED))
    assert raw["dir_mae_deg"] > calibrated["dir_mae_deg"] + 15.0
    assert raw["flip_pct"] > calibrated["flip_pct"] + 10.0
    assert calibrated["dir_mae_deg"] < none["dir_mae_deg"] + 5.0
    assert none == run(replace(DIRN, acoustics=UNCOUPLED, oracle_gains=False))   # gains 1
