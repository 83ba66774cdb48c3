"""Calibration frames from audio: streaming equals offline, a one-sided grasp does not bias
the gain estimate, and the Predictor's streaming API and stream checks."""

import numpy as np
import pytest
from scipy import signal as sps

from aslip_ros.learn.calibration import grasp as cal
from aslip_ros.learn.calibration.frames import (FrameCutter, StreamCalibration, grasp_frames,
                                                window_offsets)
from aslip_ros.learn.checkpoint import Checkpoint, CheckpointMismatch
from aslip_ros.learn.features import FeatureConfig

SR = 16000.0
NAMES = ("a", "b", "c", "d")
MIC_ANGLE = np.array([0.25, 0.75, 1.25, 1.75]) * np.pi
FC = FeatureConfig(n_mels=16, n_fft=256, hop=160)
_HIGH = sps.butter(4, [3000.0, 6000.0], btype="bandpass", fs=SR, output="sos")
_LOW = sps.butter(4, [200.0, 1000.0], btype="bandpass", fs=SR, output="sos")


def grasp_audio(rng, gain_db, seconds=20.0, one_sided=None):
    """Audio (n, 4) of one grasp and per-sample slip: intermittent common-mode background
    (low band), slip (high band) louder at the microphones it moves towards, a floor, and
    each microphone's coupling ``gain_db``. ``one_sided``: 80 % of the slip within +-30 deg
    of that direction."""
    n = int(seconds * SR)
    seg = int(0.5 * SR)
    k = n // seg + 1
    kind = rng.choice(3, k, p=[0.3, 0.35, 0.35])            # quiet, background, slip
    ang = rng.uniform(-np.pi, np.pi, k)
    if one_sided is not None:
        near = rng.random(k) < 0.8
        ang = np.where(near, one_sided + rng.uniform(-np.pi / 6, np.pi / 6, k), ang)
    bg = np.repeat(kind == 1, seg)[:n]
    slip = np.repeat(kind == 2, seg)[:n]
    pattern = np.repeat(1.0 + 0.7 * np.cos(ang[:, None] - MIC_ANGLE[None, :]), seg, 0)[:n]
    audio = 0.05 * bg[:, None] * sps.sosfilt(_LOW, rng.standard_normal((n, 1)), axis=0)
    audio = audio + 0.05 * slip[:, None] * pattern * sps.sosfilt(
        _HIGH, rng.standard_normal((n, 4)), axis=0)
    audio = audio * 10.0 ** (np.asarray(gain_db) / 20.0)
    audio = audio + 1e-4 * rng.standard_normal((n, 4))
    return audio.astype(np.float32), slip


def rel_db(gain_db):
    g = np.asarray(gain_db, dtype=float)
    return g - g.mean()


@pytest.fixture(scope="module")
def constants():
    rng = np.random.default_rng(0)
    cutter = FrameCutter(FC, SR)
    frames, labels, truth = [], [], []
    for _ in range(6):
        g = rng.uniform(-3.0, 3.0, 4)
        a, slip = grasp_audio(rng, g, seconds=15.0)
        f = cutter.frames(a)
        centre = np.arange(f.shape[2]) * cutter.hop + cutter.span // 2
        frames.append(f)
        labels.append(slip[centre])
        truth.append(cal.relative_log_gain(10.0 ** (g / 20.0)))
    return {m: cal.fit_constants(frames, labels, NAMES, cutter.hop_s, true_offsets=truth,
                                 method=m) for m in ("background", "slip")}


def test_frames_follow_the_stream_not_the_blocks(constants):
    """Any block size, the same frames as the whole grasp at once; offsets per window end."""
    k = constants["background"]
    rng = np.random.default_rng(1)
    a, _ = grasp_audio(rng, [2.0, -1.0, 0.0, -1.0], seconds=3.0)
    frames = grasp_frames(a, FC, SR)
    cutter = FrameCutter(FC, SR)
    assert frames.shape[2] == cutter.count(a.shape[0]) == 1 + (a.shape[0] - 256) // 160
    for block in (1, 160, 333, 4000):
        s = StreamCalibration(k, FC, SR)
        ends, offs = [], []
        for i in range(0, a.shape[0], block):
            s.push(a[i:i + block])
            ends.append(min(i + block, a.shape[0]))
            offs.append(s.offsets.copy())
        assert s.state.n_frames == frames.shape[2]
        np.testing.assert_allclose(offs, window_offsets(frames, np.array(ends), cutter, k),
                                   atol=1e-9)
    s.reset()
    assert s.state.n_frames == 0 and s.resets == 1 and not s.offsets.any()


@pytest.mark.parametrize("input_rate", [SR, 48000.0])
def test_frame_j_is_the_log_mel_of_its_own_samples(input_rate):
    """The module's definition: frame j is the log-mel of input samples [j*hop, j*hop+span)
    featurised on their own, at the stream's rate as at the features' (a strided view must
    not shift or mix them); the frame count is the same for an int and an array."""
    from aslip_ros.learn.features import LogMel
    cutter = FrameCutter(FC, input_rate)
    a = np.random.default_rng(2).standard_normal((cutter.span + 6 * cutter.hop + 7, 4))
    a = (0.1 * a).astype(np.float32)
    frames = cutter.frames(a[::1])
    assert frames.shape == (4, FC.n_mels, 7)
    logmel = LogMel(FC, input_rate)
    for j in range(7):
        own = logmel(a[j * cutter.hop:j * cutter.hop + cutter.span][None])[0, :, :, 0]
        np.testing.assert_allclose(frames[:, :, j], own, rtol=1e-6, atol=1e-6)
    n = np.arange(0, a.shape[0] + 1, 37)
    assert [cutter.count(int(k)) for k in n] == list(cutter.count(n))
    assert cutter.count(np.int64(n[-1])) == cutter.count(n)[-1]


