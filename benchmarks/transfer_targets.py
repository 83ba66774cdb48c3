"""The transfer protocol's target: does the package's method beat the best baseline?

For each cell (train scene -> test scene) ``aslip`` is compared with the best baseline of each
metric (``BASELINES``: the paper's SVM and the plain log-mel CNN and SVM). The target of a
cell is met when ``aslip`` is at least ``TARGET`` (20 %) better than that baseline in
direction MAE and in magnitude RMSE, with 95 % trial-bootstrap intervals that do not overlap,
and its detection accuracy is at least as high. The improvement ``1 - aslip / baseline`` and
the detection difference also get paired intervals: both methods are scored on the same
resamples of test trials, since they saw the same trials.
"""

from __future__ import annotations

from typing import Any

import numpy as np

BASELINES = ("paper_svm", "plain_cnn", "plain_svm")
#: The plain baselines alone (no per-grasp calibration, no handcrafted features).
PLAIN = ("plain_cnn", "plain_svm")
TARGET = 0.2
_LEVEL = 95.0


def _metrics(p: dict[str, np.ndarray], idx: np.ndarray | None = None) -> dict[str, float]:
    from aslip_ros.learn.metrics import compute_metrics
    arrays = [p[k] if idx is None else p[k][idx]
              for k in ("prob", "raw_velocity", "true_velocity", "slip")]
    m = compute_metrics(*arrays, float(p["window_s"]))
    return {k: m.get(k, np.nan) for k in
            ("detection_accuracy", "direction_mae_deg", "magnitude_rmse_mm")}


def _same_windows(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    return (a["trial"].shape == b["trial"].shape and np.array_equal(a["trial"], b["trial"])
            and np.allclose(a["true_velocity"], b["true_velocity"]))


def _interval(values: list[float]) -> tuple[float, float]:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (float("nan"), float("nan"))
    lo, hi = np.percentile(v, [(100.0 - _LEVEL) / 2, (100.0 + _LEVEL) / 2])
    return float(lo), float(hi)


def targets(preds: dict[str, dict[str, np.ndarray]], n_boot: int = 500,
            seed: int = 0, baselines: tuple[str, ...] = BASELINES) -> dict[str, Any] | None:
    """``aslip`` against the best of ``baselines`` per metric on one cell's predictions (per
    method, the arrays of ``transfer.predict``); None without ``aslip`` or a baseline."""
    if "aslip" not in preds:
        return None
    base = [m for m in baselines if m in preds and _same_windows(preds[m], preds["aslip"])]
    if not base:
        return None
    trial = preds["aslip"]["trial"]
    ids = np.unique(trial)
    members = [np.flatnonzero(trial == t) for t in ids]
    rng = np.random.default_rng(seed)
    full = {m: _metrics(preds[m]) for m in ["aslip"] + base}
    boots: dict[str, list[dict[str, float]]] = {m: [] for m in full}
    for _ in range(n_boot):
        idx = np.concatenate([members[k] for k in rng.integers(0, ids.size, ids.size)])
        for m in full:
            boots[m].append(_metrics(preds[m], idx))
    out: dict[str, Any] = {"n_trials": int(ids.size)}
    for key in ("detection_accuracy", "direction_mae_deg", "magnitude_rmse_mm"):
        higher = key == "detection_accuracy"
        have = [m for m in base if np.isfinite(full[m][key])]
        if not have or not np.isfinite(full["aslip"][key]):
            out[key] = None
            continue
        best = (max if higher else min)(have, key=lambda m: full[m][key])
        a = [b[key] for b in boots["aslip"]]
        o = [b[key] for b in boots[best]]
        a_ci, o_ci = _interval(a), _interval(o)
        if higher:
            gain = full["aslip"][key] - full[best][key]
            paired = _interval([x - y for x, y in zip(a, o)])
            met = gain >= 0.0
        else:
            gain = 1.0 - full["aslip"][key] / full[best][key]
            paired = _interval([1.0 - x / y for x, y in zip(a, o) if y > 0])
            met = gain >= TARGET and a_ci[1] < o_ci[0]
        out[key] = {"baseline": best, "aslip": full["aslip"][key], "aslip_ci": a_ci,
                    "baseline_value": full[best][key], "baseline_ci": o_ci,
                    "gain": float(gain), "gain_ci": paired,
                    "separated": bool(a_ci[0] > o_ci[1] if higher else a_ci[1] < o_ci[0]),
                    "met": bool(met)}
    out["met"] = all(out[k] is not None and out[k]["met"] for k in
                     ("detection_accuracy", "direction_mae_deg", "magnitude_rmse_mm"))
    return out


def targets_markdown(all_targets: dict[str, Any],
                     against: str = "the best baseline (paper SVM, plain CNN, plain SVM)"
                     ) -> list[str]:
    """The target table: one row per cell."""
    rows = [(c, t) for c, t in all_targets.items() if t]
    if not rows:
        return []
    lines = [f"## Target: `aslip` against {against}, per metric", "",
             f"Improvement = 1 - aslip / baseline [paired 95 % interval over the same trial "
             f"resamples]; met: >= {TARGET:.0%} better in direction and magnitude with "
             "separated intervals, and detection at least as high (difference in points).",
             "", "| cell | detection (pp) | direction | magnitude | met |",
             "|---|---|---|---|---|"]
    for cell, t in rows:
        out = []
        for key, scale, unit in (("detection_accuracy", 100.0, " pp"),
                                 ("direction_mae_deg", 100.0, " %"),
                                 ("magnitude_rmse_mm", 100.0, " %")):
            r = t.get(key)
            if r is None:
                out.append("n/a")
                continue
            lo, hi = r["gain_ci"]
            sep = "" if r["separated"] else ", cannot be told apart"
            out.append(f"{r['gain'] * scale:+.1f}{unit} [{lo * scale:+.1f}, {hi * scale:+.1f}] "
                       f"vs {r['baseline']}{sep}")
        lines.append(f"| {cell} | " + " | ".join(out) + f" | {'yes' if t['met'] else 'no'} |")
    lines.append("")
    return lines
