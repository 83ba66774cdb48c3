"""Incremental log-mel frames: one feature path for live streams and recorded trials.

    feat = StreamingLogMel(FeatureConfig(), input_rate=48000.0, n_channels=4)
    frames = feat.push(block)         # block (n, C) float32 -> (k, C, n_mels) new frames
    feat.reset()                      # after a gap: forget the history
    frames = stream_logmel(audio, cfg, 48000.0)   # a whole trial, the same computation

Audio at the stream rate is low-pass filtered with a causal FIR (the Kaiser design of
``features.LogMel``) and decimated by an integer factor, carrying the filter history from
block to block; other rate ratios are refused (a fractional polyphase state is not worth
its complexity while every supported source is a multiple of the feature rate). Frames are
``n_fft`` samples at the feature rate, ``hop`` apart, not centred: frame ``k`` covers
feature-rate samples ``[k hop, k hop + n_fft)`` of the stream since the last reset, i.e.
it ends at input sample ``(k hop + n_fft) * factor`` (exclusive). ``frame_end_samples``
gives these ends; an estimate made from frame ``k`` describes that instant.

The offline call is literally the streaming object fed one block, so training frames and
live frames agree up to float rounding whatever the block sizes.
"""

from __future__ import annotations

import math

import numpy as np

from aslip_ros.learn.features import (FeatureConfig, antialias_taps, mel_filterbank,
                                      periodic_hann, resample_ratio)


def decimation_factor(input_rate: float, feature_rate: float) -> int:
    """Integer ``input_rate / feature_rate``; ValueError for any other ratio."""
    if not (input_rate > 0 and math.isfinite(input_rate)):
        raise ValueError(f"input_rate must be positive, got {input_rate}")
    try:
        up, down = resample_ratio(float(input_rate), float(feature_rate))
    except ValueError:
        up, down = 0, 0
    if up != 1:
        raise ValueError(
            f"streaming features need the stream rate to be an integer multiple of the "
            f"feature rate; {input_rate:g} Hz -> {feature_rate:g} Hz is not supported "
            f"(choose a feature rate that divides the stream rate)")
    return int(down)


def decimation_filter(factor: int) -> np.ndarray:
    """Anti-alias FIR taps for decimation by ``factor`` (``[1.0]`` when factor is 1)."""
    if factor == 1:
        return np.ones(1, np.float32)
    return antialias_taps(factor).astype(np.float32)


