"""Bootstrap over trials: intervals cover the estimate, widen with trial spread, and rank."""

import numpy as np
import pytest

from aslip_ros.learn import stats
from aslip_ros.learn.metrics import compute_metrics


def data(n_trials=10, per=50, spread=10.0, seed=0):
    """Slip windows whose direction error is a per-trial offset of ``spread`` deg std."""
    rng = np.random.default_rng(seed)
    trial = np.repeat(np.arange(n_trials), per)
    off = np.radians(np.abs(rng.normal(20.0, spread, n_trials)))[trial]
    ang = rng.uniform(-np.pi, np.pi, trial.size)
    true = np.stack([np.cos(ang), np.sin(ang)], 1) * 0.02
    pred = np.stack([np.cos(ang + off), np.sin(ang + off)], 1) * 0.02
    slip = np.ones(trial.size, bool)
    return trial, np.ones(trial.size), pred, true, slip


def test_interval_covers_the_estimate_and_widens_with_trial_spread():
    narrow = stats.bootstrap_metrics(*data(spread=1.0), 0.2, n_boot=300)
    wide = stats.bootstrap_metrics(*data(spread=15.0), 0.2, n_boot=300)
    for r in (narrow, wide):
        lo, hi = r["direction_mae_deg_ci"]
        assert lo <= r["direction_mae_deg"] <= hi
    width = {k: r["direction_mae_deg_ci"][1] - r["direction_mae_deg_ci"][0]
             for k, r in (("narrow", narrow), ("wide", wide))}
    assert width["wide"] > 4 * width["narrow"]


def test_resampling_is_by_trial_not_by_window():
    # Windows within a trial agree perfectly, trials differ: a window bootstrap would give a
    # much narrower interval than the trial bootstrap here.
    trial, prob, pred, true, slip = data(n_trials=6, per=200, spread=15.0)
    r = stats.bootstrap_metrics(trial, prob, pred, true, slip, 0.2, n_boot=300)
    lo, hi = r["direction_mae_deg_ci"]
    assert hi - lo > 5.0
    with pytest.raises(ValueError, match="two trials"):
        stats.bootstrap_metrics(np.zeros(5), *(a[:5] for a in (prob, pred, true, slip)), 0.2)


def test_paired_difference_tells_methods_apart_only_when_they_differ():
    trial, prob, pred, true, slip = data()
    rot = np.radians(15.0)
    worse = pred @ np.array([[np.cos(rot), np.sin(rot)], [-np.sin(rot), np.cos(rot)]])

    def mae(p):
        return lambda idx: compute_metrics(prob[idx], p[idx], true[idx], slip[idx],
                                           0.2)["direction_mae_deg"]
    est, lo, hi = stats.paired_difference(trial, mae(worse), mae(pred), n_boot=300)
    assert est > 5.0 and lo > 0.0
    est, lo, hi = stats.paired_difference(trial, mae(pred), mae(pred), n_boot=300)
    assert est == 0.0 and lo <= 0.0 <= hi
