"""Bootstrap confidence intervals over trials for the paper's metrics.

Windows of one trial share a grasp, an object and a coupling, so they are not independent:
resampling windows would give intervals far too narrow. Here whole trials are resampled with
replacement and the metric is recomputed over the pooled windows of each resample.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from aslip_ros.learn.metrics import ROTATION_KEYS, compute_metrics
from aslip_ros.slip import DEFAULT_THRESHOLD

KEYS = ("detection_accuracy", "direction_mae_deg", "magnitude_rmse_mm")


def resamples(trial: np.ndarray, n_boot: int, seed: int):
    trial = np.asarray(trial)
    ids = np.unique(trial)
    if ids.size < 2:
        raise ValueError("a bootstrap over trials needs at least two trials")
    members = {t: np.flatnonzero(trial == t) for t in ids}
    rng = np.random.default_rng(seed)
    for _ in range(n_boot):
        pick = rng.choice(ids, ids.size, replace=True)
        yield np.concatenate([members[t] for t in pick])


def bootstrap_metrics(trial: np.ndarray, prob, raw_velocity, true_velocity, slip,
                      window_s: float, *, n_boot: int = 1000, seed: int = 0,
                      level: float = 0.95, threshold: float = DEFAULT_THRESHOLD,
                      angular=None, true_angular=None) -> dict[str, Any]:
    """``compute_metrics`` overall plus ``<key>_ci`` = (low, high) for each of ``KEYS`` and,
    with ``true_angular`` (rad/s, NaN: no label; ``angular`` the model's raw rate or None),
    for each rotational metric (``metrics.ROTATION_KEYS``) the windows allow."""
    arrays = [np.asarray(a) for a in (prob, raw_velocity, true_velocity, slip)]
    rot = {} if true_angular is None else {
        "true_angular": np.asarray(true_angular),
        "angular": None if angular is None else np.asarray(angular)}
    out = compute_metrics(*arrays, window_s, threshold, **rot)
    keys = KEYS + (ROTATION_KEYS if rot else ())
    samples = {k: [] for k in keys}
    for idx in resamples(trial, n_boot, seed):
        m = compute_metrics(*(a[idx] for a in arrays), window_s, threshold,
                            **{k: None if a is None else a[idx] for k, a in rot.items()})
        for k in keys:
            if k in m:
                samples[k].append(m[k])
    lo, hi = 50.0 * (1.0 - level), 50.0 * (1.0 + level)
    for k, vals in samples.items():
        if vals:
            out[k + "_ci"] = (float(np.percentile(vals, lo)), float(np.percentile(vals, hi)))
    return out


def paired_difference(trial: np.ndarray, metric: Callable[[np.ndarray], float],
                      other: Callable[[np.ndarray], float], *, n_boot: int = 1000,
                      seed: int = 0, level: float = 0.95) -> tuple[float, float, float]:
    """``metric - other`` on the same trial resamples: (estimate, low, high).

    ``metric(idx)`` and ``other(idx)`` compute a scalar over the windows ``idx``. When the
    interval contains 0 the two methods cannot be told apart on these trials.
    """
    everything = np.arange(np.asarray(trial).shape[0])
    est = float(metric(everything) - other(everything))
    diffs = [metric(idx) - other(idx) for idx in resamples(trial, n_boot, seed)]
    lo, hi = np.percentile(diffs, [50.0 * (1.0 - level), 50.0 * (1.0 + level)])
    return est, float(lo), float(hi)


def rate_interval(events, exposure, *, n_boot: int = 1000, seed: int = 0,
                  level: float = 0.95) -> tuple[float, float] | None:
    """The ``level`` interval of ``sum(events) / sum(exposure)`` (a rate: false alarms a
    minute of audio without slip, say) over a bootstrap of whole trials, one entry of each
    per trial; None with fewer than two trials. A trial's events share its grasp and its
    arm, so they are not independent events."""
    n = np.asarray(events, float)
    m = np.asarray(exposure, float)
    if n.size < 2:
        return None
    rates = [n[i].sum() / max(m[i].sum(), 1e-9)
             for i in resamples(np.arange(n.size), n_boot, seed)]
    lo, hi = np.percentile(rates, [50.0 * (1.0 - level), 50.0 * (1.0 + level)])
    return float(lo), float(hi)
