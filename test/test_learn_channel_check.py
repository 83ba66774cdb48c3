"""dead_channels: dead or disconnected microphones in one window, and nothing else."""

import warnings

import numpy as np
import pytest

from aslip_ros.learn.inference.channel_check import DEAD_FLOOR_RMS, DEAD_MARGIN_DB, dead_channels

NAMES = ["left_front_top", "left_rear_bottom", "right_front_bottom", "right_rear_top"]


def window(rms=0.01, n=2400, seed=0, gains_db=(0.0, 0.0, 0.0, 0.0)):
    """Noise at ``rms`` per channel, each scaled by its gain in dB."""
    x = np.random.default_rng(seed).standard_normal((n, len(gains_db)))
    return (rms * x * 10.0 ** (np.asarray(gains_db) / 20.0)).astype(np.float32)


@pytest.fixture(autouse=True)
def no_warnings():
    """No RuntimeWarning (log of zero, 0/0) anywhere: the check must be NaN-free."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def test_defaults():
    assert DEAD_MARGIN_DB == 40.0 and DEAD_FLOOR_RMS == 1e-7


def test_healthy_window_has_no_dead_channel():
    assert dead_channels(window(), NAMES) == []


@pytest.mark.parametrize("ch", range(4))
def test_all_zero_channel_is_flagged(ch):
    x = window()
    x[:, ch] = 0.0
    assert dead_channels(x, NAMES) == [NAMES[ch]]


def test_channel_below_the_absolute_floor_is_flagged():
    x = window()
    x[:, 2] = window(rms=5e-8)[:, 2]
    assert dead_channels(x, NAMES) == [NAMES[2]]


@pytest.mark.parametrize("down_db", [45.0, 50.0, 60.0])
def test_channel_far_below_the_others_is_flagged(down_db):
    x = window(gains_db=(0.0, -down_db, 0.0, 0.0))
    assert dead_channels(x, NAMES) == [NAMES[1]]


@pytest.mark.parametrize("gains_db", [(0, -10, 0, 0), (0, -20, 0, 0), (0, -20, -10, 0),
                                      (10, -10, 0, 5), (-20, -20, 0, 0)])
def test_normal_level_differences_are_not_flagged(gains_db):
    assert dead_channels(window(gains_db=gains_db), NAMES) == []


@pytest.mark.parametrize("rms", [3e-4, 1e-5, 1e-6])
def test_all_channels_quiet_together_is_not_flagged(rms):
    """Silence, no slip: every microphone at its noise floor, above digital silence."""
    assert dead_channels(window(rms=rms), NAMES) == []
    # Level differences near the floor do not count either.
    assert dead_channels(window(rms=rms, gains_db=(0, -15, 0, 3)), NAMES) == []


def test_others_at_the_floor_do_not_make_a_quiet_channel_dead():
    """The relative test applies only when the other channels are above the floor."""
    x = window(rms=5e-8)                       # three channels under the floor ...
    x[:, 0] = window(rms=2e-6)[:, 0]           # ... one quiet one far above them
    assert dead_channels(x, NAMES) == NAMES[1:]
    x = window(rms=2e-7, gains_db=(0, 0, 0, -45))   # all near the floor, one 45 dB down
    assert dead_channels(x, NAMES) == [NAMES[3]]     # (that one is under the floor itself)


def test_several_dead_channels_and_all_digital_silence():
    x = window()
    x[:, 0] = 0.0
    x[:, 3] = 0.0
    assert dead_channels(x, NAMES) == [NAMES[0], NAMES[3]]
    # Every input digitally silent: every microphone disconnected (real ones never are).
    assert dead_channels(np.zeros((2400, 4), np.float32), NAMES) == NAMES


def test_margin_is_configurable():
    x = window(gains_db=(0, -30, 0, 0))
    assert dead_channels(x, NAMES) == []
    assert dead_channels(x, NAMES, margin_db=25.0) == [NAMES[1]]
    x = window(gains_db=(0, -50, 0, 0))
    assert dead_channels(x, NAMES, margin_db=60.0) == []


def test_channel_counts_and_dtypes():
    one = window()[:, :1]
    assert dead_channels(one, NAMES[:1]) == []
    assert dead_channels(np.zeros_like(one), NAMES[:1]) == NAMES[:1]
    two = window(gains_db=(0, -50))
    assert dead_channels(two, NAMES[:2]) == [NAMES[1]]
    assert dead_channels(window().astype(np.float64), NAMES) == []
    ints = (window() * 1e4).astype(np.int16)              # no overflow when squared
    ints[:, 2] = 0
    assert dead_channels(ints, NAMES) == [NAMES[2]]
    assert dead_channels(np.zeros((0, 4), np.float32), NAMES) == []


def test_non_finite_input_never_flags_a_healthy_channel_or_raises():
    x = window()
    x[7, 1] = np.nan
    x[9, 3] = np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")       # numpy may warn on inf * inf; not our output
        assert dead_channels(x, NAMES) == []


def test_rejects_bad_arguments():
    with pytest.raises(ValueError):
        dead_channels(window(), NAMES[:3])
    with pytest.raises(ValueError):
        dead_channels(window()[None], NAMES)
    for bad in (0.0, -3.0, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            dead_channels(window(), NAMES, margin_db=bad)
    with pytest.raises(ValueError):
        dead_channels(window(), NAMES, floor_rms=-1.0)
