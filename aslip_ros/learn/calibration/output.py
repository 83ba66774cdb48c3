"""Calibrated outputs: the decision threshold and the direction uncertainty of a model,
fitted on its validation windows and checked on held-out ones (docs/model.md).

Threshold (``choose_threshold``): the p(slip) threshold with the highest detection accuracy
on the validation windows, searched over 0.05 ... 0.95 in steps of 0.01; among equally good
thresholds the one nearest 0.5 (the paper's), so a flat optimum does not drift on noise.
With fewer than ``MIN_THRESHOLD_WINDOWS`` windows, or fewer than ``MIN_CLASS_WINDOWS`` of
either class, the threshold stays 0.5 and the document says why.

Direction sigma (``fit_sigma_model``): over validation windows labelled slip with a
non-zero true velocity, the angle between the ungated predicted velocity and the true one
(a zero prediction counts as pi/2, as in ``evaluate``). The windows are split into up to
``MAX_BINS`` bins by quantiles of the predicted speed (at least ``MIN_BIN_WINDOWS`` each);
each bin's sigma is the 68.27th percentile of its errors, so about 68 % of errors lie
within one sigma, as for a normal distribution. Slow slip gives worse directions, so sigma
may only fall with speed: adjacent bins that break that are merged and their percentile
taken again over the pooled errors. Sigmas are clipped to [``SIGMA_FLOOR_RAD``, pi].
Fewer than ``MIN_SIGMA_WINDOWS`` slip windows give no model (``None``): sigma unknown.

Angular sigma (``fit_angular_sigma``, a model with a rotational output): over validation
windows with an angular label (rotating or not), the absolute error of the raw rate
``|w_hat - wy|`` [rad/s], binned like the direction sigma by quantiles of the predicted
``|w_hat|`` (up to ``MAX_BINS`` bins of at least ``MIN_BIN_WINDOWS``); each bin's sigma is
the 68.27th percentile of its errors, floored at ``ANGULAR_SIGMA_FLOOR_RAD_S``. No
monotonicity is imposed: an absolute rate error may grow with the rate as well as fall.
Fewer than ``MIN_SIGMA_WINDOWS`` labelled windows give no model: ``angular_sigma`` -1.

``calibration_check`` measures both on any split (``aslip evaluate``: held-out test by
default): the fraction of slip windows with error <= sigma, and the expected calibration
error of p(slip) over ten equal-width probability bins; ``plot_reliability`` draws them.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from aslip_ros.slip import DEFAULT_THRESHOLD, N_VELOCITY
from aslip_ros.util import atomic_path

ONE_SIGMA = 0.6827                 # P(|x| <= sigma) of a normal distribution
THRESHOLD_GRID = np.round(np.arange(0.05, 0.9501, 0.01), 2)
MIN_THRESHOLD_WINDOWS = 50
MIN_CLASS_WINDOWS = 10
MIN_SIGMA_WINDOWS = 30
MIN_BIN_WINDOWS = 30
MAX_BINS = 4
SIGMA_FLOOR_RAD = math.radians(2.0)
#: The smallest angular sigma [rad/s] (about 1 deg/s): a perfect validation fit is not a
#: promise of a perfect estimate.
ANGULAR_SIGMA_FLOOR_RAD_S = 0.02
RELIABILITY_BINS = 10


def _arrays(prob, v_pred, v_true, slip) -> tuple[np.ndarray, ...]:
    prob = np.asarray(prob, np.float64).reshape(-1)
    v_pred = np.asarray(v_pred, np.float64).reshape(-1, N_VELOCITY)
    v_true = np.asarray(v_true, np.float64).reshape(-1, N_VELOCITY)
    slip = np.asarray(slip, bool).reshape(-1)
    if not (prob.shape[0] == v_pred.shape[0] == v_true.shape[0] == slip.shape[0]):
        raise ValueError("prob, velocities and slip labels must have the same length")
    if not (np.isfinite(prob).all() and np.isfinite(v_pred).all()
            and np.isfinite(v_true).all()):
        raise ValueError("probabilities and velocities must be finite")
    return prob, v_pred, v_true, slip


def angle_errors(v_pred, v_true) -> np.ndarray:
    """|angle| between predicted and true velocity [rad], in [0, pi]; a zero prediction
    has no direction and counts as pi/2 (neither right nor opposite)."""
    v_pred = np.asarray(v_pred, np.float64).reshape(-1, N_VELOCITY)
    v_true = np.asarray(v_true, np.float64).reshape(-1, N_VELOCITY)
    sp, st = np.linalg.norm(v_pred, axis=1), np.linalg.norm(v_true, axis=1)
    cos = (v_pred * v_true).sum(1) / np.maximum(sp * st, 1e-300)
    err = np.arccos(np.clip(cos, -1.0, 1.0))
    err[sp == 0] = math.pi / 2
    return err


def direction_rows(v_true, slip) -> np.ndarray:
    """The windows whose direction is scored: labelled slip with a non-zero true velocity."""
    return np.asarray(slip, bool) & (np.linalg.norm(np.asarray(v_true).reshape(-1, N_VELOCITY),
                                                    axis=1) > 0)


# --- threshold ------------------------------------------------------------------------------

def choose_threshold(prob, slip) -> dict[str, Any]:
    """The decision threshold of the module docstring, with its accuracy and the reason."""
    prob = np.asarray(prob, np.float64).reshape(-1)
    slip = np.asarray(slip, bool).reshape(-1)
    n, n_pos = int(prob.size), int(slip.sum())
    out: dict[str, Any] = {"criterion": "max validation detection accuracy, ties toward 0.5",
                           "n_windows": n, "n_slip": n_pos}
    if n < MIN_THRESHOLD_WINDOWS or min(n_pos, n - n_pos) < MIN_CLASS_WINDOWS:
        out.update(threshold=DEFAULT_THRESHOLD, accuracy=None,
                   note=f"kept {DEFAULT_THRESHOLD}: too few validation windows (need "
                        f">= {MIN_THRESHOLD_WINDOWS}, >= {MIN_CLASS_WINDOWS} of each class)")
        return out
    acc = ((prob[None, :] >= THRESHOLD_GRID[:, None]) == slip[None, :]).mean(axis=1)
    best = np.flatnonzero(acc >= acc.max() - 1e-12)
    pick = best[np.argmin(np.abs(THRESHOLD_GRID[best] - DEFAULT_THRESHOLD))]
    out.update(threshold=float(THRESHOLD_GRID[pick]), accuracy=float(acc[pick]),
               accuracy_at_default=float(((prob >= DEFAULT_THRESHOLD) == slip).mean()))
    return out


# --- direction sigma ------------------------------------------------------------------------

class SigmaModel:
    """One-sigma direction error [rad] as a step function of the predicted speed [m/s]."""

    def __init__(self, speed_edges: Sequence[float], sigma: Sequence[float]) -> None:
        self.edges = np.asarray(speed_edges, np.float64).reshape(-1)
        self.sigma = np.asarray(sigma, np.float64).reshape(-1)
        problems = sigma_problems({"speed_edges_m_s": self.edges.tolist(),
                                   "sigma_rad": self.sigma.tolist()})
        if problems:
            raise ValueError("; ".join(problems))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SigmaModel":
        return cls(d["speed_edges_m_s"], d["sigma_rad"])

    def bins(self, speed) -> np.ndarray:
        return np.searchsorted(self.edges, np.asarray(speed, np.float64), side="right")

    def __call__(self, speed) -> np.ndarray:
        """Sigma per predicted speed; a non-finite speed gets pi (no direction known)."""
        s = np.asarray(speed, np.float64)
        out = self.sigma[self.bins(np.where(np.isfinite(s), s, 0.0))]
        return np.where(np.isfinite(s), out, math.pi)


def _bin_sigmas(err: np.ndarray, speed: np.ndarray, edges: list[float]) -> np.ndarray:
    b = np.searchsorted(np.asarray(edges), speed, side="right")
    return np.array([np.quantile(err[b == k], ONE_SIGMA) for k in range(len(edges) + 1)])


def _quantile_edges(x: np.ndarray) -> list[float]:
    """Edges of up to ``MAX_BINS`` bins of ``x`` at its quantiles, at least
    ``MIN_BIN_WINDOWS`` values each, none empty."""
    k = max(1, min(MAX_BINS, x.size // MIN_BIN_WINDOWS))
    edges = sorted(set(float(e) for e in np.quantile(x, np.arange(1, k) / k)))
    while True:                   # tied values can leave a bin empty: drop its edge
        counts = np.bincount(np.searchsorted(np.asarray(edges), x, side="right"),
                             minlength=len(edges) + 1)
        if counts.all():
            return edges
        j = int(np.flatnonzero(counts == 0)[0])
        del edges[max(j - 1, 0)]


def fit_sigma_model(v_pred, v_true, slip) -> dict[str, Any]:
    """The direction-uncertainty model of the module docstring, as a JSON-able dict;
    ``{"model": None, "note": ...}`` when there are too few slip windows."""
    m = direction_rows(v_true, slip)
    err = angle_errors(np.asarray(v_pred).reshape(-1, N_VELOCITY)[m],
                       np.asarray(v_true).reshape(-1, N_VELOCITY)[m])
    speed = np.linalg.norm(np.asarray(v_pred, np.float64).reshape(-1, N_VELOCITY)[m], axis=1)
    n = int(err.size)
    if n < MIN_SIGMA_WINDOWS:
        return {"model": None, "n_slip_windows": n,
                "note": f"no sigma model: {n} validation slip windows (need "
                        f">= {MIN_SIGMA_WINDOWS}); direction_sigma stays unknown (-1)"}
    edges = _quantile_edges(speed)
    sig = _bin_sigmas(err, speed, edges)
    while len(edges) and np.any(np.diff(sig) > 0):    # slower must not be surer: pool
        j = int(np.flatnonzero(np.diff(sig) > 0)[0])
        del edges[j]
        sig = _bin_sigmas(err, speed, edges)
    sig = np.clip(sig, SIGMA_FLOOR_RAD, math.pi)
    counts = np.bincount(np.searchsorted(np.asarray(edges), speed, side="right"),
                         minlength=len(edges) + 1)
    return {"model": {"speed_edges_m_s": edges, "sigma_rad": sig.tolist(),
                      "quantile": ONE_SIGMA, "floor_rad": SIGMA_FLOOR_RAD,
                      "bin_counts": counts.tolist()},
            "n_slip_windows": n}


def _binned_problems(d: Any, what: str, edges_key: str, sigma_key: str, sigma_ok,
                     sigma_want: str, edges_want: str) -> list[str]:
    """What is wrong with a binned sigma document: ``sigma_key`` a non-empty list of numbers
    that ``sigma_ok`` accepts, ``edges_key`` one fewer increasing values >= 0."""
    if not isinstance(d, dict):
        return [f"{what} sigma model must be a JSON object, got {type(d).__name__}"]
    edges, sig = d.get(edges_key), d.get(sigma_key)
    num = (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)
           and math.isfinite(v))
    if not isinstance(sig, list) or not sig or not all(num(v) and sigma_ok(v) for v in sig):
        return [f"{sigma_key} must be a non-empty list of {sigma_want}, got {sig!r}"]
    if not isinstance(edges, list) or not all(num(e) and e >= 0 for e in edges) \
            or any(b <= a for a, b in zip(edges, edges[1:])) or len(edges) != len(sig) - 1:
        return [f"{edges_key} must be {len(sig) - 1} increasing {edges_want} >= 0, "
                f"got {edges!r}"]
    return []


def sigma_problems(d: Any) -> list[str]:
    """What is wrong with a sigma model document (empty when sound)."""
    return _binned_problems(d, "direction", "speed_edges_m_s", "sigma_rad",
                            lambda v: 0 < v <= math.pi + 1e-9, "numbers in (0, pi]", "speeds")


def meta_problems(d: Any) -> list[str]:
    """What is wrong with a checkpoint's ``output_calibration`` document."""
    if not isinstance(d, dict):
        return [f"output_calibration must be a JSON object, got {type(d).__name__}"]
    t = d.get("threshold")
    problems = [] if isinstance(t, (int, float)) and not isinstance(t, bool) \
        and 0.0 <= t <= 1.0 else [f"output_calibration.threshold must be in [0, 1], got {t!r}"]
    model = (d.get("direction_sigma") or {}).get("model") \
        if isinstance(d.get("direction_sigma"), dict) else "missing"
    if model == "missing":
        problems.append("output_calibration.direction_sigma must be a JSON object")
    elif model is not None:
        problems += [f"output_calibration: {p}" for p in sigma_problems(model)]
    ang = d.get("angular_sigma")
    if ang is not None:
        if not isinstance(ang, dict):
            problems.append("output_calibration.angular_sigma must be a JSON object")
        elif ang.get("model") is not None:
            problems += [f"output_calibration: {p}"
                         for p in angular_sigma_problems(ang["model"])]
    return problems


