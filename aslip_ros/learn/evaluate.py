"""The paper's metrics, for any checkpoint on any dataset split: ``aslip evaluate``.

Definitions (inputs in SI; the report converts to the paper's degrees and millimetres):

- ``detection_accuracy``: fraction of windows where (p >= threshold) equals the label
  (speed > epsilon, as stored in the dataset).
- ``direction_mae_deg`` / ``direction_std_deg``: over windows labelled slip with a
  non-zero true velocity, the absolute angle between the *ungated* predicted direction and
  the true one, in [0, 180]; mean and population standard deviation of that per-window
  error. Ungated, so direction quality is measured apart from detection (the gated vector
  has no direction when p < threshold).
- ``magnitude_rmse_mm`` / ``magnitude_std_mm``: per-window displacement error
  e = |s_hat - s*| * window_s over the same slip windows (s = speed, ungated), RMSE
  sqrt(mean(e^2)) and the population std of |e|. ``magnitude_rmse_gated_mm`` repeats it
  over all windows with the gated speed (zero below threshold), i.e. what a controller sees.

Calibrated outputs (``output_calibration`` in the result; learn/calibration/output.py):
``ece``, the expected calibration error of p(slip) over ten equal-width bins, with the
bins themselves (``reliability``), and, for a checkpoint with a direction-sigma model,
``sigma.coverage``: the fraction of scored slip windows (as for the direction error) whose
error is at most the sigma the checkpoint reports for its predicted speed (about 0.68 when
calibrated). ``ece_ci`` and ``sigma.coverage_ci``: 95 % intervals from 1000 resamples of
whole trials (``stats``: windows of one trial are not independent).
``--reliability PATH.png`` draws both.

Rotational slip (a dataset with angular labels, ``wy``; learn/metrics.py,
``rotation_metrics``): ``rotation_mae_deg_s`` over rotating windows (``|wy| >
ROTATION_EPSILON_RAD_S``) with ``rotation_mean_true_deg_s`` and their ratio,
``pure_rotation_detection``, ``false_rotation_on_translation`` and ``kind_agreement``, each
with a 95 % trial-bootstrap interval (``<key>_ci``). A checkpoint without a rotational
output is scored as what it publishes, a rate of 0 (``rotation_estimated`` false). Planar
metrics are unchanged. ``output_calibration.angular_sigma``: the angular sigma coverage
for a checkpoint with an angular sigma model.

Streaming checkpoints (``aslip_stream``) are scored on the same windows and labels: the
estimator runs over each trial's audio from its start (a zero state, as the live node after
a reset) and each window gets the newest estimate available at its end (the last frame
ending at or before it, up to one 10 ms hop earlier), i.e. what ``slip_inference`` had
published when the window closed. The window's label is its mean velocity while the
estimate is the velocity *now*, so on changing slip the two differ by the model's whole
advantage in lag; in exchange the numbers compare with the window models' over identical
rows (the lag against the true velocity is ``benchmarks.lag``'s measure). Displacement
errors use the dataset's window length; trials with audio gaps are left out (live, the gap
would reset the state; their files join the segments).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from aslip_ros.util import write_json

from aslip_ros.learn.inference.live import load_predictor
from aslip_ros.learn.models.registry import model_backend
from aslip_ros.learn.checkpoint import CheckpointMismatch
from aslip_ros.learn.coverage import NO_SLIP, SECTORS, direction_groups, sector_name
from aslip_ros.learn.data_io import open_dataset, select_windows
from aslip_ros.learn.calibration.output import calibration_check, plot_reliability
from aslip_ros.learn.metrics import ROTATION_KEYS, compute_metrics, grouped_metrics
from aslip_ros.learn.stats import bootstrap_metrics, resamples

__all__ = ["compute_metrics", "evaluate_checkpoint", "grouped_metrics", "predict_split"]


def predict_split(checkpoint: str | Path, dataset: str | Path, split: str = "test", *,
                  induced: str | None = None, objects: Sequence[str] | None = None,
                  conditions: Sequence[str] | None = None, split_seed: int = 0,
                  threshold: float | None = None, batch_size: int = 256,
                  predictor=None) -> dict[str, Any]:
    """Run a checkpoint over a dataset split; per-window predictions and labels.

    Dataset channels are picked by the checkpoint's channel names, so a single-microphone
    model evaluates on a 4-microphone dataset; rate and window length must match exactly
    (a streaming checkpoint: the rate; see the module docstring).
    Returns ``prob``, ``raw_velocity``, ``true_velocity``, ``slip``, ``angular`` (the raw
    rate wy, None for a model without a rotational output), ``true_angular`` (NaN: no
    label), ``trial`` (per window), ``index`` (window indices), ``window_s``, ``threshold``
    and the ``predictor`` and ``dataset`` used.
    """
    pred = predictor or _load(checkpoint, threshold)
    ds = open_dataset(dataset)
    cols = ds.channel_indices(pred.channel_names)
    check = pred.checkpoint
    check.check_compatible(ds.sample_rate, [ds.channel_names[c] for c in cols])
    if model_backend(pred.model_type).streaming:
        idx = _selected(ds, dataset, split, induced, objects, conditions, split_seed)
        return _predict_stream(pred, ds, cols, idx)
    if ds.window_samples != pred.window_samples:
        raise CheckpointMismatch(
            f"dataset windows are {ds.window_s * 1e3:g} ms ({ds.window_samples} samples), the "
            f"checkpoint expects {pred.window_s * 1e3:g} ms ({pred.window_samples} samples)")
    idx = _selected(ds, dataset, split, induced, objects, conditions, split_seed)
    offsets = None
    if pred.calibration is not None:
        # The checkpoint's causal per-grasp calibration, each trial a grasp from its start.
        from aslip_ros.learn.calibration.frames import dataset_offsets
        offsets = dataset_offsets(ds, pred.channel_names, pred.feature_config,
                                  pred.calibration, idx)
    parts = []
    for s in range(0, idx.size, 2048):
        parts.append(pred.predict_batch(
            ds.window_audio(idx[s:s + 2048], cols), batch_size=batch_size,
            offsets=None if offsets is None else offsets[idx[s:s + 2048]]))
    return {"prob": np.concatenate([b.probability for b in parts]),
            "raw_velocity": np.concatenate([b.raw_velocity for b in parts]),
            "angular": None if parts[0].angular is None else
            np.concatenate([b.angular for b in parts]),
            "true_velocity": ds.velocity(idx), "slip": ds.slip(idx),
            "true_angular": ds.angular(idx),
            "trial": np.asarray(ds.windows["trial"][idx]), "index": idx,
            "window_s": pred.window_s, "threshold": pred.threshold, "predictor": pred,
            "dataset": ds}


def _load(checkpoint: str | Path, threshold: float | None):
    """A Predictor, or a StreamingPredictor for a streaming checkpoint (the live one's)."""
    return load_predictor(checkpoint, threshold)


def _selected(ds, dataset, split, induced, objects, conditions, split_seed) -> np.ndarray:
    """The split's window indices; ValueError (with a hint) when there are none."""
    idx = select_windows(ds, split, induced=induced, objects=objects, conditions=conditions,
                         seed=split_seed)
    if idx.size == 0:
        from aslip_ros.data.dataset import split_summary
        hint = ("" if split == "all" else
                f"; the split by trial gives {split_summary(ds.trials, split_seed)}: "
                "--split all evaluates every trial (for a dataset held out from training)")
        raise ValueError(f"no windows in split {split!r} of {dataset} with these filters"
                         + hint)
    return idx


def _predict_stream(pred, ds, cols, idx: np.ndarray) -> dict[str, Any]:
    """``predict_split`` for a StreamingPredictor: per trial from its start, the newest
    estimate at each window's end (module docstring)."""
    trial = np.asarray(ds.windows["trial"][idx])
    end = np.asarray(ds.windows["start"][idx], np.int64) + ds.window_samples
    prob, raw, rate = np.zeros(idx.size), np.zeros((idx.size, 2)), np.zeros(idx.size)
    keep = np.zeros(idx.size, bool)
    for k in np.unique(trial):
        if int(ds.trials[k].get("audio_gaps") or 0):
            continue
        ends, p, v, w = pred.trial_outputs(np.asarray(ds.audio(k))[:, cols])
        rows = np.flatnonzero(trial == k)
        j = np.searchsorted(ends, end[rows], side="right") - 1
        ok = j >= 0                      # a window ending before the first frame has none
        prob[rows[ok]], raw[rows[ok]] = p[j[ok]], v[j[ok]]
        if w is not None:
            rate[rows[ok]] = w[j[ok]]
        keep[rows[ok]] = True
    if not keep.any():
        raise ValueError("no window of the split has a streaming estimate (trials with audio "
                         "gaps are left out, and the first frame needs "
                         f"{pred.window_s * 1e3:g} ms of audio)")
    idx = idx[keep]
    return {"prob": prob[keep], "raw_velocity": raw[keep], "true_velocity": ds.velocity(idx),
            "angular": rate[keep] if pred.estimates_rotation else None,
            "slip": ds.slip(idx), "true_angular": ds.angular(idx), "trial": trial[keep],
            "index": idx, "window_s": ds.window_s, "threshold": pred.threshold,
            "predictor": pred, "dataset": ds}


def evaluate_checkpoint(checkpoint: str | Path, dataset: str | Path, split: str = "test",
                        **kw: Any) -> dict[str, Any]:
    """Run a checkpoint over a dataset split; returns overall, per-object, per-condition metrics
    (keyword arguments: those of :func:`predict_split`)."""
    p = predict_split(checkpoint, dataset, split, **kw)
    pred, ds, idx = p["predictor"], p["dataset"], p["index"]
    args = (p["prob"], p["raw_velocity"], p["true_velocity"], p["slip"], p["window_s"],
            pred.threshold)
    rot = _rotation_args(p)
    return {
        "checkpoint": str(checkpoint), "dataset": str(dataset), "split": split,
        "model_type": pred.model_type, "layout": pred.layout,
        "channel_names": pred.channel_names,
        "calibration": None if pred.calibration is None else pred.calibration.method,
        "overall": _overall(p, args, rot),
        "per_object": grouped_metrics(ds.trial_field("object", idx), *args, **rot),
        "per_condition": grouped_metrics(ds.trial_field("condition", idx), *args, **rot),
        # Where the training slip was sparse (learn/coverage.py), the direction is weaker.
        "per_direction": grouped_metrics(direction_groups(p["true_velocity"], p["slip"]),
                                         *args, **rot),
        "output_calibration": _output_calibration(p, getattr(pred, "sigma_model", None),
                                                  getattr(pred, "angular_sigma_model", None)),
    }


def _rotation_args(p: dict[str, Any]) -> dict[str, Any]:
    """The rotational arguments of ``compute_metrics`` (none when the split's windows have
    no angular label)."""
    if not np.isfinite(p["true_angular"]).any():
        return {}
    return {"angular": p["angular"], "true_angular": p["true_angular"]}


def _overall(p: dict[str, Any], args: tuple, rot: dict[str, Any],
             n_boot: int = 1000) -> dict[str, Any]:
    """``compute_metrics`` over the split; with angular labels and two trials or more, the
    rotational metrics' trial-bootstrap intervals (``<key>_ci``)."""
    out = compute_metrics(*args, **rot)
    if rot and np.unique(p["trial"]).size >= 2:
        boot = bootstrap_metrics(p["trial"], *args[:5], n_boot=n_boot, seed=0,
                                 threshold=args[5], **rot)
        out.update({k + "_ci": boot[k + "_ci"] for k in ROTATION_KEYS if k + "_ci" in boot})
    return out


def _output_calibration(p: dict[str, Any], model, angular_model=None,
                        n_boot: int = 1000) -> dict[str, Any]:
    """``calibration_check`` on the split, with trial-bootstrap intervals (docstring)."""
    arrays = [np.asarray(p[k]) for k in ("prob", "raw_velocity", "true_velocity", "slip")]
    rates = {} if p.get("angular") is None or angular_model is None else {
        "w_pred": np.asarray(p["angular"]), "w_true": np.asarray(p["true_angular"])}
    out = calibration_check(*arrays, model, angular_model=angular_model, **rates)
    if np.unique(p["trial"]).size < 2:
        return out
    ece, cover, w_cover = [], [], []
    for idx in resamples(p["trial"], n_boot, 0):
        c = calibration_check(*(a[idx] for a in arrays), model, angular_model=angular_model,
                              **{k: a[idx] for k, a in rates.items()})
        ece.append(c["ece"])
        if c["sigma"] is not None and c["sigma"]["coverage"] is not None:
            cover.append(c["sigma"]["coverage"])
        if c.get("angular_sigma") and c["angular_sigma"]["coverage"] is not None:
            w_cover.append(c["angular_sigma"]["coverage"])
    out["ece_ci"] = [float(v) for v in np.percentile(ece, [2.5, 97.5])]
    if cover and out["sigma"] is not None:
        out["sigma"]["coverage_ci"] = [float(v) for v in np.percentile(cover, [2.5, 97.5])]
    if w_cover and out.get("angular_sigma") is not None:
        out["angular_sigma"]["coverage_ci"] = [float(v)
                                               for v in np.percentile(w_cover, [2.5, 97.5])]
    return out


def format_report(res: dict[str, Any]) -> str:
    """A short human-readable summary in the paper's units."""
    def row(name: str, m: dict[str, Any]) -> str:
        acc = m.get("detection_accuracy", float("nan")) * 100
        return (f"{name:<24} n={m['n_windows']:>6}  det {acc:5.1f} %  "
                f"dir {m.get('direction_mae_deg', float('nan')):5.1f} ± "
                f"{m.get('direction_std_deg', float('nan')):4.1f} deg  "
                f"mag {m.get('magnitude_rmse_mm', float('nan')):5.2f} ± "
                f"{m.get('magnitude_std_mm', float('nan')):4.2f} mm")
    lines = [f"{res['model_type']} {res['checkpoint']} on {res['dataset']} [{res['split']}]",
             row("overall", res["overall"])]
    lines += [row(f"  {k}", v) for k, v in res["per_object"].items()]
    by_dir = {k: v for k, v in (res.get("per_direction") or {}).items() if k != NO_SLIP}
    if by_dir:
        lines.append("direction MAE by true slip direction: " + ", ".join(
            f"{k} {v.get('direction_mae_deg', float('nan')):.0f} deg (n={v['n_slip']})"
            for k, v in ((k, by_dir[k]) for k in map(sector_name, range(SECTORS))
                         if k in by_dir)))
    cal = res.get("output_calibration")
    if cal is not None:
        sig = cal["sigma"]
        ci = (lambda c: "" if c is None else f" [{c[0]:.3f}, {c[1]:.3f}]")
        cover = "no sigma model in the checkpoint" if sig is None else (
            f"{sig['coverage']:.1%} of {sig['n']} slip windows within direction sigma "
            f"(target {sig['target']:.1%}){ci(sig.get('coverage_ci'))}" if sig["n"]
            else "no slip windows")
        lines.append(f"calibration: threshold {res['overall']['threshold']:.2f}, "
                     f"ECE {cal['ece']:.3f}{ci(cal.get('ece_ci'))}; {cover}")
    if res["overall"].get("n_angular_labelled"):
        lines.append(rotation_line(res["overall"]))
    return "\n".join(lines)


def rotation_line(m: dict[str, Any]) -> str:
    """The rotational metrics (``compute_metrics`` with angular labels) in one line, each
    with its interval where the result has one."""
    def cell(key: str, scale: float, fmt: str, unit: str) -> str:
        if key not in m:
            return "-"
        c = m.get(key + "_ci")
        span = "" if c is None else f" [{c[0] * scale:{fmt}}, {c[1] * scale:{fmt}}]"
        return f"{m[key] * scale:{fmt}}{unit}{span}"
    head = "rotation" + ("" if m.get("rotation_estimated") else
                         " (the model has no rotational output: scored as 0)")
    return (f"{head}: n rotating {m['n_rotating']}, MAE "
            f"{cell('rotation_mae_deg_s', 1, '.1f', ' deg/s')} of mean "
            f"{cell('rotation_mean_true_deg_s', 1, '.1f', ' deg/s')} (ratio "
            f"{cell('rotation_mae_ratio', 1, '.2f', '')}); pure rotation detected "
            f"{cell('pure_rotation_detection', 100, '.1f', ' %')} of "
            f"{m['n_pure_rotation']}; false rotation on translation "
            f"{cell('false_rotation_on_translation', 100, '.1f', ' %')} of "
            f"{m['n_pure_translation']}; kind agreement "
            f"{cell('kind_agreement', 100, '.1f', ' %')} of {m['n_kind_windows']} slip windows")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--checkpoint", required=True, help="checkpoint file (aslip train --out)")
    p.add_argument("--dataset", required=True, help="dataset directory (aslip export)")
    p.add_argument("--split", default="test", choices=["train", "val", "test", "all"])
    p.add_argument("--split-seed", type=int, default=0, help="seed of the trial split")
    p.add_argument("--induced", default=None, help="only trials with this 'induced' value")
    p.add_argument("--objects", default=None, help="comma-separated objects to keep")
    p.add_argument("--conditions", default=None, help="comma-separated conditions to keep")
    p.add_argument("--threshold", type=float, default=None,
                   help="p(slip) threshold (default: the checkpoint's, chosen on validation)")
    p.add_argument("--json", default=None, help="write the metrics here as JSON")
    p.add_argument("--reliability", default=None, metavar="PATH.png",
                   help="draw the reliability diagram and the direction-sigma coverage")
    p.add_argument("--threads", type=int, default=2, help="torch threads")


def run(args: argparse.Namespace) -> int:
    import torch

    torch.set_num_threads(max(1, args.threads))
    split_list = (lambda s: [x for x in s.split(",") if x] if s else None)
    try:
        res = evaluate_checkpoint(args.checkpoint, args.dataset, args.split,
                                  induced=args.induced, objects=split_list(args.objects),
                                  conditions=split_list(args.conditions),
                                  split_seed=args.split_seed, threshold=args.threshold)
    except (ValueError, FileNotFoundError) as exc:
        print(f"aslip evaluate: error: {exc}", file=sys.stderr)
        return 1
    print(format_report(res))
    if args.reliability:
        plot_reliability(args.reliability, res["output_calibration"],
                         f"{res['model_type']} {Path(args.checkpoint).name} on "
                         f"{Path(args.dataset).name} [{args.split}]")
        print(f"wrote {args.reliability}")
    if args.json:
        write_json(args.json, res)
    else:
        print(json.dumps(res["overall"], indent=2))
    return 0
