"""Where the speed error is: the slip-speed error of every model of a ``benchmarks.magnitude``
cell, split by stratum, so that one sees where the package CNN loses to the direct regressor.

All numbers are on the test scene's *true-slip windows* (the dataset's slip label and a true
speed above 0: the windows ``learn.metrics.compute_metrics`` scores the magnitude on), ungated
(the model's raw speed whatever its p(slip)). Per window the displacement error is
``(s_hat - s*) * window_s`` in mm, ``s`` the norm of the planar velocity; a stratum's
*RMSE* is the root mean square of it (``compute_metrics``' ``magnitude_rmse_mm`` over the
stratum's windows) and its *bias* the mean (+: the model is too fast). Strata:

- ``object``: the test dataset's manifest object of each window's trial (the predictions'
  ``trial`` is the index into ``manifest["trials"]``, as in ``learn.data_io``);
- ``speed``: terciles of the true speed over the scored windows (slow / middle / fast);
- ``loudness``: terciles of the trials' loudness (quiet / middle / loud), a trial's
  loudness being its mean audio power over all samples and microphones, dB re full scale
  (the dataset's audio through ``learn.data_io``).

A stratum with at least ``MIN_TRIALS_CI`` trials gets 95 % trial-bootstrap intervals
(``learn.stats.resamples``: whole trials of the stratum resampled) and, where the cell has
both models of ``PAIR``, their paired RMSE difference on the same resamples
(``learn.stats.paired_difference``). Overall, per model: the *scale* (mean predicted over
mean true speed: below 1 the model shrinks towards slow), the Spearman rank correlation of
predicted and true speed, and the *oracle scale*: the one factor that, times the model's
speeds, fits the true speeds of the TEST windows in least squares, and the RMSE at it. The
oracle uses the test labels, which no deployed model has: it is a diagnostic only. A model
whose RMSE falls to the others' at its oracle scale loses on scale (or bias); one that stays
behind loses on ranking (it does not tell fast windows from slow ones).

``benchmarks.magnitude`` calls ``cell_breakdown`` for each cell and ``where_markdown`` for
its report; this module imports nothing of it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

#: A stratum gets bootstrap intervals (and the paired difference) from this many trials.
MIN_TRIALS_CI = 5
#: The paired RMSE difference shown per stratum: the package CNN minus the direct SVR.
PAIR = ("recipe", "plain_svm")
SPEED_NAMES = ("slow", "middle", "fast")
LOUDNESS_NAMES = ("quiet", "middle", "loud")
LEVEL = 0.95


def speeds(p: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scored (true-slip) windows of predictions ``p`` as a boolean mask, and the
    predicted and true speeds [m/s] of all windows."""
    from aslip_ros.slip import N_VELOCITY
    s_hat = np.linalg.norm(np.asarray(p["raw_velocity"], np.float64).reshape(-1, N_VELOCITY),
                           axis=1)
    s_true = np.linalg.norm(np.asarray(p["true_velocity"], np.float64)
                            .reshape(-1, N_VELOCITY), axis=1)
    return np.asarray(p["slip"], bool).reshape(-1) & (s_true > 0), s_hat, s_true


def trial_facts(test_ds: str | Path, trials: Sequence[int]
                ) -> tuple[np.ndarray, np.ndarray]:
    """Per manifest trial of ``test_ds``: its object (str array over all trials) and the
    loudness of the trials ``trials`` (mean audio power over all samples and microphones,
    dB re full scale; NaN for the others)."""
    from aslip_ros.learn.data_io import open_dataset
    ds = open_dataset(test_ds)
    objects = np.array([str(t.get("object", "")) for t in ds.trials], dtype=object)
    loud = np.full(len(ds.trials), np.nan)
    for k in np.unique(np.asarray(trials, dtype=np.int64)):
        loud[k] = 10.0 * np.log10(np.mean(np.square(ds.audio(int(k)), dtype=np.float64)))
    ds.release_audio()
    return objects, loud