def sigma_model(meta: dict[str, Any]) -> SigmaModel | None:
    """The checkpoint's sigma model (None when it has none: older checkpoints too)."""
    d = (meta.get("output_calibration") or {}).get("direction_sigma") or {}
    return None if d.get("model") is None else SigmaModel.from_dict(d["model"])


# --- angular sigma --------------------------------------------------------------------------

class AngularSigmaModel:
    """One-sigma error of the rotational rate [rad/s] as a step function of the predicted
    ``|w_hat|`` [rad/s]."""

    def __init__(self, rate_edges: Sequence[float], sigma: Sequence[float]) -> None:
        self.edges = np.asarray(rate_edges, np.float64).reshape(-1)
        self.sigma = np.asarray(sigma, np.float64).reshape(-1)
        problems = angular_sigma_problems({"rate_edges_rad_s": self.edges.tolist(),
                                           "sigma_rad_s": self.sigma.tolist()})
        if problems:
            raise ValueError("; ".join(problems))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "AngularSigmaModel":
        return cls(d["rate_edges_rad_s"], d["sigma_rad_s"])

    def bins(self, rate) -> np.ndarray:
        return np.searchsorted(self.edges, np.abs(np.asarray(rate, np.float64)), side="right")

    def __call__(self, rate) -> np.ndarray:
        """Sigma per predicted rate (its sign does not matter); a non-finite rate gets the
        largest sigma."""
        r = np.asarray(rate, np.float64)
        out = self.sigma[self.bins(np.where(np.isfinite(r), r, 0.0))]
        return np.where(np.isfinite(r), out, self.sigma.max())