class StreamingLogMel:
    """Stateful log-mel featuriser for one ``(n, n_channels)`` stream at ``input_rate``.

    ``push`` returns the frames completed by the block, ``(k, n_channels, n_mels)``
    float32 (natural-log mel power, no normalisation, as ``features.LogMel``).
    """

    def __init__(self, cfg: FeatureConfig, input_rate: float, n_channels: int) -> None:
        if int(n_channels) < 1:
            raise ValueError(f"n_channels must be >= 1, got {n_channels}")
        self.cfg = cfg
        self.input_rate = float(input_rate)
        self.n_channels = int(n_channels)
        self.factor = decimation_factor(self.input_rate, cfg.sample_rate)
        self.fir = decimation_filter(self.factor)
        self.window = periodic_hann(cfg.n_fft).astype(np.float32)
        self.fb_t = np.ascontiguousarray(mel_filterbank(cfg).T)      # (n_bins, n_mels)
        self.reset()

    @property
    def frame_step_samples(self) -> int:
        """Input samples per hop."""
        return self.cfg.hop * self.factor

    @property
    def frame_samples(self) -> int:
        """Input samples spanned by one frame."""
        return self.cfg.n_fft * self.factor

    def reset(self) -> None:
        """Forget all history: the next frame needs ``frame_samples`` fresh samples."""
        n_taps = self.fir.size
        self._hist = np.zeros((self.n_channels, n_taps - 1), np.float32)
        # Output m is taken at input sample (m + 1) factor - 1, the last sample it may see,
        # so a frame ends exactly at (k hop + n_fft) factor input samples.
        self._phase = self.factor - 1       # input samples to skip before the next output
        self._pcm = np.zeros((self.n_channels, 0), np.float32)   # feature-rate, unframed
        self.n_input = 0                    # input samples since reset
        self.n_frames = 0                   # frames emitted since reset

    def frame_end_samples(self, k: np.ndarray | int) -> np.ndarray:
        """Input-sample index (since reset, exclusive) where frame ``k`` ends."""
        return (np.asarray(k, dtype=np.int64) * self.cfg.hop + self.cfg.n_fft) * self.factor

    def _decimate(self, x: np.ndarray) -> np.ndarray:
        """Filter and decimate ``(C, n)``, carrying the FIR history."""
        if self.factor == 1:
            return x
        n_hist = self._hist.shape[1]
        buf = np.concatenate([self._hist, x], axis=1)
        self._hist = buf[:, buf.shape[1] - n_hist:].copy()
        first = self._phase
        n_out = 0 if first >= x.shape[1] else 1 + (x.shape[1] - 1 - first) // self.factor
        self._phase = first + n_out * self.factor - x.shape[1]
        if n_out == 0:
            return np.zeros((self.n_channels, 0), np.float32)
        taps = np.lib.stride_tricks.sliding_window_view(buf, self.fir.size, axis=-1)
        # Output at input position j uses samples j - n_taps + 1 .. j (causal): buf index j.
        sel = taps[:, first:first + (n_out - 1) * self.factor + 1:self.factor]
        return np.einsum("cnk,k->cn", sel, self.fir[::-1]).astype(np.float32, copy=False)

    def push(self, block: np.ndarray) -> np.ndarray:
        """Feed ``(n, n_channels)`` samples; the frames they complete, oldest first."""
        x = np.asarray(block, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.n_channels:
            raise ValueError(f"expected a block shaped (n, {self.n_channels}), got {x.shape}")
        self.n_input += x.shape[0]
        y = self._decimate(np.ascontiguousarray(x.T))
        pcm = np.concatenate([self._pcm, y], axis=1) if self._pcm.shape[1] else y
        n_fft, hop = self.cfg.n_fft, self.cfg.hop
        k = 0 if pcm.shape[1] < n_fft else 1 + (pcm.shape[1] - n_fft) // hop
        self._pcm = np.ascontiguousarray(pcm[:, k * hop:])
        self.n_frames += k
        if k == 0:
            return np.zeros((0, self.n_channels, self.cfg.n_mels), np.float32)
        frames = np.lib.stride_tricks.sliding_window_view(pcm, n_fft, axis=-1)[:, :k * hop:hop]
        spec = np.fft.rfft(frames * self.window, axis=-1)             # (C, k, bins)
        power = (spec.real ** 2 + spec.imag ** 2).astype(np.float32, copy=False)
        mel = np.log(np.maximum(power @ self.fb_t, self.cfg.log_floor))  # (C, k, M)
        return np.ascontiguousarray(np.swapaxes(mel, 0, 1), dtype=np.float32)


def stream_logmel(audio: np.ndarray, cfg: FeatureConfig, input_rate: float) -> np.ndarray:
    """All frames of a recorded ``(n, C)`` trial, ``(n_frames, C, n_mels)``: the live path
    (``StreamingLogMel``) fed the whole trial at once."""
    x = np.asarray(audio)
    if x.ndim != 2:
        raise ValueError(f"audio must be (n_samples, n_channels), got {x.shape}")
    return StreamingLogMel(cfg, input_rate, x.shape[1]).push(x)


def stream_meta_problems(meta: dict, mcfg, fcfg: FeatureConfig | None) -> list[str]:
    """What an ``aslip_stream`` checkpoint document gets wrong (empty when sound): channel
    and mel counts against the model, a stream rate the features cannot decimate, the hop
    and the label definition."""
    problems = []
    names = meta["channel_names"]
    if mcfg.n_channels != len(names):
        problems.append(f"model_config.n_channels {mcfg.n_channels} != {len(names)} "
                        f"channel_names")
    if fcfg is None:
        return problems
    if mcfg.n_mels != fcfg.n_mels:
        problems.append(f"model_config.n_mels {mcfg.n_mels} != feature_config.n_mels "
                        f"{fcfg.n_mels}")
    try:
        decimation_factor(float(meta["sample_rate"]), fcfg.sample_rate)
    except ValueError as exc:
        problems.append(str(exc))
    hop = meta.get("hop_s")
    if not isinstance(hop, (int, float)) or abs(hop - fcfg.hop / fcfg.sample_rate) > 1e-9:
        problems.append(f"hop_s must equal feature hop / rate = "
                        f"{fcfg.hop / fcfg.sample_rate:g} s, got {hop!r}")
    if not isinstance(meta.get("label"), dict) or not meta["label"].get("kind"):
        problems.append("an aslip_stream checkpoint needs a label definition (label.kind)")
    return problems