def tercile(values: np.ndarray, edges_from: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two tercile edges of ``edges_from`` and each of ``values``' tercile (0, 1, 2;
    a value on an edge goes up)."""
    edges = np.quantile(np.asarray(edges_from, np.float64), [1.0 / 3.0, 2.0 / 3.0])
    return edges, np.digitize(values, edges)


def _rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(e)))) if e.size else float("nan")


def error_stats(e_mm: np.ndarray, trial: np.ndarray, *, n_boot: int, seed: int = 0
                ) -> dict[str, Any]:
    """RMSE and bias of the per-window signed errors ``e_mm`` [mm]; with at least
    ``MIN_TRIALS_CI`` trials their trial-bootstrap intervals (``_ci``: low, high)."""
    from aslip_ros.learn.stats import resamples
    n_trials = int(np.unique(trial).size)
    out: dict[str, Any] = {"n_windows": int(e_mm.size), "n_trials": n_trials,
                           "rmse_mm": _rmse(e_mm), "bias_mm": float(np.mean(e_mm))}
    if n_trials >= MIN_TRIALS_CI and n_boot > 0:
        boot = np.array([(_rmse(e_mm[idx]), np.mean(e_mm[idx]))
                         for idx in resamples(trial, n_boot, seed)])
        lo, hi = np.percentile(boot, [50.0 * (1.0 - LEVEL), 50.0 * (1.0 + LEVEL)], axis=0)
        out["rmse_mm_ci"] = (float(lo[0]), float(hi[0]))
        out["bias_mm_ci"] = (float(lo[1]), float(hi[1]))
    return out


def scale_stats(s_hat: np.ndarray, s_true: np.ndarray, window_s: float) -> dict[str, float]:
    """Shrinkage and ranking of predicted speeds ``s_hat`` against ``s_true`` [m/s]: the mean
    ratio, the Spearman rank correlation, the least-squares factor ``k`` of
    ``s_true ~ k s_hat`` and the RMSE [mm] of ``k s_hat`` (the oracle scale, fitted on the
    very windows it is scored on: diagnostic only)."""
    from scipy.stats import spearmanr
    k = float(np.linalg.lstsq(s_hat[:, None], s_true, rcond=None)[0][0])
    rho = spearmanr(s_hat, s_true)[0] if s_hat.size > 1 else np.nan
    return {"scale_ratio": float(np.mean(s_hat) / np.mean(s_true)),
            "rank_corr": float(rho), "oracle_scale": k,
            "oracle_rmse_mm": _rmse((k * s_hat - s_true) * window_s * 1e3)}


def _same_windows(preds: dict[str, dict[str, np.ndarray]]) -> None:
    ref = next(iter(preds.values()))
    for name, p in preds.items():
        if not all(np.array_equal(np.asarray(p[k]), np.asarray(ref[k]))
                   for k in ("trial", "slip", "true_velocity")):
            raise ValueError(f"{name}: the breakdown needs every model's predictions of the "
                             "same windows")


def breakdown(preds: dict[str, dict[str, np.ndarray]], objects: Sequence[str],
              loudness_db: np.ndarray, *, n_boot: int = 500, seed: int = 0,
              pair: tuple[str, str] = PAIR) -> dict[str, Any]:
    """The speed error of every model of ``preds`` (name -> cached predictions of the same
    windows), overall and by stratum. ``objects[k]`` and ``loudness_db[k]``: manifest trial
    ``k``'s object and loudness (``trial_facts``).

    Returns ``n_windows``, ``n_trials``, ``speed_edges_mm_s``, ``loudness_edges_db``,
    ``overall`` (model -> ``error_stats`` and ``scale_stats``) and ``strata`` (kind ->
    stratum -> ``n_windows``, ``n_trials``, ``mean_true_mm_s``, ``models`` (model ->
    ``error_stats``) and, where both models of ``pair`` are there and the stratum has
    ``MIN_TRIALS_CI`` trials, ``pair`` and ``pair_rmse_diff_mm`` (estimate, low, high))."""
    from aslip_ros.learn.stats import paired_difference
    if not preds:
        raise ValueError("no predictions")
    _same_windows(preds)
    ref = next(iter(preds.values()))
    m, _, s_true = speeds(ref)
    if not m.any():
        raise ValueError("no true-slip window to score the speed on")
    w = float(ref["window_s"])
    trial = np.asarray(ref["trial"], np.int64)[m]
    s_true = s_true[m]
    err = {name: (speeds(p)[1][m] - s_true) * w * 1e3 for name, p in preds.items()}
    loud = np.asarray(loudness_db, np.float64)
    scored = np.unique(trial)
    speed_edges, speed_t = tercile(s_true, s_true)
    loud_edges, loud_t = tercile(loud[trial], loud[scored])
    groups = {"object": np.asarray(objects, dtype=object)[trial],
              "speed": np.array(SPEED_NAMES, dtype=object)[speed_t],
              "loudness": np.array(LOUDNESS_NAMES, dtype=object)[loud_t]}
    order = {"object": sorted(set(groups["object"].tolist())), "speed": SPEED_NAMES,
             "loudness": LOUDNESS_NAMES}

    def rmse_of(name: str, sel: np.ndarray) -> Callable[[np.ndarray], float]:
        return lambda idx: _rmse(err[name][sel][idx])

    strata: dict[str, dict[str, Any]] = {}
    for kind, g in groups.items():
        strata[kind] = {}
        for value in order[kind]:
            sel = np.flatnonzero(g == value)
            if not sel.size:
                continue
            st = {"n_windows": int(sel.size), "n_trials": int(np.unique(trial[sel]).size),
                  "mean_true_mm_s": float(np.mean(s_true[sel]) * 1e3),
                  "models": {name: error_stats(e[sel], trial[sel], n_boot=n_boot, seed=seed)
                             for name, e in err.items()}}
            if all(n in err for n in pair) and st["n_trials"] >= MIN_TRIALS_CI and n_boot > 0:
                st["pair"] = list(pair)
                st["pair_rmse_diff_mm"] = paired_difference(
                    trial[sel], rmse_of(pair[0], sel), rmse_of(pair[1], sel),
                    n_boot=n_boot, seed=seed, level=LEVEL)
            strata[kind][value] = st
    overall = {name: {**error_stats(e, trial, n_boot=n_boot, seed=seed),
                      **scale_stats(speeds(preds[name])[1][m], s_true, w)}
               for name, e in err.items()}
    return {"n_windows": int(m.sum()), "n_trials": int(scored.size),
            "mean_true_mm_s": float(np.mean(s_true) * 1e3),
            "speed_edges_mm_s": [float(x * 1e3) for x in speed_edges],
            "loudness_edges_db": [float(x) for x in loud_edges],
            "overall": overall, "strata": strata}


def cell_breakdown(preds: dict[str, dict[str, np.ndarray]], test_ds: str | Path, *,
                   n_boot: int = 500, seed: int = 0) -> dict[str, Any]:
    """``breakdown`` of a cell's predictions on the exported dataset ``test_ds``."""
    ref = next(iter(preds.values()))
    objects, loud = trial_facts(test_ds, np.unique(ref["trial"]))
    return breakdown(preds, objects, loud, n_boot=n_boot, seed=seed)