def fit_angular_sigma(w_pred, w_true) -> dict[str, Any]:
    """The angular-uncertainty model of the module docstring from the raw predicted rates
    and the labels (rad/s; NaN: no label), as a JSON-able dict; ``{"model": None, "note":
    ...}`` when too few windows have a label."""
    w_pred = np.asarray(w_pred, np.float64).reshape(-1)
    w_true = np.asarray(w_true, np.float64).reshape(-1)
    if w_pred.shape != w_true.shape or not np.isfinite(w_pred).all():
        raise ValueError("predicted rates must be finite, one per label")
    m = np.isfinite(w_true)
    n = int(m.sum())
    if n < MIN_SIGMA_WINDOWS:
        return {"model": None, "n_windows": n,
                "note": f"no angular sigma model: {n} validation windows with an angular "
                        f"label (need >= {MIN_SIGMA_WINDOWS}); angular_sigma stays unknown "
                        "(-1)"}
    err, rate = np.abs(w_pred[m] - w_true[m]), np.abs(w_pred[m])
    edges = _quantile_edges(rate)
    sig = np.maximum(_bin_sigmas(err, rate, edges), ANGULAR_SIGMA_FLOOR_RAD_S)
    counts = np.bincount(np.searchsorted(np.asarray(edges), rate, side="right"),
                         minlength=len(edges) + 1)
    return {"model": {"rate_edges_rad_s": edges, "sigma_rad_s": sig.tolist(),
                      "quantile": ONE_SIGMA, "floor_rad_s": ANGULAR_SIGMA_FLOOR_RAD_S,
                      "bin_counts": counts.tolist()},
            "n_windows": n}


