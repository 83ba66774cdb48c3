"""How ``aslip train --stage auto`` ranks candidates on the validation trials, and what the
ranking is worth.

The criterion (``score``, ``select``) is the sum, over direction MAE, magnitude RMSE and
detection error (1 - accuracy, floored at ``DETECTION_ERROR_FLOOR``), of a candidate's
value divided by the best candidate's value: 3.0 is best at everything, and a candidate
20 % worse on one metric pays 0.2. Where the validation windows carry angular labels
(rotational slip, dataset version 2) the rotational MAE is a fourth term, so that a recording
with rotation chooses a model that hears it. Lowest wins; ties go to the candidate trained
first.

What it is worth (``worth``, ``score_difference``): the winner's figures with 95 %
intervals from a bootstrap over validation trials (``learn.stats``), and the winner's
criterion minus the runner-up's on the same resamples; an interval that holds 0 says the
two cannot be told apart on these trials.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from aslip_ros.learn.data_io import WindowSet
from aslip_ros.learn.metrics import compute_metrics
from aslip_ros.learn.stats import KEYS, bootstrap_metrics, paired_difference
from aslip_ros.learn.training.config import TrainResult

DETECTION_ERROR_FLOOR = 0.01
N_BOOT = 1000
#: The three figures the criterion weighs (the paper's metrics, ``learn.stats``).
METRICS = KEYS
#: The fourth, where the validation windows rotate (``learn.metrics.rotation_metrics``).
ROTATION_METRIC = "rotation_mae_deg_s"
CRITERION = ("sum over direction MAE, magnitude RMSE, detection error (1 - accuracy, "
             f"floored at {DETECTION_ERROR_FLOOR}) and, where the validation windows rotate, "
             "rotational MAE of the candidate's value over the best candidate's; lowest wins "
             "(3.0 or 4.0: best at all)")


def _value(metrics: dict[str, Any], key: str) -> float | None:
    v = metrics.get(key)
    if v is None or not np.isfinite(v):
        return None
    return max(1.0 - v, DETECTION_ERROR_FLOOR) if key == "detection_accuracy" else float(v)


def score(val_metrics: dict[str, dict[str, Any]]) -> dict[str, float]:
    """The criterion (module docstring) per candidate name; lower is better. A metric no
    candidate has is left out; a candidate without one another has scores infinity."""
    out = {name: 0.0 for name in val_metrics}
    for key in METRICS + (ROTATION_METRIC,):
        vals = {n: _value(m, key) for n, m in val_metrics.items()}
        have = [v for v in vals.values() if v is not None]
        if not have:
            continue
        best = max(min(have), 1e-9)
        for n, v in vals.items():
            out[n] += float("inf") if v is None else v / best
    return out


def select(val_metrics: dict[str, dict[str, Any]]) -> tuple[str, dict[str, float], str]:
    """The winning candidate (first of the lowest scores), all scores, and why it won."""
    if not val_metrics:
        raise ValueError("no candidate finished training; nothing to choose from")
    scores = score(val_metrics)
    winner = min(scores, key=lambda n: scores[n])   # min keeps the first of equal scores
    m = val_metrics[winner]
    others = sorted((s, n) for n, s in scores.items() if n != winner)
    runner = f"runner-up {others[0][1]} at {others[0][0]:.3f}" if others else "no rival"
    why = (f"{winner} has the lowest validation score {scores[winner]:.3f} ({runner}; "
           f"{CRITERION}) with detection "
           f"{100 * m.get('detection_accuracy', float('nan')):.1f} %, direction MAE "
           f"{m.get('direction_mae_deg', float('nan')):.1f} deg and magnitude RMSE "
           f"{m.get('magnitude_rmse_mm', float('nan')):.2f} mm on "
           f"{m.get('n_windows', 0)} validation windows")
    return winner, scores, why


def _pair_score(a: dict[str, Any], b: dict[str, Any]) -> float:
    """``a``'s criterion minus ``b``'s, scored between the two alone."""
    sc = score({"a": a, "b": b})
    return sc["a"] - sc["b"]


def _val_trials(ds: WindowSet, va: np.ndarray) -> np.ndarray:
    return np.asarray(ds.windows["trial"])[va]


def score_difference(ds: WindowSet, va: np.ndarray, results: dict[str, TrainResult],
                     a: str, b: str, n_boot: int = N_BOOT, seed: int = 0
                     ) -> tuple[float, float, float] | None:
    """``a``'s criterion minus ``b``'s on the validation trials, with its 95 % interval over
    trial resamples (negative: ``a`` better); None without two trials or predictions."""
    trial = _val_trials(ds, va)
    if np.unique(trial).size < 2 or any(results[n].val_pred is None for n in (a, b)):
        return None
    truth = (ds.velocity(va), ds.slip(va))

    w_true = ds.angular(va) if ds.has_angular(va) else None

    def metrics(name: str, idx: np.ndarray) -> dict[str, Any]:
        p = results[name].val_pred
        rot = {} if w_true is None else {
            "true_angular": w_true[idx],
            "angular": None if p.get("w") is None else np.asarray(p["w"])[idx]}
        return compute_metrics(p["prob"][idx], p["v"][idx], truth[0][idx], truth[1][idx],
                               ds.window_s, **rot)

    return paired_difference(trial, lambda idx: _pair_score(metrics(a, idx), metrics(b, idx)),
                             lambda idx: 0.0, n_boot=n_boot, seed=seed)


def worth(ds: WindowSet, va: np.ndarray, results: dict[str, TrainResult], winner: str,
          runner_up: str | None, n_boot: int = N_BOOT, seed: int = 0) -> dict[str, Any]:
    """The winner's validation figures with 95 % intervals over validation trials, and the
    winner's criterion minus the runner-up's on the same trial resamples (an interval that
    holds 0: the two cannot be told apart on these trials). Empty where a result carries no
    validation predictions (a custom trainer)."""
    trial = _val_trials(ds, va)
    if np.unique(trial).size < 2 or results[winner].val_pred is None:
        return {}
    p = results[winner].val_pred
    boot = bootstrap_metrics(trial, p["prob"], p["v"], ds.velocity(va), ds.slip(va),
                             ds.window_s, n_boot=n_boot, seed=seed)
    out: dict[str, Any] = {"n_trials": int(np.unique(trial).size), "n_boot": n_boot,
                           "winner": {k: boot.get(k) for k in METRICS},
                           "winner_ci": {k: boot.get(k + "_ci") for k in METRICS}}
    d = None if runner_up is None else score_difference(ds, va, results, winner, runner_up,
                                                        n_boot, seed)
    if d is not None:
        out["runner_up"] = runner_up
        out["score_difference"] = {"estimate": d[0], "ci": (d[1], d[2])}
        out["told_apart"] = bool(d[2] < 0.0)
    return out


def worth_line(w: dict[str, Any]) -> str:
    """One sentence on the winner's validation figures and its lead, for the comparison."""
    if not w:
        return ""
    ci = w["winner_ci"]

    def cell(k: str, scale: float, nd: int) -> str:
        v, c = w["winner"].get(k), ci.get(k)
        if v is None:
            return "-"
        return (f"{v * scale:.{nd}f}" + (f" [{c[0] * scale:.{nd}f}, {c[1] * scale:.{nd}f}]"
                                         if c else ""))
    line = (f"On the {w['n_trials']} validation trials (95 % intervals, trial bootstrap): "
            f"detection {cell('detection_accuracy', 100, 1)} %, direction MAE "
            f"{cell('direction_mae_deg', 1, 1)} deg, magnitude RMSE "
            f"{cell('magnitude_rmse_mm', 1, 2)} mm.")
    if "runner_up" in w:
        d = w["score_difference"]
        line += (f" Against the runner-up {w['runner_up']}: criterion difference "
                 f"{d['estimate']:+.3f} [{d['ci'][0]:+.3f}, {d['ci'][1]:+.3f}], "
                 + ("the winner is better on these trials." if w["told_apart"] else
                    "**the two cannot be told apart on these trials**; more validation "
                    "trials would decide."))
    return line
