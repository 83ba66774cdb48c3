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

Each output from the candidate that gives it best (``choose_outputs``, ``compose``): for
detection, speed, direction and, where the validation windows rotate, rotation, the
candidate best on that output's metric replaces the winner's output where it is better on
the same trial resamples (the paired interval of the difference excludes 0); an output the
trials cannot tell apart stays the winner's. Beside the candidates, each output weighs one
blend (``per_output.BLEND``): the mean of the two candidates best at it, on the same rule.
Where any output changes hands, the model is a ``per_output`` checkpoint
(learn/models/per_output.py) of the candidates that give them, with its threshold and
sigma models fitted again on its own validation predictions.
Among the candidates better than the winner at an output, one that the trials cannot tell
apart from the best of them but that costs the combination clearly less time per window
(``combination_cost``: typically a part that reads the winner's log-mel rather than
features of its own) gives it instead: the live budget is part of the choice.
"""

from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np

from aslip_ros.learn.calibration.output import checkpoint_fields
from aslip_ros.learn.checkpoint import estimates_rotation
from aslip_ros.learn.data_io import WindowSet
from aslip_ros.learn.inference.predictor import Predictor
from aslip_ros.learn.metrics import compute_metrics
from aslip_ros.learn.models.per_output import (PerOutputConfig, assemble, blend, combine,
                                               members, role_outputs)
from aslip_ros.learn.stats import KEYS, bootstrap_metrics, paired_difference
from aslip_ros.learn.training.config import TrainResult
from aslip_ros.learn.training.data import rotation_args

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


# --- each output from the candidate that gives it best -------------------------------------

#: Validation windows timed for the latency a combination costs (``window_latency_ms``).
LATENCY_WINDOWS = 20
#: Each output's metric and whether higher is better.
OUTPUT_METRICS = {"detection": ("detection_accuracy", True),
                  "speed": ("magnitude_rmse_mm", False),
                  "direction": ("direction_mae_deg", False),
                  "rotation": (ROTATION_METRIC, False)}


def _candidate_metric(ds: WindowSet, va: np.ndarray, pred: dict[str, Any], key: str):
    """``metric(idx)``: ``key`` of the candidate's validation predictions over ``idx``."""
    truth, slip = ds.velocity(va), ds.slip(va)

    def metric(idx: np.ndarray) -> float:
        rot = rotation_args(ds, va[idx], None if pred.get("w") is None
                            else np.asarray(pred["w"])[idx])
        m = compute_metrics(pred["prob"][idx], pred["v"][idx], truth[idx], slip[idx],
                            ds.window_s, **rot)
        v = m.get(key)
        return float("nan") if v is None else float(v)
    return metric


#: A part that the trials cannot tell from the best one replaces it where the combination
#: with it costs at most this fraction of the time per window (``choose_outputs``).
CHEAPER = 0.8