def angular_sigma_problems(d: Any) -> list[str]:
    """What is wrong with an angular sigma model document (empty when sound)."""
    return _binned_problems(d, "angular", "rate_edges_rad_s", "sigma_rad_s", lambda v: v > 0,
                            "positive numbers", "rates")


def angular_sigma_model(meta: dict[str, Any]) -> AngularSigmaModel | None:
    """The checkpoint's angular sigma model (None when it has none: a model without a
    rotational output, or one trained before it existed)."""
    d = (meta.get("output_calibration") or {}).get("angular_sigma") or {}
    return None if d.get("model") is None else AngularSigmaModel.from_dict(d["model"])


def angular_coverage(model: AngularSigmaModel, w_pred, w_true) -> dict[str, Any]:
    """Fraction of windows with an angular label whose rate error is <= their sigma,
    overall and per bin (None where there are no windows)."""
    w_pred = np.asarray(w_pred, np.float64).reshape(-1)
    w_true = np.asarray(w_true, np.float64).reshape(-1)
    m = np.isfinite(w_true)
    inside = np.abs(w_pred[m] - w_true[m]) <= model(w_pred[m])
    b = model.bins(w_pred[m])
    per_bin = [{"sigma_rad_s": float(s), "n": int((b == k).sum()),
                "coverage": float(inside[b == k].mean()) if (b == k).any() else None}
               for k, s in enumerate(model.sigma)]
    return {"coverage": float(inside.mean()) if inside.size else None, "n": int(inside.size),
            "target": ONE_SIGMA, "per_bin": per_bin}