def test_one_sided_grasp_does_not_bias_the_gain_estimate(constants):
    """80 % of the slip towards one side: the background estimate still finds the coupling
    (error well below the 1-2 dB a slip-energy average makes of the same grasp)."""
    rng = np.random.default_rng(7)
    gain = np.array([2.5, -1.5, 1.0, -2.0])
    a, _ = grasp_audio(rng, gain, seconds=30.0, one_sided=0.25 * np.pi)
    err = {}
    for method, k in constants.items():
        s = StreamCalibration(k, FC, SR)
        for i in range(0, a.shape[0], 480):
            s.push(a[i:i + 480])
        err[method] = float(np.sqrt(np.mean((s.state.gain_db - rel_db(gain)) ** 2)))
    assert s.state.converged
    assert err["background"] < 0.5, err
    assert err["slip"] > 1.0, err                     # the failure this method avoids


def _predictor(k, sample_rate=SR, channel_names=NAMES):
    import torch

    from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet
    from aslip_ros.learn.inference.predictor import Predictor
    torch.manual_seed(0)
    mc = ModelConfig(n_channels=4, n_mels=FC.n_mels, width=4, depth=2, temporal_layers=1,
                     temporal_channels=8, gate_hidden=4, head_hidden=8)
    meta = {"model_type": "aslip_cnn", "model_config": mc.to_dict(),
            "feature_config": FC.to_dict(), "channel_names": list(channel_names),
            "layout": "x", "sample_rate": sample_rate, "window_s": 0.2,
            "window_samples": int(0.2 * sample_rate), "epsilon_m_s": 0.005}
    if k is not None:
        meta["calibration"] = k.to_dict()
    return Predictor(Checkpoint(meta, SlipNet(mc).state_dict()))


def test_predictor_streaming_api(constants):
    k = constants["background"]
    p = _predictor(k)
    assert p.calibrated and not p.calibration_converged
    rng = np.random.default_rng(3)
    a, _ = grasp_audio(rng, [3.0, -3.0, 1.0, -1.0], seconds=8.0)
    for i in range(0, a.shape[0], 160):
        p.push_audio(a[i:i + 160])
    cutter = FrameCutter(FC, SR)
    want = window_offsets(grasp_frames(a, FC, SR), np.array([a.shape[0]]), cutter, k)[0]
    off = p.calibration_offsets()
    np.testing.assert_allclose(off, want, atol=1e-9)
    summary = p.calibration_summary()
    assert summary["calibration_frames"] == cutter.count(a.shape[0])
    assert set(summary["gain_db"]) == set(NAMES)
    w = a[-p.window_samples:]
    assert p.predict(w, off).probability != pytest.approx(p.predict(w).probability, abs=1e-7)
    with pytest.raises(ValueError, match="offsets"):
        p.predict(w, np.full(4, np.nan))
    p.reset_calibration()
    assert not p.calibration_offsets().any() and p.calibration_summary()["calibration_resets"]
    p.check_stream(SR, NAMES)
    with pytest.raises(CheckpointMismatch):
        p.check_stream(SR, ("a", "b", "d", "c"))
    # Without calibration: the same API, no state.
    plain = _predictor(None)
    plain.push_audio(a[:160])
    assert not plain.calibrated and plain.calibration_offsets() is None
    assert plain.calibration_summary() is None


def test_predictor_refuses_a_stream_its_calibration_cannot_follow(constants):
    """22.05 kHz: a 10 ms hop is no whole number of samples."""
    with pytest.raises(CheckpointMismatch, match="whole number"):
        _predictor(constants["background"].with_(), sample_rate=22050.0)


def test_calibrations_that_share_frames_keep_their_own_offsets(constants):
    """Two calibrations cutting frames with one cutter: the frames of audio seen just before
    are not computed again, and each one's offsets are bit for bit those it computes alone,
    also while the other is fed other audio (its own restart, another stream)."""
    k = constants["background"]
    rng = np.random.default_rng(3)
    a1, _ = grasp_audio(rng, [2.0, -1.0, 0.0, -1.0], seconds=2.0)
    a2, _ = grasp_audio(rng, [-2.0, 1.0, 0.5, 0.0], seconds=2.0)
    first, same, other = (StreamCalibration(k, FC, SR) for _ in range(3))
    assert same.share_frames(first) and other.share_frames(first)
    alone = [StreamCalibration(k, FC, SR) for _ in range(3)]
    for i in range(0, a1.shape[0], 160):
        for s, audio in zip((first, same, other), (a1, a1, a2)):
            s.push(audio[i:i + 160])
        for s, audio in zip(alone, (a1, a1, a2)):
            s.push(audio[i:i + 160])
        for s, ref in zip((first, same, other), alone):
            np.testing.assert_array_equal(s.offsets, ref.offsets)
    n = first.state.n_frames
    assert n > 10 and same.state.n_frames == other.state.n_frames == n
    assert first.cutter.reused == n                   # ``same`` computed none of its own
    assert not StreamCalibration(k, FeatureConfig(n_mels=16, n_fft=512, hop=160),
                                 SR).share_frames(first)     # other frames: not shared