# --- report -------------------------------------------------------------------------------

def _ci(d: dict[str, Any], key: str) -> str:
    v = d.get(key)
    if v is None or not np.isfinite(v):
        return "n/a"
    sign = "+" if key.startswith("bias") else ""
    ci = d.get(key + "_ci")
    return f"{v:{sign}.2f}" + ("" if ci is None else f" [{ci[0]:{sign}.2f}, {ci[1]:{sign}.2f}]")


def _pair(d: tuple[float, float, float] | list[float] | None) -> str:
    if d is None:
        return ""
    est, lo, hi = d
    s = f"{est:+.2f} [{lo:+.2f}, {hi:+.2f}]"
    return f"**{s}**" if lo > 0 or hi < 0 else s


def where_markdown(where: dict[str, Any]) -> list[str]:
    """The "Where the speed error is" section of one cell (markdown lines)."""
    models = list(where["overall"])
    pair = next((st["pair"] for kind in where["strata"].values() for st in kind.values()
                 if "pair" in st), None)
    a, b = where["speed_edges_mm_s"]
    qa, qb = where["loudness_edges_db"]
    lines = ["### Where the speed error is", "",
             f"Slip speed on the {where['n_windows']} true-slip windows of the test scene "
             f"({where['n_trials']} trials, mean true speed {where['mean_true_mm_s']:.1f} "
             "mm/s), ungated: RMSE [mm] of the per-window displacement error "
             "|s_hat - s\\*| x window (the table's magnitude) / bias [mm] (mean signed "
             "error, +: too fast), with 95 % trial-bootstrap intervals where a stratum has "
             f"at least {MIN_TRIALS_CI} trials."
             + ("" if pair is None else
                f" `{pair[0]} - {pair[1]}`: their RMSE difference on the same trial "
                "resamples (+: the first is worse; **bold**: the interval excludes 0)."), "",
             "| model | RMSE mm | bias mm | mean s_hat / mean s\\* | rank corr. | "
             "oracle scale | RMSE at oracle scale mm (diagnostic only) |",
             "|---|---|---|---|---|---|---|"]
    for name, o in where["overall"].items():
        lines.append(f"| {name} | {_ci(o, 'rmse_mm')} | {_ci(o, 'bias_mm')} | "
                     f"{o['scale_ratio']:.2f} | {o['rank_corr']:.2f} | "
                     f"{o['oracle_scale']:.2f} | {o['oracle_rmse_mm']:.2f} |")
    lines += ["", "Mean s_hat / mean s\\*: below 1 the model shrinks its speeds. Rank corr.: "
              "Spearman's, predicted against true speed. Oracle scale: the one factor that "
              "fits each model's speeds to the true speeds of these TEST windows in least "
              "squares, and the RMSE at it: DIAGNOSTIC ONLY (it uses the test labels). A "
              "model that catches up at its oracle scale loses on scale, one that stays "
              "behind loses on ranking.", ""]
    titles = {"object": "By object",
              "speed": f"By true speed (terciles of the scored windows: slow < {a:.1f} mm/s "
                       f"<= middle < {b:.1f} mm/s <= fast)",
              "loudness": f"By trial loudness (terciles of the trials' mean audio power: "
                          f"quiet < {qa:.1f} dB FS <= middle < {qb:.1f} dB FS <= loud)"}
    for kind, strata in where["strata"].items():
        lines += [f"{titles.get(kind, kind)}, RMSE mm / bias mm:", "",
                  f"| {kind} (trials, windows, mean s\\* mm/s) | " + " | ".join(models)
                  + ("" if pair is None else f" | {pair[0]} - {pair[1]} RMSE mm") + " |",
                  "|---|" + "---|" * (len(models) + (pair is not None))]
        for value, st in strata.items():
            row = [f"{value} ({st['n_trials']}, {st['n_windows']}, "
                   f"{st['mean_true_mm_s']:.1f})"]
            row += [f"{_ci(st['models'][n], 'rmse_mm')} / {_ci(st['models'][n], 'bias_mm')}"
                    for n in models]
            if pair is not None:
                row.append(_pair(st.get("pair_rmse_diff_mm")))
            lines.append("| " + " | ".join(row) + " |")
        lines.append("")
    return lines