# --- checks ---------------------------------------------------------------------------------

def sigma_coverage(model: SigmaModel, v_pred, v_true, slip) -> dict[str, Any]:
    """Fraction of scored slip windows whose direction error is <= their sigma, overall and
    per speed bin (None where there are no windows)."""
    m = direction_rows(v_true, slip)
    vp = np.asarray(v_pred, np.float64).reshape(-1, N_VELOCITY)[m]
    err = angle_errors(vp, np.asarray(v_true).reshape(-1, N_VELOCITY)[m])
    speed = np.linalg.norm(vp, axis=1)
    inside = err <= model(speed)
    b = model.bins(speed)
    per_bin = [{"sigma_deg": math.degrees(s), "n": int((b == k).sum()),
                "coverage": float(inside[b == k].mean()) if (b == k).any() else None}
               for k, s in enumerate(model.sigma)]
    return {"coverage": float(inside.mean()) if err.size else None, "n": int(err.size),
            "target": ONE_SIGMA, "per_bin": per_bin}


def reliability(prob, slip, n_bins: int = RELIABILITY_BINS) -> dict[str, Any]:
    """p(slip) in equal-width bins against the observed slip frequency; the expected
    calibration error is the count-weighted mean |frequency - mean p| over the bins."""
    prob = np.asarray(prob, np.float64).reshape(-1)
    slip = np.asarray(slip, bool).reshape(-1)
    b = np.minimum((prob * n_bins).astype(int), n_bins - 1)
    bins, ece = [], 0.0
    for k in range(n_bins):
        sel = b == k
        n = int(sel.sum())
        row = {"lo": k / n_bins, "hi": (k + 1) / n_bins, "n": n, "mean_p": None, "freq": None}
        if n:
            row.update(mean_p=float(prob[sel].mean()), freq=float(slip[sel].mean()))
            ece += n * abs(row["freq"] - row["mean_p"])
        bins.append(row)
    return {"bins": bins, "ece": float(ece / prob.size) if prob.size else None}


def calibration_check(prob, v_pred, v_true, slip, model: SigmaModel | None, *,
                      w_pred=None, w_true=None,
                      angular_model: AngularSigmaModel | None = None) -> dict[str, Any]:
    """Reliability of p(slip) and, with a model, the sigma coverage on these windows; with
    an ``angular_model``, the raw rates ``w_pred`` and the labels ``w_true`` (rad/s, NaN: no
    label), the angular sigma coverage (``angular_sigma``)."""
    prob, v_pred, v_true, slip = _arrays(prob, v_pred, v_true, slip)
    rel = reliability(prob, slip)
    out = {"n_windows": int(prob.size), "ece": rel["ece"], "reliability": rel["bins"],
           "sigma": None if model is None else sigma_coverage(model, v_pred, v_true, slip)}
    if angular_model is not None and w_pred is not None and w_true is not None:
        out["angular_sigma"] = angular_coverage(angular_model, w_pred, w_true)
    return out


def fit_output_calibration(prob, v_pred, v_true, slip, threshold: float | None = None,
                           criterion: str = "", *, w_pred=None, w_true=None) -> dict[str, Any]:
    """Threshold and direction-sigma model from VALIDATION windows (module docstring):
    ``prob`` (n,), ungated predicted velocity ``v_pred`` (n, 2) and true velocity
    ``v_true`` (n, 2) in m/s, slip labels (n,). A trainer with a criterion of its own
    passes its ``threshold`` and names the ``criterion``. A model with a rotational output
    passes its raw rates ``w_pred`` (n,) and the labels ``w_true`` (n,, rad/s, NaN: none or
    None) for the angular sigma model (``angular_sigma``). Returns the checkpoint's JSON
    document."""
    prob, v_pred, v_true, slip = _arrays(prob, v_pred, v_true, slip)
    thr = choose_threshold(prob, slip) if threshold is None else {
        "threshold": float(threshold), "criterion": criterion or "chosen by the trainer",
        "n_windows": int(prob.size), "n_slip": int(slip.sum())}
    sig = fit_sigma_model(v_pred, v_true, slip)
    model = None if sig["model"] is None else SigmaModel.from_dict(sig["model"])
    check = calibration_check(prob, v_pred, v_true, slip, model)
    doc = {"threshold": thr["threshold"], "threshold_fit": thr, "direction_sigma": sig,
           "validation": {"n_windows": check["n_windows"], "ece": check["ece"],
                          "sigma_coverage": None if model is None
                          else check["sigma"]["coverage"]}}
    if w_pred is not None:
        labels = np.full(prob.size, np.nan) if w_true is None else w_true
        doc["angular_sigma"] = fit_angular_sigma(w_pred, labels)
    return doc


