"""One inference interface over every window model, built from a checkpoint alone.

    p = Predictor.from_checkpoint("model.pt")
    p.check_stream(sample_rate, channel_names)     # CheckpointMismatch (a ValueError)
    pred = p.predict(window)                        # window: (window_samples, C) float32

Below the threshold (default: the checkpoint's, else 0.5, the paper's) the reported slip
vector is zero; the ungated estimate stays available in ``BatchPrediction.raw_velocity`` for
evaluation. The predictor is the one holder of the decision threshold: a live user changes
it with ``set_threshold`` and every estimate carries the threshold it was decided at, so a
published decision and its reported threshold cannot disagree.

Every estimate also carries ``direction_sigma`` [rad]: the one-sigma direction error the
checkpoint's ``output_calibration`` gives for the estimate's ungated predicted speed
(learn/calibration/output.py; about 68 % of validation and held-out slip windows fall
within it), or -1 (unknown) for a checkpoint without one.

A checkpoint whose ``outputs`` list ``wy`` (a model with a rotational output) also gives
``angular_velocity`` [rad/s] about +y of the grasp plane: the raw estimate, NOT gated by the
planar decision (a pure rotation is planar no-slip), and ``angular_sigma`` [rad/s] from the
checkpoint's angular sigma model (-1 without one). Any other checkpoint (``models/*.pt``
included) gives 0.0 and -1 (``BatchPrediction.angular`` is None).

A checkpoint with a per-grasp ``calibration`` (docs/model.md, "Per-grasp calibration") gets
window offsets from the caller: offline ``calibration_frames.dataset_offsets``; live, feed
every accepted audio block to ``push_audio`` and pass ``calibration_offsets()`` with the
window that ends with it (``reset_calibration()`` when a new grasp starts).

The model itself is the checkpoint's backend (learn/models/registry.py: the CNN, the SVM
baseline or a registered one); this class holds what every model shares: input checks,
per-grasp calibration, the threshold and the gating.

A model fed a window with a dead or disconnected microphone under-reports slip: live users
check each window first with ``aslip_ros.learn.inference.channel_check.dead_channels``.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from aslip_ros.slip import DEFAULT_THRESHOLD, N_VELOCITY
from aslip_ros.learn.models.registry import model_backend
from aslip_ros.learn.calibration.grasp import CalibrationConstants
from aslip_ros.learn.calibration.frames import FrameCutter, StreamCalibration
from aslip_ros.learn.checkpoint import (Checkpoint, CheckpointFacts, CheckpointMismatch,
                                        check_compatible, estimates_rotation, load_checkpoint)
from aslip_ros.learn.features import FeatureConfig, LogMel
from aslip_ros.learn.calibration.output import angular_sigma_model, sigma_model


@dataclass(frozen=True)
class Prediction:
    """One window's estimate. Velocities in m/s in the grasp plane; window_length in s."""

    probability: float
    slipping: bool
    vx: float
    vz: float
    speed: float
    direction: tuple[float, float]   # unit (x, z) when slipping, else (0, 0)
    window_length: float
    threshold: float = DEFAULT_THRESHOLD   # the decision threshold ``slipping`` was decided at
    direction_sigma: float = -1.0    # one-sigma direction error [rad]; -1: unknown
    # Rotational slip about +y of the grasp plane [rad/s], raw (not gated by ``slipping``);
    # 0 when the model does not estimate it.
    angular_velocity: float = 0.0
    angular_sigma: float = -1.0      # one-sigma error of angular_velocity [rad/s]; -1: unknown


@dataclass(frozen=True)
class BatchPrediction:
    probability: np.ndarray    # (B,)
    slipping: np.ndarray       # (B,) bool
    velocity: np.ndarray       # (B, 2) gated: zero where not slipping
    raw_velocity: np.ndarray   # (B, 2) ungated estimate
    window_length: float
    threshold: float = DEFAULT_THRESHOLD   # the decision threshold ``slipping`` was decided at
    direction_sigma: np.ndarray | None = None   # (B,) [rad] from the raw speed; None: unknown
    angular: np.ndarray | None = None   # (B,) raw wy [rad/s]; None: no rotational output
    angular_sigma: np.ndarray | None = None   # (B,) [rad/s]; None: unknown

    def __len__(self) -> int:
        return int(self.probability.shape[0])

    def __getitem__(self, i: int) -> Prediction:
        v = self.velocity[i]
        speed = float(np.hypot(v[0], v[1]))
        d = (float(v[0] / speed), float(v[1] / speed)) if speed > 0 else (0.0, 0.0)
        sigma = -1.0 if self.direction_sigma is None else float(self.direction_sigma[i])
        w = 0.0 if self.angular is None else float(self.angular[i])
        w_sigma = -1.0 if self.angular is None or self.angular_sigma is None \
            else float(self.angular_sigma[i])
        return Prediction(float(self.probability[i]), bool(self.slipping[i]), float(v[0]),
                          float(v[1]), speed, d, self.window_length, self.threshold, sigma,
                          w, w_sigma)