def choose_outputs(ds: WindowSet, va: np.ndarray, results: dict[str, TrainResult],
                   winner: str, n_boot: int = N_BOOT, seed: int = 0,
                   cost: Callable[[str, str], float] | None = None) -> dict[str, Any]:
    """Per output, the candidate that gives it (module docstring), with each choice's worth:
    ``{role: {"from", "metric", "value", "winner_value", "difference", "ci", "why"}}``.
    The winner gives every output it is not beaten on; roles the winner lacks are left out
    (rotation without angular labels or without the winner's rotational output).
    ``cost(role, name)``: milliseconds per window of the model with ``name`` giving
    ``role`` (``combination_cost``); None: the best candidate gives it whatever it costs."""
    trial = _val_trials(ds, va)
    preds = {n: r.val_pred for n, r in results.items() if r.val_pred is not None}
    if winner not in preds:
        return {}
    rotates = ds.has_angular(va) and preds[winner].get("w") is not None
    out: dict[str, Any] = {}
    everything = np.arange(va.size)
    for role, (key, higher) in OUTPUT_METRICS.items():
        if role == "rotation" and not rotates:
            continue
        names = [n for n in preds if role != "rotation" or preds[n].get("w") is not None]
        fns = {n: _candidate_metric(ds, va, preds[n], key) for n in names}
        vals = {n: fns[n](everything) for n in names}
        vals = {n: v for n, v in vals.items() if np.isfinite(v)}
        if winner not in vals:
            continue
        sign = -1.0 if higher else 1.0           # lower sign * value is better
        pair = sorted(vals, key=lambda n: (sign * vals[n], n != winner))[:2]
        if len(pair) == 2:
            mixed = blend(pair)
            fns[mixed] = _candidate_metric(ds, va, blend_prediction(preds, mixed), key)
            v = fns[mixed](everything)
            if np.isfinite(v):
                vals[mixed] = v
        best = min(vals, key=lambda n: (sign * vals[n], n != winner))
        row = {"from": winner, "metric": key, "value": vals[winner],
               "winner_value": vals[winner]}
        if best == winner or np.unique(trial).size < 2:
            row["why"] = "the winner's own" if best == winner else \
                "too few validation trials to tell another candidate's apart"
        else:
            d = paired_difference(trial, fns[best], fns[winner], n_boot=n_boot, seed=seed)
            row.update(difference=d[0], ci=(d[1], d[2]), best=best, best_value=vals[best])
            better = d[1] > 0.0 if higher else d[2] < 0.0
            if better:
                row.update({"from": best, "value": vals[best]})
                row["why"] = (f"{best} is better than {winner} on the same trial resamples "
                              f"({key} {d[0]:+.3g} [{d[1]:+.3g}, {d[2]:+.3g}])")
                if cost is not None:
                    _cheaper_part(row, role, trial, fns, vals, winner, higher, cost,
                                  n_boot, seed)
            else:
                row["why"] = (f"{best} ({vals[best]:.3g}) cannot be told apart from the "
                              f"winner {winner} ({vals[winner]:.3g}) on these trials "
                              f"(difference {d[0]:+.3g} [{d[1]:+.3g}, {d[2]:+.3g}])")
        out[role] = row
    return out


def blend_prediction(preds: dict[str, dict[str, Any]], name: str) -> dict[str, Any]:
    """The validation predictions of the blend ``name`` (``per_output.members``) from its
    parts', every output averaged as a ``per_output`` model averages it."""
    outs = {n: (preds[n]["prob"], preds[n]["v"], preds[n].get("w")) for n in members(name)}
    prob, v, w = combine(role_outputs(
        {r: name for r in ("detection", "speed", "direction", "rotation")}, outs))
    return {"prob": prob, "v": v, "w": w}


def _cheaper_part(row: dict[str, Any], role: str, trial: np.ndarray, fns: dict, vals: dict,
                  winner: str, higher: bool, cost: Callable[[str, str], float], n_boot: int,
                  seed: int) -> None:
    """``row`` (best chosen, better than the winner) given instead by the best-scoring
    other candidate that is also better than the winner, cannot be told apart from the best
    and whose combination costs at most ``CHEAPER`` of the best's. Only such candidates are
    timed (``cost`` assembles and runs a model)."""
    best = row["from"]
    costs = {best: cost(role, best)}
    row["cost_ms"] = {best: costs[best]}
    for n in sorted(vals, key=lambda n: -vals[n] if higher else vals[n]):
        if n in (best, winner):
            continue
        vs_winner = paired_difference(trial, fns[n], fns[winner], n_boot=n_boot, seed=seed)
        vs_best = paired_difference(trial, fns[n], fns[best], n_boot=n_boot, seed=seed)
        if not (vs_winner[1] > 0.0 if higher else vs_winner[2] < 0.0) or \
                not vs_best[1] <= 0.0 <= vs_best[2]:
            continue
        costs[n] = cost(role, n)
        row["cost_ms"][n] = costs[n]
        if costs[n] > CHEAPER * costs[best]:
            continue
        row.update({"from": n, "value": vals[n]})
        row["why"] = (f"{n} cannot be told apart from {best} ({row['metric']} "
                      f"{vs_best[0]:+.3g} [{vs_best[1]:+.3g}, {vs_best[2]:+.3g}]), is better "
                      f"than {winner} ({vs_winner[0]:+.3g} [{vs_winner[1]:+.3g}, "
                      f"{vs_winner[2]:+.3g}]) and costs the model {costs[n]:.2f} ms per "
                      f"window against {costs[best]:.2f} ms with {best}")
        return