def plot_reliability(path: str | os.PathLike, check: dict[str, Any], title: str = "") -> Path:
    """The reliability diagram (and the sigma coverage per speed bin when measured) as a
    PNG, written atomically."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    has_sigma = check.get("sigma") is not None and check["sigma"]["n"] > 0
    fig, axes = plt.subplots(1, 2 if has_sigma else 1, figsize=(10 if has_sigma else 5, 4.2),
                             squeeze=False)
    ax = axes[0, 0]
    ax.plot([0, 1], [0, 1], "--", color="grey", lw=1, label="perfectly calibrated")
    for row in check["reliability"]:
        if row["n"]:
            ax.bar((row["lo"] + row["hi"]) / 2, row["freq"], width=row["hi"] - row["lo"],
                   color="tab:blue", alpha=0.6, edgecolor="black", lw=0.5)
            ax.text((row["lo"] + row["hi"]) / 2, min(row["freq"] + 0.02, 0.95),
                    str(row["n"]), ha="center", fontsize=7)
    ece = check["ece"] or 0.0
    ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="predicted p(slip)",
           ylabel="observed slip frequency",
           title=f"reliability (ECE {ece:.3f}, n {check['n_windows']})")
    ax.legend(loc="upper left", fontsize=8)
    if has_sigma:
        s = check["sigma"]
        ax = axes[0, 1]
        rows = [r for r in s["per_bin"] if r["n"]]
        ax.bar(range(len(rows)), [r["coverage"] for r in rows], color="tab:orange",
               alpha=0.7, edgecolor="black", lw=0.5)
        ax.axhline(s["target"], color="grey", ls="--", lw=1, label="target 68.3 %")
        ax.set_xticks(range(len(rows)), [f"sigma {r['sigma_deg']:.0f} deg\nn {r['n']}"
                                         for r in rows], fontsize=7)
        ax.set(ylim=(0, 1), ylabel="fraction of slip windows with error <= sigma",
               title=f"direction sigma coverage {s['coverage']:.1%} (n {s['n']})")
        ax.legend(loc="lower right", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return path


def checkpoint_fields(prob, v_pred, v_true, slip, *, w_pred=None,
                      w_true=None) -> dict[str, Any]:
    """The checkpoint keys a trainer sets from its validation predictions: the fitted
    ``output_calibration`` and the ``threshold`` it chose (``w_pred``/``w_true``: the raw
    rates and angular labels of a model with a rotational output)."""
    doc = fit_output_calibration(prob, v_pred, v_true, slip, w_pred=w_pred, w_true=w_true)
    return {"output_calibration": doc, "threshold": doc["threshold"]}


def sequence_fields(outputs, seqs, threshold: float,
                    criterion: str = "validation false alarms per minute "
                                     "(threshold_selection)") -> dict[str, Any]:
    """``checkpoint_fields`` for a per-frame model validated on whole trials (the streaming
    trainer): per trial ``(p, v, w)`` outputs (``w`` None without a rotational output) and
    ``seqs`` with per-trial ``v``, ``slip``, ``valid`` (label) and ``w`` (angular label,
    NaN: none) arrays. The model keeps the ``threshold`` its trainer chose by
    ``criterion``; the sigma models are fitted here on the valid frames."""
    def cat(xs, i=None):
        return np.concatenate([np.asarray(x if i is None else x[i])[np.asarray(m, bool)]
                               for x, m in zip(xs, seqs.valid)] or [np.zeros((0, 2))])
    angular = bool(outputs) and all(o[2] is not None for o in outputs)
    rates = {"w_pred": cat(outputs, 2).reshape(-1),
             "w_true": cat(seqs.w).reshape(-1)} if angular else {}
    return {"output_calibration": fit_output_calibration(
        cat(outputs, 0).reshape(-1), cat(outputs, 1), cat(seqs.v), cat(seqs.slip).reshape(-1),
        threshold, criterion, **rates)}
