"""Live streaming slip estimation from an ``aslip_stream`` checkpoint (ROS-free, node-ready).

    p = StreamingPredictor.from_checkpoint("stream.pt")
    p.check_stream(sample_rate, channel_names)        # CheckpointMismatch (a ValueError)
    for est in p.push(block):                         # block: AudioData-like (see below)
        publish(est.stamp_ns, est.prediction)         # one estimate per completed 10 ms hop
    p.reset()                                         # forget features and state

A caller that gates the stream itself (``slip_inference`` counts gaps, restarts and drops
with its own ``StreamGate``) calls ``reset(reason)`` where it restarts and ``feed(block)``
for each accepted block instead of ``push``. Offline, ``trial_outputs(audio)`` gives the
estimates of a whole recording from a zero state (the batched forward, equal to ``push``).

``push`` takes anything with ``block`` ``(frames, C)`` float32, ``first_sample_index``,
``frames``, ``stamp_ns``, ``end_stamp_ns`` and ``sample_rate`` (``nodes.convert.AudioData``).
Continuity is judged by ``stream.StreamGate`` exactly as the window node does: a gap, a
time jump, a new stream or a refused block (NaN / Inf: ``push`` raises) resets the
features and the recurrent state (the block that revealed a gap starts the new history);
repeated or out-of-order blocks are dropped. Each
estimate describes the instant of its frame's last sample: ``stamp_ns`` is that sample's
time on the block clock, and ``Prediction.window_length`` is the frame length (the audio
the estimate reads directly; the state summarises what came before). Its
``direction_sigma`` comes from the checkpoint's ``output_calibration`` at the hop's ungated
speed (-1 without one), as for ``learn.inference.predictor``; a checkpoint with a rotational
output adds the raw ``angular_velocity`` now and its ``angular_sigma`` (0.0 / -1 without).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from aslip_ros.learn.calibration.frames import FrameCutter, window_offsets
from aslip_ros.learn.checkpoint import Checkpoint, estimates_rotation, load_checkpoint
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.calibration.output import angular_sigma_model, sigma_model
from aslip_ros.learn.inference.predictor import Prediction, PredictorBase
from aslip_ros.learn.incremental_features import StreamingLogMel, stream_logmel
from aslip_ros.learn.inference.audio_window import StreamGate
from aslip_ros.learn.models.registry import model_backend

DEFAULT_MAX_TIME_JUMP_S = 0.05


@dataclass(frozen=True)
class StreamEstimate:
    """One hop's estimate and the stream instant it describes."""

    stamp_ns: int
    sample_index: int           # stream index one past the frame's last sample
    prediction: Prediction
    raw_velocity: tuple[float, float] = (0.0, 0.0)   # ungated (vx, vz), for evaluation