class PredictorBase(CheckpointFacts):
    """What the window and the streaming predictors share: the decision threshold (the one
    holder of it) and the per-grasp calibration of the stream. A subclass sets
    ``checkpoint`` and ``feature_config``, then calls ``set_threshold`` and
    ``_open_calibration``."""

    feature_config: FeatureConfig
    _threshold: float = DEFAULT_THRESHOLD
    calibration: CalibrationConstants | None = None
    _stream_cal: StreamCalibration | None = None
    _stream_ok: tuple | None = None    # (rate, names) of the last stream passed

    def _open_calibration(self) -> None:
        """The checkpoint's per-grasp calibration (none when it has no ``calibration``)."""
        ckpt = self.checkpoint
        if ckpt.meta.get("calibration") is not None:
            self.calibration = CalibrationConstants.from_dict(ckpt.meta["calibration"])
            self._check_calibration(ckpt.sample_rate, ckpt.channel_names)
            self._stream_cal = StreamCalibration(self.calibration, self.feature_config,
                                                 ckpt.sample_rate)

    # --- what the checkpoint expects ------------------------------------------------------
    @property
    def checkpoint_threshold(self) -> float:
        """The decision threshold the checkpoint was selected with (the paper's 0.5 when it
        names none)."""
        return float(self.meta.get("threshold", DEFAULT_THRESHOLD))

    @property
    def threshold(self) -> float:
        """The decision threshold every following estimate is gated with."""
        return self._threshold

    def set_threshold(self, threshold: float | None) -> float:
        """Gate the following estimates at ``threshold`` (``None``: the checkpoint's).

        Returns the threshold now in force; ValueError outside [0, 1] (nothing changes).
        """
        t = self.checkpoint_threshold if threshold is None else float(threshold)
        if not (0.0 <= t <= 1.0):
            raise ValueError(f"threshold must be in [0, 1], got {t}")
        self._threshold = t       # one float store: a concurrent predict sees old or new
        return t

    def check_stream(self, sample_rate: float, channel_names: Sequence[str]) -> None:
        """Raise CheckpointMismatch (a ValueError) unless the stream matches the training:
        rate and channel names (in order), and the calibration's features at that rate.

        The last stream that passed is remembered: the live path checks every block, and
        the calibration's check builds a featuriser."""
        key = (float(sample_rate), tuple(channel_names))
        if key == self._stream_ok:
            return
        check_compatible(self.meta, sample_rate, channel_names)
        if self.calibration is not None:
            self._check_calibration(sample_rate, channel_names)
        self._stream_ok = key

    def _check_calibration(self, sample_rate: float, channel_names: Sequence[str]) -> None:
        try:
            hop_s = FrameCutter(self.feature_config, sample_rate).hop_s
        except ValueError as exc:
            raise CheckpointMismatch(str(exc)) from exc
        self.calibration.check_stream(channel_names, self.feature_config.n_mels, hop_s)

    # --- per-grasp calibration, live ------------------------------------------------------
    @property
    def calibrated(self) -> bool:
        """True when the checkpoint carries a per-grasp calibration."""
        return self.calibration is not None

    def share_calibration_frames(self, other: "PredictorBase") -> bool:
        """Cut the per-grasp calibration's frames with ``other``'s where both calibrate on the
        same frames of the same stream (``StreamCalibration.share_frames``)."""
        mine, theirs = self._stream_cal, other._stream_cal
        return mine is not None and theirs is not None and mine.share_frames(theirs)

    def reset_calibration(self) -> None:
        """A new grasp (gap, restart, request): the estimate starts again from zero gain."""
        if self._stream_cal is not None:
            self._stream_cal.reset()

    def calibration_offsets(self) -> np.ndarray | None:
        """A copy of the current per-channel offsets (None without calibration)."""
        return None if self._stream_cal is None else self._stream_cal.offsets.copy()

    @property
    def calibration_converged(self) -> bool:
        return self._stream_cal is not None and self._stream_cal.state.converged

    @property
    def calibration_trusted(self) -> bool | None:
        """The per-grasp calibration's self-check (``CalibrationState.trusted``): False when
        its background is not common mode; None without calibration, before convergence or
        for constants without a threshold."""
        return None if self._stream_cal is None else self._stream_cal.state.trusted

    def calibration_summary(self) -> dict[str, Any] | None:
        """Converged, per-channel gain [dB], accepted and seen frames, resets, the
        self-check (or None)."""
        return None if self._stream_cal is None else self._stream_cal.summary()


