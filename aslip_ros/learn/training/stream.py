"""Training the streaming estimator (``aslip train --stage stream``).

The dataset is the one ``aslip export`` writes for the window models; the streaming model
reads each trial's whole audio (frames from ``streaming.stream_logmel``, the live path) and
its object-relative track (labels from ``data.stream_labels.frame_labels``: the smoothed
slip velocity at each frame's last sample). Splits are by trial with
``data_io.trial_splits``, so a trial is in the same split for the window models and this
one. Training draws random 2 s sequences from the training trials, each starting from a
zero state as the live estimator does after a reset; selection is by the validation loss
over whole validation trials, with a time budget, and writes a self-describing checkpoint
(``model_type`` "aslip_stream").

Rotational slip: where the tracks give a per-frame angular label (``wy``; NaN where a
recording has none), the model gets a rotational output, trained with a Huber loss on the
rim speed ``wy * ROTATION_RADIUS_M`` in ``speed_scale`` units over every valid labelled
frame (``rotation_weight``), and the checkpoint's ``outputs`` list ``wy``.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable, Sequence

import numpy as np

from aslip_ros.slip import (ANGULAR_COMPONENT, DEFAULT_THRESHOLD, ROTATION_EPSILON_RAD_S,
                            ROTATION_RADIUS_M)
import torch
from torch.nn import functional as F

from aslip_ros.learn.calibration.frames import FrameCutter, fit_on_dataset, window_offsets
from aslip_ros.learn.calibration.grasp import CalibrationConstants
from aslip_ros.learn.models.aslip_stream import StreamBackend
from aslip_ros.learn.checkpoint import checkpoint_meta, git_revision, save_checkpoint
from aslip_ros.learn.data_io import WindowSet, open_dataset, trial_splits
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.calibration.output import sequence_fields
from aslip_ros.learn.incremental_features import StreamingLogMel, stream_logmel
from aslip_ros.data.stream_labels import DEFAULT_SMOOTHER, Smoother, frame_labels, load_track
from aslip_ros.learn.models.aslip_stream import StreamConfig, StreamNet, offline_outputs
from aslip_ros.learn.training.config import resolve_device

MODEL_TYPE = StreamBackend.model_type
_DB = math.log(10.0) / 10.0      # +1 dB of power in natural-log mel units


@dataclass
class StreamTrainConfig:
    epochs: int = 60
    steps_per_epoch: int = 40
    batch_size: int = 32
    seq_frames: int = 200
    lr: float = 2e-3
    weight_decay: float = 1e-4
    patience: int = 12
    time_budget_s: float = 300.0
    seed: int = 0
    split_seed: int = 0
    gain_db: float = 6.0
    channel_gain_db: float = 1.0
    velocity_weight: float = 2.0
    # The rotational rim-speed Huber term (one component against the velocity's two).
    rotation_weight: float = 2.0
    fa_per_min: float = 2.0        # validation false alarms per minute the threshold allows
    threads: int = 1
    progress: bool = True
    device: str = "auto"           # auto | cpu | cuda (training.config.resolve_device)
    # Per-grasp calibration (as the window models'): off, or a method of calibration.grasp.
    # ``aslip train`` defaults to background.
    calibration: str = "off"


@dataclass
class Sequences:
    """Per-trial frames ``(T, C, M)`` and labels, for one split."""

    trials: list[int]
    frames: list[np.ndarray]
    v: list[np.ndarray]
    slip: list[np.ndarray]
    valid: list[np.ndarray]
    decided: list[np.ndarray]      # valid and outside the onset / end guard band
    w: list[np.ndarray]            # angular label wy [rad/s] per frame; NaN: none

    @property
    def has_angular(self) -> bool:
        """Whether any valid frame has an angular label."""
        return any(bool(np.isfinite(w[m]).any()) for w, m in zip(self.w, self.valid))


def trial_sequences(ds: WindowSet, trials: Sequence[int], channels: Sequence[str],
                    fcfg: FeatureConfig, smoother: Smoother = DEFAULT_SMOOTHER,
                    calibration: CalibrationConstants | None = None) -> Sequences:
    """Frames and per-frame labels of whole trials (trials with audio gaps are skipped:
    their file joins segments the live estimator would see as a reset). With
    ``calibration``, each frame is read with its grasp's causal calibration removed, as
    ``StreamingPredictor`` reads it live."""
    cols = ds.channel_indices(channels)
    cutter = FrameCutter(fcfg, ds.sample_rate) if calibration is not None else None
    out = Sequences([], [], [], [], [], [], [])
    for k in trials:
        if int(ds.trials[k].get("audio_gaps") or 0):
            continue
        audio = np.asarray(ds.audio(k))[:, cols]
        frames = stream_logmel(audio, fcfg, ds.sample_rate)
        ends = StreamingLogMel(fcfg, ds.sample_rate, len(cols)).frame_end_samples(
            np.arange(frames.shape[0]))
        if cutter is not None:
            offsets = window_offsets(cutter.frames(audio), ends, cutter, calibration)
            frames = frames - offsets.astype(np.float32)[:, :, None]
        lab = frame_labels(load_track(ds.root, k), ends, ds.sample_rate, ds.epsilon, smoother)
        out.trials.append(int(k))
        out.frames.append(frames)
        out.v.append(lab["v"])
        out.slip.append(lab["slip"])
        out.valid.append(lab["valid"])
        out.decided.append(lab["valid"] & ~lab["ambiguous"])
        w = lab.get(ANGULAR_COMPONENT)
        out.w.append(np.full(lab["slip"].shape, np.nan, np.float32) if w is None
                     else np.asarray(w, np.float32).reshape(-1))
    return out


def split_trial_indices(ds: WindowSet, split: str, seed: int = 0) -> list[int]:
    return [k for k, s in enumerate(trial_splits(ds, seed)) if s == split]


def frame_metrics(p: np.ndarray, v: np.ndarray, v_true: np.ndarray, slip: np.ndarray,
                  valid: np.ndarray, threshold: float = DEFAULT_THRESHOLD) -> dict[str, float]:
    """Per-frame detection and, on true slip frames, direction MAE (deg) and speed RMSE."""
    p, v, v_true, slip = p[valid], v[valid], v_true[valid], slip[valid]
    pred = p >= threshold
    tp = float((pred & slip).sum())
    out = {"n_frames": int(p.size), "n_slip": int(slip.sum()),
           "detection_accuracy": float((pred == slip).mean()) if p.size else float("nan"),
           "precision": tp / max(float(pred.sum()), 1.0),
           "recall": tp / max(float(slip.sum()), 1.0)}
    if slip.any():
        a = np.arctan2(v[slip, 1], v[slip, 0]) - np.arctan2(v_true[slip, 1], v_true[slip, 0])
        err = np.degrees(np.abs((a + np.pi) % (2 * np.pi) - np.pi))
        out["direction_mae_deg"] = float(err.mean())
        d = np.hypot(*v[slip].T) - np.hypot(*v_true[slip].T)
        out["speed_rmse_mm_s"] = float(np.sqrt((d ** 2).mean()) * 1e3)
    return out


def false_alarms_per_min(p: np.ndarray, slip: np.ndarray, threshold: float, hop_s: float,
                         quiet_s: float = 0.35) -> tuple[int, float]:
    """Rising edges of ``p >= threshold`` with no labelled slip in the ``quiet_s`` before,
    and the minutes of such quiet frames."""
    n = int(round(quiet_s / hop_s))
    cum = np.concatenate([[0], np.cumsum(slip.astype(np.int64))])
    idx = np.arange(slip.size)
    quiet = cum[idx + 1] == cum[np.maximum(idx + 1 - n, 0)]
    fired = p >= threshold
    rise = fired & ~np.concatenate([[False], fired[:-1]])
    return int((rise & quiet).sum()), float(quiet.sum()) * hop_s / 60.0


def select_threshold(p: list[np.ndarray], slip: list[np.ndarray], hop_s: float,
                     fa_per_min: float) -> tuple[float, list[dict], float]:
    """The lowest threshold (0.5 .. 0.95) whose false alarms per minute over the
    validation trials stay at or below ``fa_per_min`` (else the one with the fewest), the
    sweep, and the minutes of validation audio without slip the rates are counted on.
    The sweep's ``frame_recall`` is None where the validation trials hold no slip frame.

    A per-hop decision is taken 20 times as often as a 200 ms window's with a 100 ms hop;
    at the window models' 0.5 it fires on brief noise, so the threshold is chosen here,
    on validation trials, for a false-alarm rate rather than frame accuracy."""
    table, minutes = [], 0.0
    p_slip = np.concatenate(p)[np.concatenate(slip)]       # empty: no slip to recall
    for t in np.round(np.arange(0.5, 0.96, 0.05), 2):
        fa = [false_alarms_per_min(a, b, float(t), hop_s) for a, b in zip(p, slip)]
        minutes = sum(m for _, m in fa)
        n = sum(k for k, _ in fa)
        recall = round(float(np.mean(p_slip >= t)), 3) if p_slip.size else None
        table.append({"threshold": float(t), "false_alarms": int(n),
                      "fa_per_min": round(n / max(minutes, 1e-9), 2),
                      "frame_recall": recall})
    ok = [r for r in table if r["fa_per_min"] <= fa_per_min]
    best = ok[0] if ok else min(table, key=lambda r: r["fa_per_min"])
    return best["threshold"], table, minutes


def chosen_rate(p: list[np.ndarray], slip: list[np.ndarray], threshold: float,
                hop_s: float) -> dict[str, Any]:
    """The false alarms a minute at ``threshold`` over the trials, with the 95 % interval of
    a bootstrap over whole trials (``pooled_rate``): how far the rate the threshold was
    chosen for may be off on other audio."""
    return pooled_rate([false_alarms_per_min(a, b, threshold, hop_s)
                        for a, b in zip(p, slip)])


def pooled_rate(per_trial: Sequence[tuple[int, float]]) -> dict[str, Any]:
    """False alarms a minute pooled over trials' ``(false alarms, quiet minutes)``, with the
    95 % interval of a bootstrap over whole trials (``learn.stats.rate_interval``; None with
    one trial)."""
    from aslip_ros.learn.stats import rate_interval
    n, m = [k for k, _ in per_trial], [q for _, q in per_trial]
    interval = rate_interval(n, m)
    return {"fa_per_min": round(sum(n) / max(sum(m), 1e-9), 2),
            "fa_per_min_interval": interval and [round(v, 2) for v in interval]}


def threshold_support(quiet_min: float, fa_per_min: float) -> str | None:
    """A warning when the validation audio without slip is too short for the false-alarm
    target: one false alarm there counts for more than a quarter of the target, so a few
    events decide the threshold (measured: the same recipe chose 0.70 or 0.95 between
    draws of its scene, docs/results.md); None when it is long enough."""
    if quiet_min * fa_per_min >= 4.0:
        return None
    return (f"the threshold rests on {quiet_min:.1f} min of validation audio without slip, "
            f"where one false alarm is {1.0 / max(quiet_min, 1e-9):.2f} a minute against "
            f"the target's {fa_per_min:g}: a few false alarms chose it; validation trials "
            f"with more audio without slip give a steadier choice")


def _batch(seqs: Sequences, cfg: StreamTrainConfig, rng: np.random.Generator,
           mean: np.ndarray) -> tuple[torch.Tensor, ...]:
    lens = np.array([f.shape[0] for f in seqs.frames])
    t = cfg.seq_frames
    k = rng.choice(len(lens), cfg.batch_size, p=lens / lens.sum())
    xs, vs, ss, ms, ds, ws = [], [], [], [], [], []
    for j in k:
        s = int(rng.integers(0, max(1, lens[j] - t)))
        x = seqs.frames[j][s:s + t].astype(np.float32)
        # Gain augmentation in log-mel units, as the window models: whole sequence and per
        # microphone; added to the signal part only (the floor would not move).
        g = rng.uniform(-cfg.gain_db, cfg.gain_db) * _DB
        gc = rng.uniform(-cfg.channel_gain_db, cfg.channel_gain_db, x.shape[1]) * _DB
        xs.append(x + (g + gc).astype(np.float32)[None, :, None])
        vs.append(seqs.v[j][s:s + t])
        ss.append(seqs.slip[j][s:s + t])
        ms.append(seqs.valid[j][s:s + t])
        ds.append(seqs.decided[j][s:s + t])
        ws.append(seqs.w[j][s:s + t])
    n = min(x.shape[0] for x in xs)
    return tuple(torch.from_numpy(np.stack([a[:n] for a in arr]))
                 for arr in (xs, vs, ss, ms, ds, ws))


def _loss(model: StreamNet, x, v, slip, valid, decided, w,
          cfg: StreamTrainConfig) -> torch.Tensor:
    """Per valid frame: BCE (outside the guard band), the velocity's Huber loss and, for a
    model with a rotational output, the rim speed's where the frame has an angular label
    (NaN frames are masked before the arithmetic: no gradient from them)."""
    logit, vp, wp, _ = model(x)
    m = valid.float()
    bce = F.binary_cross_entropy_with_logits(logit, slip.float(), reduction="none")
    scale = model.cfg.speed_scale
    hub = F.smooth_l1_loss(vp / scale, v / scale, reduction="none").sum(-1)
    per_frame = bce * decided.float() + cfg.velocity_weight * hub * m
    if wp is not None:
        lab = valid & torch.isfinite(w)
        k = ROTATION_RADIUS_M / scale
        target = torch.where(lab, w, torch.zeros_like(w)) * k
        per_frame = per_frame + cfg.rotation_weight * lab.float() * F.smooth_l1_loss(
            wp * k, target, reduction="none")
    return per_frame.sum() / m.sum().clamp(min=1.0)


def _validate(model: StreamNet, seqs: Sequences, cfg: StreamTrainConfig):
    # Whole validation trials are long single sequences: the CPU runs them, as live.
    device = model.feat_mean.device
    model.to("cpu")
    try:
        return _validate_cpu(model, seqs, cfg)
    finally:
        model.to(device)


def _validate_cpu(model: StreamNet, seqs: Sequences, cfg: StreamTrainConfig):
    model.eval()
    losses, outs = [], []
    with torch.inference_mode():
        for x, v, s, m, d, w in zip(seqs.frames, seqs.v, seqs.slip, seqs.valid, seqs.decided,
                                    seqs.w):
            t = [torch.from_numpy(np.ascontiguousarray(a))[None] for a in (x, v, s, m, d, w)]
            losses.append(float(_loss(model, t[0].float(), *t[1:], cfg)) * float(m.sum()))
            outs.append(offline_outputs(model, x))
    loss = sum(losses) / max(1.0, float(sum(m.sum() for m in seqs.valid)))
    p = np.concatenate([o[0] for o in outs])
    v = np.concatenate([o[1] for o in outs])
    metrics = frame_metrics(p, v, np.concatenate(seqs.v), np.concatenate(seqs.slip),
                            np.concatenate(seqs.valid))
    if outs and outs[0][2] is not None:
        metrics.update(frame_rotation_metrics(np.concatenate([o[2] for o in outs]),
                                              np.concatenate(seqs.w),
                                              np.concatenate(seqs.valid)))
    return loss, metrics


def frame_rotation_metrics(w: np.ndarray, w_true: np.ndarray,
                           valid: np.ndarray) -> dict[str, float]:
    """Per frame, over valid frames with an angular label: the rate MAE over all of them
    and over rotating ones (deg/s; ``|wy| > ROTATION_EPSILON_RAD_S``)."""
    m = valid & np.isfinite(w_true)
    if not m.any():
        return {}
    err = np.degrees(np.abs(w[m] - w_true[m]))
    out = {"rotation_frames": int(m.sum()), "rotation_mae_all_deg_s": float(err.mean())}
    rot = np.abs(w_true[m]) > ROTATION_EPSILON_RAD_S
    if rot.any():
        out["rotation_mae_deg_s"] = float(err[rot].mean())
    return out


def train_stream(ds: WindowSet, cfg: StreamTrainConfig, *,
                 feature_config: FeatureConfig | None = None,
                 model_config: dict[str, Any] | None = None,
                 channels: Sequence[str] | None = None,
                 smoother: Smoother = DEFAULT_SMOOTHER,
                 log: Callable[[str], None] = print) -> tuple[dict, dict, list]:
    """Train and select; returns ``(meta, tensors, history)`` for ``save_checkpoint``."""
    torch.set_num_threads(max(1, cfg.threads))
    resolve_device(cfg.device)              # refuses cuda without a GPU before the features
    channels = list(channels or ds.channel_names)
    fcfg = feature_config or FeatureConfig()
    StreamingLogMel(fcfg, ds.sample_rate, len(channels))    # refuses unsupported rates early
    t0 = time.perf_counter()
    tr, va, cal = _split_sequences(ds, cfg, channels, fcfg, smoother, log)
    t_feat = time.perf_counter() - t0
    model, fit = fit_stream(tr, va, cfg, model_config=model_config, log=log)
    out_val = [offline_outputs(model, x) for x in va.frames]     # (p, v, w) per trial
    p_val, hop_s = [o[0] for o in out_val], fcfg.hop / fcfg.sample_rate
    threshold, sweep, quiet_min = select_threshold(p_val, va.slip, hop_s, cfg.fa_per_min)
    rate = chosen_rate(p_val, va.slip, threshold, hop_s)
    ci = rate["fa_per_min_interval"]
    log(f"threshold {threshold:.2f} (validation false alarms per minute <= "
        f"{cfg.fa_per_min:g} where reachable, on {quiet_min:.1f} min without slip): "
        f"{rate['fa_per_min']:g} a minute"
        + ("" if ci is None else f", 95 % interval over trials [{ci[0]:g}, {ci[1]:g}]"))
    thin = threshold_support(quiet_min, cfg.fa_per_min)
    if thin is not None:
        log(f"warning: {thin}")
    meta = stream_meta(ds, cfg, model.cfg, fcfg, channels, smoother, model)
    if cal is not None:
        meta["calibration"] = cal.to_dict()
    meta.update(threshold=threshold, **sequence_fields(out_val, va, threshold))
    meta["threshold_selection"] = {"fa_per_min_target": cfg.fa_per_min, "sweep": sweep,
                                   "quiet_minutes": round(quiet_min, 3),
                                   "thin": thin is not None, **rate}
    meta["provenance"].update(
        metrics={"val": fit["val_metrics"], "best_val_loss": fit["best_val_loss"]},
        training={**fit["training"], "feature_time_s": t_feat, "train_trials": tr.trials,
                  "val_trials": va.trials})
    tensors = {k: v.detach().clone() for k, v in model.state_dict().items()}
    return meta, tensors, fit["history"]


def fit_stream(tr: Sequences, va: Sequences, cfg: StreamTrainConfig, *,
               model_config: dict[str, Any] | None = None,
               log: Callable[[str], None] = print) -> tuple[StreamNet, dict[str, Any]]:
    """The network trained on ``tr`` and selected on ``va`` (lowest validation loss, early
    stopping, ``cfg.time_budget_s``), on the CPU in eval mode, and what the run gives:
    ``history``, ``val_metrics`` and ``best_val_loss`` of the chosen epoch, ``training``.
    Normalisation and ``speed_scale`` come from the training sequences; the rotational
    output is built when they carry angular labels."""
    torch.manual_seed(cfg.seed)
    device = resolve_device(cfg.device)
    rng = np.random.default_rng(cfg.seed)
    allf = np.concatenate(tr.frames)
    mean, std = allf.mean(axis=(0, 1)), np.maximum(allf.std(axis=(0, 1)), 1e-3)
    speeds = np.hypot(*np.concatenate(tr.v)[np.concatenate(tr.slip)].T)
    options = {"angular": tr.has_angular, **(model_config or {})}
    mcfg = StreamConfig(n_channels=allf.shape[1], n_mels=allf.shape[2],
                        speed_scale=float(max(np.median(speeds) if speeds.size else 0.02, 1e-3)),
                        **options)
    model = StreamNet(mcfg)
    model.set_normalization(mean, std)
    model.to(device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    best = (math.inf, -1, copy.deepcopy(model.state_dict()), {})
    history: list[dict] = []
    stop = "max_epochs"
    t_start = time.perf_counter()
    for epoch in range(cfg.epochs):
        model.train()
        run = 0.0
        for _ in range(cfg.steps_per_epoch):
            loss = _loss(model, *(t.to(device) for t in _batch(tr, cfg, rng, mean)), cfg)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            run += float(loss.detach())
        val_loss, val_m = _validate(model, va, cfg)
        history.append({"epoch": epoch, "train_loss": run / cfg.steps_per_epoch,
                        "val_loss": val_loss, "time_s": time.perf_counter() - t_start})
        if cfg.progress:
            log(f"epoch {epoch:3d} train {run / cfg.steps_per_epoch:.4f} val {val_loss:.4f} "
                f"det {val_m['detection_accuracy']:.3f} "
                f"dir {val_m.get('direction_mae_deg', float('nan')):.1f} deg")
        if val_loss < best[0]:
            best = (val_loss, epoch, copy.deepcopy(model.state_dict()), val_m)
        elif epoch - best[1] >= cfg.patience:
            stop = "early_stopping"
            break
        if time.perf_counter() - t_start > cfg.time_budget_s:
            stop = "time_budget"
            break
    model.load_state_dict(best[2])
    model.to("cpu").eval()
    return model, {"history": history, "val_metrics": best[3], "best_val_loss": best[0],
                   "training": {"best_epoch": best[1], "epochs_run": len(history),
                                "stop_reason": stop,
                                "train_time_s": time.perf_counter() - t_start,
                                "device": str(device)}}


def _split_sequences(ds: WindowSet, cfg: StreamTrainConfig, channels: Sequence[str],
                     fcfg: FeatureConfig, smoother: Smoother, log: Callable[[str], None]
                     ) -> tuple[Sequences, Sequences, CalibrationConstants | None]:
    """Training and validation sequences, read with the calibration fitted on the training
    trials (None when off)."""
    train_trials = split_trial_indices(ds, "train", cfg.split_seed)
    cal = stream_calibration(ds, cfg.calibration, train_trials, channels, fcfg, log)
    tr = trial_sequences(ds, train_trials, channels, fcfg, smoother, cal)
    va = trial_sequences(ds, split_trial_indices(ds, "val", cfg.split_seed), channels, fcfg,
                         smoother, cal)
    if not tr.trials or not va.trials:
        raise ValueError(f"need training and validation trials, have {len(tr.trials)} and "
                         f"{len(va.trials)}")
    return tr, va, cal


def stream_calibration(ds: WindowSet, method: str, train_trials: Sequence[int],
                       channels: Sequence[str], fcfg: FeatureConfig,
                       log: Callable[[str], None] = print) -> CalibrationConstants | None:
    """Per-grasp calibration constants fitted on the training trials (None when off or with
    one channel: gains are relative between microphones)."""
    if method == "off":
        return None
    if len(channels) < 2:
        log("calibration: off (one channel: gains are relative between microphones)")
        return None
    rows = np.flatnonzero(np.isin(ds.windows["trial"], np.asarray(train_trials)))
    k = fit_on_dataset(ds, rows, channels, fcfg, method=method)
    log(f"calibration: {k.method} constants fitted on the training trials (converged after "
        f"{k.convergence_s:g} s of accepted audio)")
    return k


def stream_meta(ds: WindowSet, cfg: StreamTrainConfig, mcfg: StreamConfig,
                fcfg: FeatureConfig, channels: list[str], smoother: Smoother,
                model: StreamNet) -> dict[str, Any]:
    """The checkpoint document: what the model expects and what its outputs mean."""
    factor = int(round(ds.sample_rate / fcfg.sample_rate))
    frame_s = fcfg.n_fft / fcfg.sample_rate
    return checkpoint_meta(
        MODEL_TYPE, mcfg, fcfg, ds, channels,
        normalization={"mean": model.feat_mean.tolist(), "std": model.feat_std.tolist(),
                       "scope": "per mel bin over training frames and channels"},
        # One frame is the audio an estimate reads directly; the state carries the rest.
        window_s=frame_s, window_samples=fcfg.n_fft * factor,
        hop_s=fcfg.hop / fcfg.sample_rate, angular=mcfg.angular,
        label={"kind": "slip_velocity_now",
               "describes": "the last audio sample of each frame",
               "smoother": {"method": "savitzky_golay", **smoother.to_dict()},
               "frame": "grasp plane (x, z), m/s"},
        train_config=asdict(cfg),
        provenance={"dataset": str(ds.root), "git_revision": git_revision(),
                    "seed": cfg.seed, "split_seed": cfg.split_seed, "stage": "stream",
                    "torch": torch.__version__})


def run_from_args(args: argparse.Namespace) -> int:
    """``aslip train --stage stream``: the window trainer's arguments, read here."""
    try:
        StreamConfig(context=args.stream_context)          # refused before the features
        ds = open_dataset(args.dataset)
        cfg = StreamTrainConfig(
            epochs=args.epochs, lr=args.lr,
            weight_decay=args.weight_decay, patience=args.patience, seed=args.seed,
            split_seed=args.split_seed, gain_db=args.gain_db,
            channel_gain_db=args.channel_gain_db, threads=args.threads,
            time_budget_s=args.time_budget, progress=not args.no_progress,
            device=args.device, calibration=args.calibration)
        fcfg = FeatureConfig(sample_rate=args.feature_rate, n_fft=args.n_fft, hop=args.hop,
                             n_mels=args.n_mels, fmin=args.fmin, fmax=args.fmax)
        chans = [c for c in (args.channels or "").split(",") if c] or None
        meta, tensors, _ = train_stream(ds, cfg, feature_config=fcfg, channels=chans,
                                        model_config={"context": args.stream_context})
    except (ValueError, FileNotFoundError) as exc:
        print(f"aslip train: error: {exc}", file=sys.stderr)
        return 1
    save_checkpoint(args.out, meta, tensors)
    val = meta["provenance"]["metrics"]["val"]
    print(f"wrote {args.out}: val frame detection {val.get('detection_accuracy', math.nan):.3f},"
          f" direction MAE {val.get('direction_mae_deg', math.nan):.1f} deg, "
          f"speed RMSE {val.get('speed_rmse_mm_s', math.nan):.1f} mm/s")
    if "rotation_frames" in val:
        print(f"val frame rotation: MAE {val.get('rotation_mae_deg_s', math.nan):.1f} deg/s "
              f"on rotating frames, {val['rotation_mae_all_deg_s']:.1f} deg/s on all "
              f"{val['rotation_frames']} labelled frames")
    return 0