class StreamingPredictor(PredictorBase):
    """Per-hop p(slip) and slip velocity from a stream of audio blocks."""

    def __init__(self, ckpt: Checkpoint, threshold: float | None = None,
                 max_time_jump_s: float = DEFAULT_MAX_TIME_JUMP_S) -> None:
        backend = model_backend(ckpt.model_type)
        if not backend.streaming:
            raise ValueError(f"StreamingPredictor needs a streaming checkpoint (aslip_stream), "
                             f"got {ckpt.model_type!r} (window models use learn.inference."
                             "predictor)")
        self.checkpoint = ckpt
        self.feature_config = FeatureConfig.from_dict(ckpt.meta["feature_config"])
        self.backend = backend.from_checkpoint(ckpt)
        self.model_config = self.backend.cfg
        self.stepper = self.backend.stepper()
        self.features = StreamingLogMel(self.feature_config, ckpt.sample_rate,
                                        len(ckpt.channel_names))
        self.gate = StreamGate(max_time_jump_s)
        self.window_s = float(ckpt.meta["window_s"])
        self.hop_s = float(ckpt.meta["hop_s"])
        self.set_threshold(threshold)
        self.sigma_model = sigma_model(ckpt.meta)     # None: direction_sigma -1 (unknown)
        self.estimates_rotation = estimates_rotation(ckpt.meta)
        self.angular_sigma_model = angular_sigma_model(ckpt.meta)
        self._origin: int | None = None        # stream index of the first sample since reset
        self._origin_ns = 0
        self.resets = 0
        self.last_reset_reason = ""
        # Per-grasp calibration (a checkpoint with ``calibration``): the same state as the
        # window models', fed every sample of the grasp; frame k is read with the state
        # after the calibration frames complete by its last sample.
        self._open_calibration()

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, threshold: float | None = None,
                        max_time_jump_s: float = DEFAULT_MAX_TIME_JUMP_S
                        ) -> "StreamingPredictor":
        return cls(load_checkpoint(path), threshold, max_time_jump_s)

    @property
    def window_samples(self) -> int:
        return int(self.meta["window_samples"])

    @property
    def fresh(self) -> bool:
        """True when no audio was fed since the last reset (a reset would forget nothing)."""
        return self._origin is None

    def reset(self, reason: str = "reset") -> None:
        """Forget the audio history, the recurrent state and the grasp's calibration."""
        self.features.reset()
        self.stepper.reset()
        self.reset_calibration()
        self._origin = None
        self.resets += 1
        self.last_reset_reason = reason

    def warm_up(self, n: int = 3) -> None:
        """Run ``n`` silent frames through features and model (first calls allocate), then
        start clean: no audio, no state, no reset counted."""
        fc = self.feature_config
        n_in = ((n - 1) * fc.hop + fc.n_fft) * self.features.factor
        self.features.push(np.zeros((n_in, self.n_channels), np.float32))
        for _ in range(n):
            self.stepper.step(np.zeros((self.n_channels, self.feature_config.n_mels),
                                       np.float32))
        self.features.reset()
        self.stepper.reset()
        self._origin = None

    def push(self, a) -> list[StreamEstimate]:
        """Feed one block; the estimates of the hops it completes (empty when the block is
        dropped as repeated / out of order, or no hop completed)."""
        self._check_block(a)
        verdict, detail = self.gate.check(a)
        if verdict in ("repeated", "out_of_order"):
            return []
        if verdict != "ok":
            self.reset(f"{verdict}: {detail}")
        self.gate.accept(a)
        return self.feed(a)

    def _check_block(self, a) -> np.ndarray:
        x = np.asarray(a.block)
        if x.ndim != 2 or x.shape[1] != len(self.channel_names) or x.shape[0] != a.frames:
            raise ValueError(f"block shaped {x.shape} does not match {a.frames} frames of "
                             f"{len(self.channel_names)} channels")
        if not np.isfinite(x).all():
            # The next accepted block follows a hole: start over, as after a gap.
            self.reset("refused block: NaN or Inf")
            raise ValueError("audio block contains NaN or Inf")
        return x

    def feed(self, a) -> list[StreamEstimate]:
        """``push`` without the continuity gate: for a caller that has judged ``a`` the next
        block of the stream (and called ``reset`` where it is not)."""
        x = self._check_block(a)
        if self._origin is None:
            self._origin, self._origin_ns = int(a.first_sample_index), int(a.stamp_ns)
        first_frame = self.features.n_frames
        frames = self.features.push(x)
        return self._estimates(frames, first_frame, a)

    def _estimates(self, frames: np.ndarray, first_frame: int, a) -> list[StreamEstimate]:
        out = []
        ends = self.features.frame_end_samples(np.arange(first_frame,
                                                         first_frame + frames.shape[0]))
        # Sample times on the block's clock: the rate the gate holds the stamps to.
        ns_per = (a.end_stamp_ns - a.stamp_ns) / a.frames if a.frames else 1e9 / a.sample_rate
        block = np.asarray(a.block, np.float32)
        fed = 0                       # samples of this block given to the calibration
        cal = self._stream_cal
        for frame, end in zip(frames, ends):
            idx = self._origin + int(end)
            if cal is not None:
                upto = idx - int(a.first_sample_index)
                cal.push(block[fed:upto])
                fed = upto
                frame = frame - cal.offsets.astype(np.float32)[:, None]
            p, v, w = self.stepper.step(frame)
            stamp = int(a.stamp_ns + round((idx - 1 - a.first_sample_index) * ns_per))
            out.append(StreamEstimate(stamp, idx, self._prediction(p, v, w),
                                      (float(v[0]), float(v[1]))))
        if cal is not None:
            cal.push(block[fed:])
        return out

    def _prediction(self, p: float, v: np.ndarray, w: float | None = None) -> Prediction:
        t = self._threshold
        slipping = bool(p >= t)
        vx, vz = (float(v[0]), float(v[1])) if slipping else (0.0, 0.0)
        speed = float(np.hypot(vx, vz))
        d = (vx / speed, vz / speed) if speed > 0 else (0.0, 0.0)
        sigma = -1.0 if self.sigma_model is None else \
            float(self.sigma_model(float(np.hypot(v[0], v[1]))))
        rate, rate_sigma = 0.0, -1.0
        if self.estimates_rotation and w is not None:     # raw: not gated by ``slipping``
            rate = float(w)
            if self.angular_sigma_model is not None:
                rate_sigma = float(self.angular_sigma_model(rate))
        return Prediction(float(p), slipping, vx, vz, speed, d, self.window_s, t, sigma,
                          rate, rate_sigma)

    def trial_outputs(self, audio: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """A whole ``(n, C)`` recording from a zero state (offline, batched; equal to pushing
        it block by block): frame end sample indices (exclusive, from the recording's first
        sample), p, the raw (ungated) velocity and the rate wy per frame (None: the model has
        no rotational output)."""
        audio = np.asarray(audio, np.float32)
        frames = stream_logmel(audio, self.feature_config, self.sample_rate)
        ends = self.features.frame_end_samples(np.arange(frames.shape[0]))
        if self.calibration is not None:
            cutter = FrameCutter(self.feature_config, self.sample_rate)
            offsets = window_offsets(cutter.frames(audio), ends, cutter, self.calibration)
            frames = frames - offsets.astype(np.float32)[:, :, None]
        p, v, w = self.offline(frames)
        return ends, np.asarray(p), np.asarray(v), None if w is None else np.asarray(w)

    def offline(self, frames: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Batched torch forward over ``(T, C, M)`` frames from a zero state: p, raw v and
        wy (None without the rotational output)."""
        p, v, w = self.backend.offline(frames)
        return p, v, w if self.estimates_rotation else None