class Predictor(PredictorBase):
    """Slip estimation for fixed-length multi-channel windows at the checkpoint's rate."""

    def __init__(self, ckpt: Checkpoint, threshold: float | None = None) -> None:
        self.checkpoint = ckpt
        meta = ckpt.meta
        self.feature_config = FeatureConfig.from_dict(meta["feature_config"])
        self.set_threshold(threshold)
        self.window_samples = int(meta["window_samples"])
        self.window_s = float(meta["window_s"])
        backend = model_backend(ckpt.model_type)
        if backend.streaming:
            raise ValueError(f"a {ckpt.model_type!r} checkpoint runs per audio block: "
                             "learn.inference.stream_predictor.StreamingPredictor")
        self.backend = backend.from_checkpoint(ckpt)
        self.sigma_model = sigma_model(meta)
        #: True when the model estimates the rotational slip rate (``outputs`` names wy).
        self.estimates_rotation = estimates_rotation(meta)
        self.angular_sigma_model = angular_sigma_model(meta)
        self._open_calibration()

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike,
                        threshold: float | None = None) -> "Predictor":
        return cls(load_checkpoint(path), threshold=threshold)

    @functools.cached_property
    def logmel(self) -> LogMel:
        """The log-mel features of the checkpoint's feature config at the stream's rate."""
        own = getattr(self.backend, "logmel", None)
        return own if own is not None else LogMel(self.feature_config, self.sample_rate)

    def push_audio(self, block: np.ndarray) -> None:
        """Feed one accepted block ``(n, C)`` of the stream to the calibration (no-op
        without one). Every sample of the grasp, in order, exactly once."""
        if self._stream_cal is not None:
            self._stream_cal.push(block)

    # --- inference ------------------------------------------------------------------------
    def _validate(self, windows: np.ndarray) -> np.ndarray:
        x = np.asarray(windows)
        want = (self.window_samples, self.n_channels)
        if x.ndim != 3 or x.shape[1:] != want:
            raise ValueError(f"expected windows shaped (B, {want[0]}, {want[1]}), got {x.shape}")
        if not np.issubdtype(x.dtype, np.number) or np.iscomplexobj(x):
            raise ValueError(f"audio must be real numbers, got dtype {x.dtype}")
        x = x.astype(np.float32, copy=False)
        if not np.isfinite(x).all():
            raise ValueError("audio window contains NaN or Inf")
        return x

    def _window_offsets(self, offsets: np.ndarray | None, n: int) -> np.ndarray | None:
        """``offsets`` as float32 ``(n, C)``, checked finite (None stays None)."""
        if offsets is None:
            return None
        offsets = np.asarray(offsets, dtype=np.float32)
        if offsets.shape != (n, self.n_channels) or not np.isfinite(offsets).all():
            raise ValueError(f"offsets must be finite, shaped ({n}, {self.n_channels}), got "
                             f"{offsets.shape}")
        return offsets

    def predict(self, window: np.ndarray, offsets: np.ndarray | None = None) -> Prediction:
        """One window, shaped (window_samples, n_channels); ``offsets`` ``(C,)`` or None."""
        w = np.asarray(window)
        if w.ndim != 2:
            raise ValueError(f"expected a window shaped ({self.window_samples}, "
                             f"{self.n_channels}), got {w.shape}")
        return self.predict_batch(w[None], offsets=None if offsets is None
                                  else np.asarray(offsets)[None])[0]

    def predict_batch(self, windows: np.ndarray, batch_size: int = 256,
                      offsets: np.ndarray | None = None) -> BatchPrediction:
        """Windows shaped (B, window_samples, n_channels). ``offsets`` ``(B, C)``: the
        per-grasp calibration of each window (natural-log power removed per channel)."""
        x = self._validate(windows)
        offsets = self._window_offsets(offsets, x.shape[0])
        probs, vels, rates = [], [], []
        for s in range(0, max(x.shape[0], 1), batch_size):
            chunk = x[s:s + batch_size]
            if chunk.shape[0] == 0:
                break
            off = None if offsets is None else offsets[s:s + batch_size]
            p, v, w = self._checked(self.backend.predict(chunk, off), chunk.shape[0])
            probs.append(p)
            vels.append(v)
            rates.append(w)
        prob = np.concatenate(probs) if probs else np.zeros(0, np.float32)
        raw = np.concatenate(vels) if vels else np.zeros((0, N_VELOCITY), np.float32)
        w = None
        if self.estimates_rotation:
            w = np.concatenate(rates) if rates else np.zeros(0, np.float32)
        return self._gate(prob, raw, w)

    def _checked(self, out: Any, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """A backend's ``(p, v)`` or ``(p, v, w)`` checked; ``w`` kept only when the
        checkpoint says the model estimates rotation (and then required)."""
        p, v = np.asarray(out[0]), np.asarray(out[1])
        w = out[2] if len(out) > 2 else None
        if p.shape != (n,) or v.shape != (n, N_VELOCITY):
            raise ValueError(f"model {self.model_type!r} returned p {p.shape} and v {v.shape} "
                             f"for {n} windows; expected ({n},) and ({n}, {N_VELOCITY})")
        if not (np.isfinite(p).all() and np.isfinite(v).all()):
            raise ValueError(f"model {self.model_type!r} returned NaN or Inf")
        if not self.estimates_rotation:
            return p, v, None
        w = None if w is None else np.asarray(w, np.float32)
        if w is None or w.shape != (n,) or not np.isfinite(w).all():
            raise ValueError(f"model {self.model_type!r} estimates rotation (outputs) but "
                             f"returned no finite ({n},) rate: "
                             f"{None if w is None else w.shape}")
        return p, v, w

    def predict_features(self, feats: np.ndarray,
                         offsets: np.ndarray | None = None) -> BatchPrediction:
        """Log-mel features (B, C, M, T) from ``LogMel`` (e.g. a training cache, or the live
        ``SlidingLogMel``), for a model that reads them (the CNN); ``offsets`` ``(B, C)``:
        the per-grasp calibration removed from them first, as ``predict_batch`` does."""
        infer = getattr(self.backend, "infer_features", None)
        if infer is None:
            raise ValueError(f"predict_features needs a model that reads log-mel features; "
                             f"{self.model_type!r} does not")
        feats = np.asarray(feats, dtype=np.float32)
        if offsets is not None:
            offsets = np.asarray(offsets, dtype=np.float32)
            if offsets.shape != feats.shape[:2] or not np.isfinite(offsets).all():
                raise ValueError(f"offsets must be finite, shaped {feats.shape[:2]}, got "
                                 f"{offsets.shape}")
            feats = feats - offsets[:, :, None, None]
        return self._gate(*self._checked(infer(feats), feats.shape[0]))

    def predict_window_features(self, windows: np.ndarray, feats: np.ndarray,
                                offsets: np.ndarray | None = None) -> BatchPrediction:
        """``predict_batch`` of ``windows`` with their log-mel ``feats`` already computed
        (the live ``SlidingLogMel``), for a backend that reads both
        (``predict_with_features``: a ``per_output`` model with a CNN part); ``offsets``
        ``(B, C)`` go to the backend as they are."""
        both = getattr(self.backend, "predict_with_features", None)
        if both is None:
            raise ValueError(f"predict_window_features needs a model that reads windows and "
                             f"log-mel features; {self.model_type!r} does not")
        x = self._validate(windows)
        offsets = self._window_offsets(offsets, x.shape[0])
        feats = np.asarray(feats, dtype=np.float32)
        return self._gate(*self._checked(both(x, feats, offsets), x.shape[0]))

    def _gate(self, prob: np.ndarray, raw: np.ndarray,
              w: np.ndarray | None = None) -> BatchPrediction:
        """The planar decision gates the velocity; the rotational rate stays raw."""
        threshold = self._threshold      # read once: the decision and its report agree
        slipping = prob >= threshold
        vel = np.where(slipping[:, None], raw, 0.0).astype(np.float32)
        sigma = None if self.sigma_model is None else \
            self.sigma_model(np.hypot(raw[:, 0], raw[:, 1]))
        w_sigma = None if w is None or self.angular_sigma_model is None else \
            self.angular_sigma_model(w)
        return BatchPrediction(prob.astype(np.float32), slipping, vel, raw.astype(np.float32),
                               self.window_s, threshold, sigma, w, w_sigma)