def _roles(results: dict[str, TrainResult], winner: str,
           chosen: dict[str, str]) -> dict[str, str]:
    """Every role of a per-output model: ``chosen``'s, the winner's for the rest (rotation
    too where the winner estimates it, though no validation window rotates to choose on)."""
    roles = dict(chosen)
    for role in ("detection", "speed", "direction"):
        roles.setdefault(role, winner)
    if "rotation" not in roles and estimates_rotation(results[winner].meta):
        roles["rotation"] = winner
    return roles


def chosen_parts(outputs: dict[str, Any]) -> set[str]:
    """The candidates ``choose_outputs``' rows read (a blend's members too)."""
    return {m for row in outputs.values() for m in members(row["from"])}


def combination_cost(ds: WindowSet, va: np.ndarray, results: dict[str, TrainResult],
                     winner: str) -> Callable[[str, str], float]:
    """``cost(role, name)``: the median milliseconds per window (``window_latency_ms``) of
    the model that takes ``role`` from ``name`` and every other output from the winner."""
    cache: dict[tuple[str, str], float] = {}
    parts = {winner: results[winner].checkpoint()}

    def cost(role: str, name: str) -> float:
        if (role, name) not in cache:
            for m in members(name):
                if m not in parts:
                    parts[m] = results[m].checkpoint()
            roles = _roles(results, winner, {role: name})
            try:
                ck = (parts[winner] if name == winner else
                      assemble({n: parts[n] for n in PerOutputConfig(**roles).parts()}, roles))
            except ValueError:                 # parts that cannot run together
                cache[role, name] = float("inf")
            else:
                cache[role, name] = window_latency_ms(ds, va, {"m": ck})["m"]
        return cache[role, name]
    return cost


def compose(ds: WindowSet, va: np.ndarray, results: dict[str, TrainResult], winner: str,
            outputs: dict[str, Any]) -> TrainResult | None:
    """The ``per_output`` model of ``outputs`` (``choose_outputs``), with its validation
    metrics and output calibration from the combined validation predictions; None when the
    winner gives every output."""
    roles = {role: row["from"] for role, row in outputs.items()}
    if all(n == winner for n in roles.values()):
        return None
    roles = _roles(results, winner, roles)
    names = PerOutputConfig(**roles).parts()
    ck = assemble({n: results[n].checkpoint() for n in names}, roles)
    pred = {n: results[n].val_pred for n in names}
    prob, v, w = combine(role_outputs(roles, {n: (pred[n]["prob"], pred[n]["v"],
                                                  pred[n].get("w")) for n in names}))
    truth, slip = ds.velocity(va), ds.slip(va)
    rot = rotation_args(ds, va, w)
    val = compute_metrics(prob, v, truth, slip, ds.window_s, **rot)
    base = ck.meta
    base.update(checkpoint_fields(prob, v, truth, slip, w_pred=w,
                                  w_true=ds.angular(va) if rot else None))
    prov = base["provenance"]
    prov["metrics"] = {"val": val}
    prov["per_output"] = {"roles": roles, "choice": outputs,
                          "latency_ms": window_latency_ms(
                              ds, va, {"per_output": ck, winner: results[winner].checkpoint()})}
    prov.pop("training", None)
    return TrainResult(meta=base, tensors=ck.tensors, history=[],
                       val_pred={"prob": prob, "v": v, "w": w})


def window_latency_ms(ds: WindowSet, va: np.ndarray, models: dict[str, Any],
                      n: int = LATENCY_WINDOWS) -> dict[str, float]:
    """Median milliseconds of one window's estimate (``Predictor.predict``, whole-window
    features, this machine) per named checkpoint, on ``n`` validation windows: what a
    combination costs beside the winner alone (the live node's figure: make latency)."""
    out = {}
    for name, ck in models.items():
        pred = Predictor(ck)
        idx = va[:max(1, min(n, va.size))]
        x = ds.window_audio(idx, ds.channel_indices(pred.channel_names))
        pred.predict(x[0])                               # first call: lazy set-up
        times = []
        for w in x:
            t0 = time.perf_counter()
            pred.predict(w)
            times.append(time.perf_counter() - t0)
        out[name] = round(1e3 * float(np.median(times)), 3)
    return out
