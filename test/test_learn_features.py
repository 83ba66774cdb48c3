"""Log-mel features against an independent reference (scipy STFT + a loop-built filterbank)."""

import numpy as np
import pytest
from scipy import signal as sps

from aslip_ros.learn.features import (FeatureConfig, LogMel, antialias_taps, normalization_stats,
                                      periodic_hann)


def reference_mel_fb(sr, n_fft, n_mels, fmin, fmax):
    """Triangular HTK-mel filters built point by point, independent of features.py."""
    def mel(f):
        return 2595.0 * np.log10(1.0 + f / 700.0)

    def hz(m):
        return 700.0 * (10.0 ** (m / 2595.0) - 1.0)

    pts = [hz(mel(fmin) + i * (mel(fmax) - mel(fmin)) / (n_mels + 1)) for i in range(n_mels + 2)]
    fb = np.zeros((n_mels, n_fft // 2 + 1))
    for j in range(n_mels):
        lo, mid, hi = pts[j], pts[j + 1], pts[j + 2]
        for k in range(n_fft // 2 + 1):
            f = k * sr / n_fft
            if lo <= f <= mid:
                fb[j, k] = (f - lo) / (mid - lo)
            elif mid < f <= hi:
                fb[j, k] = (hi - f) / (hi - mid)
    return fb


def reference_logmel(audio, input_rate, cfg):
    x = sps.resample_poly(audio.astype(np.float64), 1, int(input_rate // cfg.sample_rate), axis=0)
    _, _, z = sps.stft(x.T, fs=cfg.sample_rate, window="hann", nperseg=cfg.n_fft,
                       noverlap=cfg.n_fft - cfg.hop, boundary=None, padded=False,
                       detrend=False, scaling="spectrum")
    win = sps.get_window("hann", cfg.n_fft)
    power = np.abs(z * win.sum()) ** 2                 # (C, F, T), undo scipy's scaling
    fb = reference_mel_fb(cfg.sample_rate, cfg.n_fft, cfg.n_mels, cfg.fmin, cfg.f_max)
    return np.log(np.maximum(np.einsum("mf,cft->cmt", fb, power), cfg.log_floor))


@pytest.mark.parametrize("input_rate", [48000.0, 16000.0])
def test_logmel_matches_reference(input_rate):
    cfg = FeatureConfig(sample_rate=16000.0, n_fft=256, hop=128, n_mels=24, fmin=50.0)
    rng = np.random.default_rng(0)
    n = int(0.2 * input_rate)
    t = np.arange(n) / input_rate
    audio = np.stack([np.sin(2 * np.pi * f * t) for f in (300.0, 1200.0, 3500.0)], axis=1)
    audio = (audio + 0.05 * rng.standard_normal(audio.shape)).astype(np.float32)
    ours = LogMel(cfg, input_rate)(audio)
    ref = reference_logmel(audio, input_rate, cfg)
    assert ours.shape == ref.shape == (3, 24, cfg.n_frames(0.2))
    assert ours.dtype == np.float32
    # Compare where there is energy; log of float32 rounding near the floor is noise.
    mask = ref > np.log(1e-6)
    np.testing.assert_allclose(ours[mask], ref[mask], atol=2e-3)


def test_resampler_equals_scipy_polyphase():
    lm = LogMel(FeatureConfig(), 48000.0)
    rng = np.random.default_rng(1)
    for n in (9600, 9601, 997):
        x = rng.standard_normal((n, 2)).astype(np.float32)
        ref = sps.resample_poly(x.astype(np.float64), 1, 3, axis=0)
        np.testing.assert_allclose(lm.resample(x), ref, atol=1e-5)


@pytest.mark.parametrize("rate", [2, 3, 4, 6, 441])
def test_antialias_taps_are_resample_polys_filter(rate):
    """The filter scipy.signal.resample_poly designs for this ratio (firwin, Kaiser 5.0)."""
    ref = sps.firwin(20 * rate + 1, 1.0 / rate, window=("kaiser", 5.0))
    np.testing.assert_allclose(antialias_taps(rate), ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [16, 400, 512, 1024])
def test_periodic_hann_is_scipys_hann(n):
    np.testing.assert_allclose(periodic_hann(n), sps.get_window("hann", n, fftbins=True),
                               rtol=0, atol=1e-12)


def test_batch_equals_single_and_shapes():
    cfg = FeatureConfig()
    lm = LogMel(cfg, 48000.0)
    x = np.random.default_rng(2).standard_normal((40, 9600, 4)).astype(np.float32)
    out = lm(x)
    assert out.shape == (40, 4, cfg.n_mels, cfg.n_frames(0.2))
    np.testing.assert_array_equal(out[37], lm(x[37]))
    assert lm.n_frames(9600) == out.shape[-1]


def test_config_validation_and_roundtrip():
    cfg = FeatureConfig(n_mels=32, fmax=6000.0)
    assert FeatureConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError):
        FeatureConfig(fmax=9000.0)               # above Nyquist at 16 kHz
    with pytest.raises(ValueError):
        FeatureConfig.from_dict({"bogus": 1})
    with pytest.raises(ValueError):
        LogMel(FeatureConfig(), 48000.0)(np.zeros((100, 4), np.float32))  # shorter than n_fft
    with pytest.raises(ValueError):
        FeatureConfig(n_fft=1024).n_frames(0.05)


def test_every_mel_filter_sees_a_bin():
    from aslip_ros.learn.features import mel_filterbank
    fb = mel_filterbank(FeatureConfig(n_fft=128, n_mels=48))
    assert (fb.sum(axis=1) > 0).all()


def test_normalization_stats_pool_channels():
    x = np.random.default_rng(3).standard_normal((50, 4, 8, 5)).astype(np.float32) * 3 + 7
    mean, std = normalization_stats(x)
    assert mean.shape == std.shape == (8,)
    np.testing.assert_allclose(mean, x.mean(axis=(0, 1, 3)), rtol=1e-5)
    np.testing.assert_allclose(std, x.std(axis=(0, 1, 3)), rtol=1e-4)
