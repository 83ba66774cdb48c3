"""Multi-channel log-mel spectrograms: the one feature path for training, evaluation and the node.

Input is audio at the stream's rate, shaped ``(..., n_samples, n_channels)`` float32 (the
layout of ``AudioFrame`` blocks and of the dataset's ``audio/<k>.npy``). Output is natural-log
mel power shaped ``(..., n_channels, n_mels, n_frames)`` float32. Normalisation with dataset
statistics is *not* applied here: the statistics live inside the model (see
``network.SlipNet``) so that a checkpoint carries them and nothing else can drift.

Every window is featurised on its own (resampled, framed, transformed) whether it comes from
the dataset or from the live ring buffer, so training and inference see identical numbers,
edge effects included. The live node's ``SlidingLogMel`` computes the same numbers for the
newest window of a stream while reusing the frames it shares with earlier windows: a frame
whose resampling filter reads no sample outside the window depends only on those samples,
wherever the window starts; every other frame (the first, whose filter reads the zeros
before the window) is computed for each window as ``LogMel`` does. Both go through
``LogMel.frames_logmel``, so they agree to float rounding (tested on scene audio).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np


@dataclass(frozen=True)
class FeatureConfig:
    """Log-mel parameters; stored verbatim in every checkpoint.

    ``sample_rate`` is the rate the features are computed at (Hz); audio at another rate is
    resampled to it with a polyphase filter. ``fmax`` of ``None`` means Nyquist.
    Frames are not centred (no padding): a window of N samples at the feature rate gives
    ``1 + (N - n_fft) // hop`` frames, so no frame mixes in invented samples.
    """

    sample_rate: float = 16000.0
    n_fft: int = 512
    hop: int = 160
    n_mels: int = 40
    fmin: float = 30.0
    fmax: float | None = None
    log_floor: float = 1e-10

    def __post_init__(self) -> None:
        if not (self.sample_rate > 0 and math.isfinite(self.sample_rate)):
            raise ValueError(f"sample_rate must be positive, got {self.sample_rate}")
        if self.n_fft < 16 or self.hop < 1 or self.n_mels < 1:
            raise ValueError(f"bad n_fft/hop/n_mels: {self.n_fft}/{self.hop}/{self.n_mels}")
        if self.n_mels > self.n_fft // 2 + 1:
            raise ValueError(f"n_mels={self.n_mels} exceeds the {self.n_fft // 2 + 1} FFT bins")
        top = self.sample_rate / 2 if self.fmax is None else self.fmax
        if not (0 <= self.fmin < top <= self.sample_rate / 2):
            raise ValueError(f"need 0 <= fmin < fmax <= Nyquist, got {self.fmin}, {top}")
        if self.log_floor <= 0:
            raise ValueError("log_floor must be positive")

    @property
    def f_max(self) -> float:
        return self.sample_rate / 2 if self.fmax is None else float(self.fmax)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "FeatureConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown feature parameters: {sorted(unknown)}")
        return cls(**d)

    def n_frames(self, window_s: float) -> int:
        """Frames produced for a window of ``window_s`` seconds."""
        n = int(round(window_s * self.sample_rate))
        if n < self.n_fft:
            raise ValueError(
                f"a {window_s * 1e3:.0f} ms window has {n} samples at {self.sample_rate:g} Hz,"
                f" fewer than n_fft={self.n_fft}")
        return 1 + (n - self.n_fft) // self.hop


def hz_to_mel(f: np.ndarray | float) -> np.ndarray:
    """HTK mel scale."""
    return 2595.0 * np.log10(1.0 + np.asarray(f, dtype=np.float64) / 700.0)


def mel_to_hz(m: np.ndarray | float) -> np.ndarray:
    return 700.0 * (10.0 ** (np.asarray(m, dtype=np.float64) / 2595.0) - 1.0)


def mel_filterbank(cfg: FeatureConfig) -> np.ndarray:
    """Triangular filters, peak 1, shape ``(n_mels, n_fft // 2 + 1)``.

    Filters too narrow to cover any FFT bin (small n_fft, many mels) would be silent
    forever; each filter is therefore guaranteed at least its nearest bin.
    """
    n_bins = cfg.n_fft // 2 + 1
    freqs = np.arange(n_bins) * cfg.sample_rate / cfg.n_fft
    edges = mel_to_hz(np.linspace(hz_to_mel(cfg.fmin), hz_to_mel(cfg.f_max), cfg.n_mels + 2))
    lo, mid, hi = edges[:-2, None], edges[1:-1, None], edges[2:, None]
    up = (freqs[None, :] - lo) / np.maximum(mid - lo, 1e-9)
    down = (hi - freqs[None, :]) / np.maximum(hi - mid, 1e-9)
    fb = np.clip(np.minimum(up, down), 0.0, None)
    empty = fb.sum(axis=1) == 0
    if np.any(empty):
        nearest = np.abs(freqs[None, :] - mid[empty]).argmin(axis=1)
        fb[np.flatnonzero(empty), nearest] = 1.0
    return fb.astype(np.float32)


def antialias_taps(rate: int) -> np.ndarray:
    """Linear-phase low-pass FIR for resampling by ``rate`` (float64, ``20 rate + 1`` taps):
    a sinc with its cutoff at ``1 / rate`` of Nyquist under a Kaiser window (beta 5), scaled
    to unit gain at DC. This is the filter scipy.signal.resample_poly designs with
    ``firwin``; it is written with numpy's ``sinc`` and ``kaiser`` because importing
    scipy.signal (which imports scipy.stats) costs every start of slip_inference 1.3-1.8 s
    of CPU. test_learn_features checks that it equals ``firwin``'s taps."""
    half = 10 * int(rate)
    taps = np.sinc(np.arange(-half, half + 1) / rate) * np.kaiser(2 * half + 1, 5.0)
    return taps / taps.sum()


def periodic_hann(n: int) -> np.ndarray:
    """The periodic Hann window of ``n`` samples (scipy's ``get_window("hann", n)``): the
    standard analysis window for overlapping STFT frames."""
    return np.hanning(n + 1)[:-1]


def resample_ratio(input_rate: float, output_rate: float) -> tuple[int, int]:
    """(up, down) integers for the polyphase resampler; exact for the usual audio rates."""
    frac = Fraction(output_rate / input_rate).limit_denominator(1000)
    if abs(float(frac) * input_rate - output_rate) > 1e-6 * output_rate:
        raise ValueError(f"cannot resample {input_rate:g} Hz to {output_rate:g} Hz exactly")
    return frac.numerator, frac.denominator


class LogMel:
    """Featuriser for one input stream rate.

    ``LogMel(cfg, input_rate)(audio)`` with audio ``(..., n_samples, n_channels)`` returns
    ``(..., n_channels, n_mels, n_frames)`` float32. Stateless between calls.
    """

    def __init__(self, cfg: FeatureConfig, input_rate: float) -> None:
        if not (input_rate > 0 and math.isfinite(input_rate)):
            raise ValueError(f"input_rate must be positive, got {input_rate}")
        self.cfg = cfg
        self.input_rate = float(input_rate)
        self.up, self.down = resample_ratio(self.input_rate, cfg.sample_rate)
        # The same linear-phase Kaiser low-pass scipy.signal.resample_poly designs; for pure
        # decimation (up == 1) it is applied here as one strided matrix-vector product,
        # several times faster than upfirdn on short windows (the live node's case).
        rate = max(self.up, self.down)
        self._half = 10 * rate
        self._fir = np.ones(1, np.float32)
        if rate > 1:
            self._fir = (antialias_taps(rate) * self.up).astype(np.float32)
        self.window = periodic_hann(cfg.n_fft).astype(np.float32)
        self.fb_t = np.ascontiguousarray(mel_filterbank(cfg).T)  # (n_bins, n_mels)
        self.chunk = 32

    def resampled_length(self, n_samples: int) -> int:
        return -(-n_samples * self.up // self.down)

    def n_frames(self, n_samples: int) -> int:
        """Frames for ``n_samples`` input samples (at the input rate)."""
        n = self.resampled_length(n_samples)
        if n < self.cfg.n_fft:
            raise ValueError(f"{n_samples} input samples give {n} < n_fft={self.cfg.n_fft}")
        return 1 + (n - self.cfg.n_fft) // self.cfg.hop

    def resample(self, audio: np.ndarray) -> np.ndarray:
        """Resample ``(..., n_samples, C)`` to the feature rate (equals scipy's resample_poly)."""
        x = np.swapaxes(np.asarray(audio, dtype=np.float32), -1, -2)
        return np.swapaxes(self._resample_cn(np.ascontiguousarray(x)), -1, -2)

    def _resample_cn(self, x: np.ndarray) -> np.ndarray:
        """Resample along the last axis of ``(..., C, N)``."""
        if self.up == self.down:
            return x
        if self.up != 1:
            from scipy import signal as sps     # rational ratios only (see antialias_taps)
            y = sps.resample_poly(x, self.up, self.down, axis=-1)
            return y.astype(np.float32, copy=False)
        n, d, half = x.shape[-1], self.down, self._half
        n_out = -(-n // d)
        right = max((n_out - 1) * d + 2 * half + 1 - half - n, 0)
        # Zeros beyond the window's edges (np.pad's result, without its per-call overhead).
        xp = np.zeros(x.shape[:-1] + (half + n + right,), np.float32)
        xp[..., half:half + n] = x
        return self.decimate_valid(xp, n_out)

    def decimate_valid(self, xp: np.ndarray, n_out: int) -> np.ndarray:
        """Output ``j`` of the decimating filter reads ``xp[..., j * down : j * down + taps]``
        (no padding: the caller supplies the margins); ``up`` must be 1."""
        xp = np.ascontiguousarray(xp, dtype=np.float32)
        step = xp.strides[-1]
        # The taps of every output as one strided view over xp's buffer (numpy checks it
        # lies inside; sliding_window_view costs more than the filter on short inputs).
        taps = np.ndarray(xp.shape[:-1] + (n_out, self._fir.size), np.float32, xp, 0,
                          xp.strides[:-1] + (self.down * step, step))
        # einsum walks the strided view directly; matmul would first copy every tap.
        return np.einsum("...k,k->...", taps, self._fir)

    def _framed(self, audio: np.ndarray) -> np.ndarray:
        """``(..., n_samples, C)`` -> STFT frames at the feature rate ``(..., C, T, n_fft)``
        (a strided view)."""
        x = np.asarray(audio, dtype=np.float32)
        if x.ndim < 2:
            raise ValueError(f"audio must be (..., n_samples, n_channels), got {x.shape}")
        x = self._resample_cn(np.ascontiguousarray(np.swapaxes(x, -1, -2)))  # (..., C, N)
        n = x.shape[-1]
        if n < self.cfg.n_fft:
            raise ValueError(f"window of {n} samples at the feature rate < n_fft={self.cfg.n_fft}")
        x = np.ascontiguousarray(x, dtype=np.float32)
        step = x.strides[-1]
        t = 1 + (n - self.cfg.n_fft) // self.cfg.hop
        # A strided view of the frames, as in ``decimate_valid``.
        return np.ndarray(x.shape[:-1] + (t, self.cfg.n_fft), np.float32, x, 0,
                          x.strides[:-1] + (self.cfg.hop * step, step))

    def frames_power(self, frames: np.ndarray) -> np.ndarray:
        """|rfft|^2 of Hann-windowed frames ``(..., n_fft)`` at the feature rate."""
        spec = np.fft.rfft(frames * self.window, axis=-1)
        return (spec.real ** 2 + spec.imag ** 2).astype(np.float32, copy=False)

    def frames_logmel(self, frames: np.ndarray) -> np.ndarray:
        """Natural-log mel power ``(..., n_mels)`` of frames ``(..., n_fft)`` at the feature
        rate: the one transform behind ``__call__`` and ``SlidingLogMel``."""
        return np.log(np.maximum(self.frames_power(frames) @ self.fb_t, self.cfg.log_floor))

    def power_spectrogram(self, audio: np.ndarray) -> np.ndarray:
        """|STFT|^2, shape ``(..., n_channels, n_frames, n_fft // 2 + 1)``, at the feature rate."""
        return self.frames_power(self._framed(audio))

    def __call__(self, audio: np.ndarray) -> np.ndarray:
        x = np.asarray(audio, dtype=np.float32)
        if x.ndim == 3 and x.shape[0] > self.chunk:
            # Large batches thrash the cache in the framed FFT; small chunks are ~3x faster.
            return np.concatenate([self(x[s:s + self.chunk])
                                   for s in range(0, x.shape[0], self.chunk)])
        out = self.frames_logmel(self._framed(x))   # (..., C, T, M)
        return np.ascontiguousarray(np.swapaxes(out, -1, -2), dtype=np.float32)


class SlidingLogMel:
    """``LogMel`` of the newest window of a stream, reusing what earlier windows computed.

        sliding = SlidingLogMel(LogMel(cfg, 48000.0), window_samples)
        feats = sliding(window, start)      # == LogMel(cfg, 48000.0)(window), (C, M, T)

    ``start`` is the stream index of the window's first sample, counted from any origin
    that stays fixed until ``reset`` (the live estimator: since its window last restarted);
    ``epoch`` names that origin (a new one forgets every frame, like ``reset``). A frame is
    *inner* when its resampling filter reads only samples inside the window: its log-mel
    then depends on nothing but those samples, so it is kept under the index of the first
    one and reused by every later window that holds the same frame (a window moved by a
    multiple of the hop holds all but one of them again). Other frames, and every frame
    of a rate ratio that needs upsampling (``up != 1``), are computed for each window
    exactly as ``LogMel`` does: the zeros around the window included. Not thread-safe.
    """

    def __init__(self, logmel: LogMel, window_samples: int) -> None:
        self.logmel = logmel
        self.window_samples = int(window_samples)
        self.n_frames = logmel.n_frames(self.window_samples)
        cfg, d = logmel.cfg, logmel.down
        #: input samples one frame's filter reads (margins included) and how far the first
        #: one lies before the frame's first sample; 0 without resampling
        self._margin = logmel._half if logmel.up == 1 and d > 1 else 0
        self._span = (cfg.n_fft - 1) * d + 1 + 2 * self._margin
        self.first = np.arange(self.n_frames) * cfg.hop * d - self._margin
        self.inner = (self.first >= 0) & (self.first + self._span <= self.window_samples)
        self.reusable = logmel.up == 1
        self._frames: dict[int, np.ndarray] = {}
        self._epoch: object = None
        self.computed = 0           # frames computed since construction (tests, benchmarks)
        self.reused = 0             # frames taken from an earlier window

    def reset(self) -> None:
        """Forget every kept frame (the stream index origin changes)."""
        self._frames = {}

    def __call__(self, window: np.ndarray, start: int, epoch: object = None) -> np.ndarray:
        """The log-mel ``(C, n_mels, n_frames)`` float32 of ``window`` ``(N, C)``, whose
        first sample has stream index ``start`` in origin ``epoch``."""
        x = np.asarray(window, dtype=np.float32)
        if x.ndim != 2 or x.shape[0] != self.window_samples:
            raise ValueError(f"expected a window shaped ({self.window_samples}, C), "
                             f"got {x.shape}")
        if not self.reusable:
            self.computed += self.n_frames
            return self.logmel(x)
        if epoch != self._epoch:
            self._frames, self._epoch = {}, epoch
        start = int(start)
        kept, frames, missing = {}, [None] * self.n_frames, []
        for k in range(self.n_frames):
            key = start + int(self.first[k])
            f = self._frames.get(key) if self.inner[k] else None
            if f is None:
                missing.append(k)
            else:
                frames[k] = kept[key] = f
        if missing:
            mel = self._compute(x, missing)                      # (len(missing), C, M)
            for i, k in enumerate(missing):
                frames[k] = mel[i]
                if self.inner[k]:
                    kept[start + int(self.first[k])] = mel[i]
        self.computed += len(missing)
        self.reused += self.n_frames - len(missing)
        self._frames = kept             # only this window's frames can recur
        return np.stack(frames, axis=-1)

    def _compute(self, x: np.ndarray, ks: list[int]) -> np.ndarray:
        """Frames ``ks`` of window ``x`` ``(N, C)``: ``(len(ks), C, n_mels)``, from the
        samples each one reads (zeros outside the window, as ``LogMel`` pads)."""
        n, n_fft, span = x.shape[0], self.logmel.cfg.n_fft, self._span
        seg = np.zeros((len(ks), span, x.shape[1]), np.float32)
        for i, k in enumerate(ks):
            lo = int(self.first[k])
            a, b = max(lo, 0), min(lo + span, n)
            seg[i, a - lo:b - lo] = x[a:b]
        seg = np.ascontiguousarray(np.swapaxes(seg, 1, 2))       # (K, C, span)
        if self.logmel.down > 1:
            seg = self.logmel.decimate_valid(seg, n_fft)         # (K, C, n_fft)
        return self.logmel.frames_logmel(seg)


def normalization_stats(features: np.ndarray, max_windows: int = 20000,
                        seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Per-mel-bin mean and std over windows, channels and frames.

    ``features``: ``(n_windows, C, M, T)``. Channels are pooled on purpose: a per-channel
    normalisation would remove the steady level differences between microphones that the
    direction head reads.
    """
    if features.ndim != 4 or features.shape[0] == 0:
        raise ValueError(f"need (n_windows, C, M, T) with n_windows > 0, got {features.shape}")
    idx = np.arange(features.shape[0])
    if idx.size > max_windows:
        idx = np.sort(np.random.default_rng(seed).choice(idx, max_windows, replace=False))
    x = np.asarray(features[idx], dtype=np.float64)
    mean = x.mean(axis=(0, 1, 3))
    std = x.std(axis=(0, 1, 3))
    return mean.astype(np.float32), np.maximum(std, 1e-3).astype(np.float32)
