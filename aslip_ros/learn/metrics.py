"""The paper's metrics from arrays (definitions: learn/evaluate.py, the module docstring).

Below evaluation and the bootstrap (learn/stats.py): both compute them, neither owns them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from aslip_ros.slip import DEFAULT_THRESHOLD, N_VELOCITY


def compute_metrics(prob: np.ndarray, raw_velocity: np.ndarray, true_velocity: np.ndarray,
                    slip: np.ndarray, window_s: float,
                    threshold: float = DEFAULT_THRESHOLD) -> dict[str, Any]:
    """The paper's metrics from arrays; see the module docstring for the definitions."""
    prob = np.asarray(prob, dtype=np.float64).reshape(-1)
    raw = np.asarray(raw_velocity, dtype=np.float64).reshape(-1, N_VELOCITY)
    true = np.asarray(true_velocity, dtype=np.float64).reshape(-1, N_VELOCITY)
    slip = np.asarray(slip, dtype=bool).reshape(-1)
    n = prob.shape[0]
    if not (raw.shape[0] == true.shape[0] == slip.shape[0] == n):
        raise ValueError("prob, velocities and slip labels must have the same length")
    out: dict[str, Any] = {"n_windows": int(n), "n_slip": int(slip.sum()),
                           "threshold": float(threshold), "window_s": float(window_s)}
    if n == 0:
        return out
    pred = prob >= threshold
    tp = int((pred & slip).sum())
    out.update(detection_accuracy=float((pred == slip).mean()),
               precision=float(tp / max(pred.sum(), 1)), recall=float(tp / max(slip.sum(), 1)))
    s_true = np.linalg.norm(true, axis=1)
    s_raw = np.linalg.norm(raw, axis=1)
    m = slip & (s_true > 0)
    if m.any():
        cos = (raw[m] * true[m]).sum(1) / (np.maximum(s_raw[m], 1e-12) * s_true[m])
        ang = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        ang[s_raw[m] == 0] = 90.0  # no direction at all: count as orthogonal, not as right
        e_mm = np.abs(s_raw[m] - s_true[m]) * window_s * 1e3
        out.update(direction_mae_deg=float(ang.mean()), direction_std_deg=float(ang.std()),
                   magnitude_rmse_mm=float(np.sqrt((e_mm ** 2).mean())),
                   magnitude_std_mm=float(e_mm.std()))
    s_gated = np.where(pred, s_raw, 0.0)
    e_all = np.abs(s_gated - s_true) * window_s * 1e3
    out["magnitude_rmse_gated_mm"] = float(np.sqrt((e_all ** 2).mean()))
    return out


def grouped_metrics(groups: np.ndarray, prob, raw_velocity, true_velocity, slip, window_s,
                    threshold=DEFAULT_THRESHOLD) -> dict[str, dict[str, Any]]:
    """``compute_metrics`` per distinct value of ``groups`` (e.g. object per window)."""
    groups = np.asarray(groups)
    return {str(g): compute_metrics(prob[groups == g], raw_velocity[groups == g],
                                    true_velocity[groups == g], slip[groups == g], window_s,
                                    threshold)
            for g in sorted(set(groups.tolist()))}
