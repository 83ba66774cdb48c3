"""The live path's cost cuts change no number: the sliding log-mel of the live estimator
equals the training path's ``LogMel`` of the same window, and every shipped checkpoint's
live estimates equal its offline ones, across a window restart (gap) and with the per-grasp
calibration's offsets (issue #39, "the live cost cut where it goes")."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from aslip_ros.audio_frame import AudioData
from aslip_ros.learn.calibration.frames import FrameCutter, window_offsets
from aslip_ros.learn.features import FeatureConfig, LogMel, SlidingLogMel
from aslip_ros.learn.inference.channel_check import dead_channels
from aslip_ros.learn.inference.live import LiveConfig, LiveEstimator, load_predictor

ROOT = Path(__file__).resolve().parents[1]
RATE = 48000.0
BLOCK = 480
WINDOW_MODELS = ("aslip_cnn", "aslip_cnn_uncalibrated", "svm", "svm_logmel", "per_output",
                 "per_output_mixed", "per_output_logmel")
GAP_AT = 60                    # blocks 60 and 61 never arrive: the window restarts
N_BLOCKS = 110
#: per_output models of the shipped ones (learn/models/per_output.py): part -> roles.
PER_OUTPUT = {
    "per_output": {"aslip_cnn": ("detection", "direction", "rotation"), "svm": ("speed",)},
    # Two CNN parts read the one sliding log-mel, one with the per-grasp offsets, one not.
    "per_output_mixed": {"aslip_cnn_uncalibrated": ("detection", "direction"),
                         "aslip_cnn": ("speed", "rotation")},
    # The speed from an SVM on the CNN's log-mel: both parts read the sliding features.
    "per_output_logmel": {"aslip_cnn": ("detection", "direction", "rotation"),
                          "svm_logmel": ("speed",)},
}


def _svm_logmel(where: Path) -> Path:
    """An SVM on the shipped CNN's time-averaged log-mel (its features and calibration),
    fitted on windows of scene audio with labels made from their level: its answers vary
    with what it hears, which is all the comparison needs."""
    from aslip_ros.hw.sources import build_world
    from aslip_ros.learn.checkpoint import PLANAR_OUTPUTS, load_checkpoint, save_checkpoint
    from aslip_ros.learn.models.svm import LogMelMeans, SvmConfig, fit_svm
    path = where / "svm_logmel.pt"
    if path.exists():
        return path
    cnn = load_checkpoint(_model("aslip_cnn"))
    w = build_world(dict(scenario="external_induced", seed=9, object="cracker_box",
                         layout="4mic", pad="textured", condition="robot_stationary",
                         sample_rate=RATE, wall_distance_m=0.0, drag_speed_m_s=0.04))
    audio = np.concatenate([w.step(BLOCK).audio for _ in range(300)]).astype(np.float32)
    n = cnn.meta["window_samples"]
    windows = np.stack([audio[s:s + n] for s in range(0, audio.shape[0] - n, 2400)])
    feats = LogMelMeans(FeatureConfig.from_dict(cnn.meta["feature_config"]), RATE)(windows)
    level = feats.mean(axis=1)
    slip = level > np.median(level)
    ang = np.linspace(-np.pi, np.pi, len(level))
    v = np.where(slip[:, None], 0.01 + 0.001 * (level - level.min())[:, None], 0.0) * \
        np.stack([np.cos(ang), np.sin(ang)], axis=1)
    cfg = SvmConfig(features="logmel")
    arrays, _ = fit_svm(feats, slip, v, cfg)
    meta = dict(cnn.meta, model_type="svm", model_config=cfg.to_dict(), normalization=None,
                outputs=list(PLANAR_OUTPUTS))
    meta.pop("output_calibration", None)
    return save_checkpoint(path, meta, arrays.to_tensors())


def _model(name: str, where: Path | None = None) -> Path:
    if name == "svm_logmel":
        return _svm_logmel(where)
    if name in PER_OUTPUT:
        from aslip_ros.learn.checkpoint import load_checkpoint, save_checkpoint
        from aslip_ros.learn.models.per_output import assemble
        parts = PER_OUTPUT[name]
        ck = assemble({n: load_checkpoint(_model(n, where)) for n in parts},
                      {role: n for n, roles in parts.items() for role in roles})
        return save_checkpoint(where / f"{name}.pt", ck.meta, ck.tensors)
    path = ROOT / "models" / f"{name}.pt"
    if not path.exists():
        pytest.skip(f"{path} not shipped in this checkout")
    return path


@pytest.fixture(scope="module")
def scene():
    """1.1 s of a simulated external-induced grasp (4 microphones): the audio and its
    blocks, with two blocks lost at ``GAP_AT``."""
    from aslip_ros.hw.sources import build_world
    w = build_world(dict(scenario="external_induced", seed=5, object="chips_can",
                         layout="4mic", pad="textured", condition="robot_stationary",
                         sample_rate=RATE, wall_distance_m=0.0, drag_speed_m_s=0.04))
    names = list(w.metadata()["channel_names"])
    audio = np.concatenate([w.step(BLOCK).audio for _ in range(N_BLOCKS)]).astype(np.float32)
    blocks = []
    for i in range(N_BLOCKS):
        if i in (GAP_AT, GAP_AT + 1):
            continue
        s = i * BLOCK
        blocks.append(AudioData(s, 1_000_000_000_000 + int(round(s * 1e9 / RATE)), RATE,
                                names, "4mic", "aslip_sensor", audio[s:s + BLOCK]))
    return audio, blocks


def _grasp_offsets(pr, audio: np.ndarray, start: int, end: int) -> np.ndarray | None:
    """The offline (training) per-grasp offsets of the window ending at ``end`` of a grasp
    that began at stream sample ``start``."""
    if pr.calibration is None:
        return None
    cutter = FrameCutter(pr.feature_config, pr.sample_rate)
    grasp = audio[start:end]
    return window_offsets(cutter.frames(grasp), np.array([grasp.shape[0]]), cutter,
                          pr.calibration)[0]


@pytest.mark.parametrize("name", WINDOW_MODELS)
def test_window_models_estimate_live_what_the_training_path_computes(scene, name, tmp_path):
    audio, blocks = scene
    model = _model(name, tmp_path)
    est = LiveEstimator.from_checkpoint(model, LiveConfig(hop_s=0.01))
    ref = load_predictor(model)                  # featurises each window whole
    logmel = LogMel(ref.feature_config, ref.sample_rate)
    grasp_start, n_jobs, epochs = 0, 0, set()
    for a in blocks:
        if a.first_sample_index == (GAP_AT + 2) * BLOCK:
            grasp_start = a.first_sample_index          # the gap starts a new grasp
        _, job = est.accept(a)
        if job is None:
            continue
        n_jobs += 1
        epochs.add(job.epoch)
        end = a.first_sample_index + a.frames
        window = audio[end - ref.window_samples:end]
        np.testing.assert_array_equal(job.window, window)
        offsets = _grasp_offsets(ref, audio, grasp_start, end)
        if offsets is None:
            assert job.offsets is None
        else:
            np.testing.assert_allclose(job.offsets, offsets, rtol=1e-6, atol=1e-7)
        got = est.run(job)
        want = ref.predict(window, offsets)
        assert got is not None
        for f in ("probability", "vx", "vz", "angular_velocity"):
            assert math.isclose(getattr(got.prediction, f), getattr(want, f),
                                rel_tol=1e-4, abs_tol=1e-5), (name, end, f)
        assert got.prediction.slipping == want.slipping or \
            abs(want.probability - want.threshold) < 1e-4
        if est._sliding is not None:                     # the CNN: features equal too
            feats = est._sliding(window, job.start, job.epoch)
            np.testing.assert_allclose(feats, logmel(window), rtol=0, atol=2e-5)
    assert n_jobs > 50 and epochs == {0, 1}
    if name != "svm":                        # each of these reads the sliding log-mel
        s = est._sliding
        assert s is not None and s.reused > 5 * s.computed     # two frames a hop


def test_the_streaming_model_estimates_live_what_it_computes_offline(scene):
    audio, blocks = scene
    est = LiveEstimator.from_checkpoint(_model("aslip_stream"))
    live = [e for a in blocks for e in est.feed(a)]
    ref = load_predictor(_model("aslip_stream"))
    want = []
    for lo, hi in ((0, GAP_AT * BLOCK), ((GAP_AT + 2) * BLOCK, N_BLOCKS * BLOCK)):
        ends, p, v, _ = ref.trial_outputs(audio[lo:hi])   # from a zero state, calibrated
        want += [(lo + int(end), float(pk), vk) for end, pk, vk in zip(ends, p, v)]
    assert len(live) == len(want) > 80
    for e, (end, pk, vk) in zip(live, want):
        stamp = 1_000_000_000_000 + (end - 1) * 1e9 / RATE
        assert abs(e.stamp_ns - stamp) < 1e3
        assert math.isclose(e.prediction.probability, pk, abs_tol=1e-4)
        np.testing.assert_allclose(e.raw_velocity, vk, atol=1e-4)


@pytest.mark.parametrize("rate,cfg", [
    (48000.0, FeatureConfig()),
    (16000.0, FeatureConfig()),                          # no resampling
    (32000.0, FeatureConfig(n_fft=256, hop=80, n_mels=24)),
    (44100.0, FeatureConfig()),                          # upsampling: featurised whole
])
def test_sliding_log_mel_equals_log_mel_whatever_the_window_moves_by(rate, cfg):
    rng = np.random.default_rng(3)
    n = int(0.2 * rate)
    t = np.arange(n * 6)[:, None] / rate
    # A loud tone over a faint floor: the zeros before a window then change its first
    # frame well beyond float rounding (on white noise alone they hardly show).
    audio = (np.sin(2 * np.pi * np.array([110.0, 170.0, 230.0]) * t)
             + 1e-4 * rng.standard_normal((n * 6, 3))).astype(np.float32)
    lm = LogMel(cfg, rate)
    sliding = SlidingLogMel(lm, n)
    if lm.up == 1 and lm.down > 1:
        step = cfg.hop * lm.down
        later, earlier = lm(audio[step:step + n]), lm(audio[:n])
        assert np.abs(later[..., 0] - earlier[..., 1]).max() > 1e-3   # an edge frame differs
    hop = int(round(rate * 0.01))
    starts = [0, hop, 2 * hop, 2 * hop + 7, 3 * hop + 7, 5 * hop, 5 * hop + 1, 9 * hop]
    for epoch, offset in ((0, 0), (1, n), (1, n + hop)):
        for s in starts:
            w = audio[offset + s:offset + s + n]
            np.testing.assert_allclose(sliding(w, offset + s, epoch), lm(w), rtol=0,
                                       atol=2e-5)
    if lm.up == 1:
        assert sliding.reused > 0
    with pytest.raises(ValueError):
        sliding(audio[:n - 1], 0, 0)


def test_the_cheaper_dead_channel_check_finds_what_the_einsum_one_found():
    rng = np.random.default_rng(4)
    names = ["a", "b", "c", "d"]
    for trial in range(50):
        x = (10 ** rng.uniform(-4, -1, 4) * rng.standard_normal((2400, 4))).astype(np.float32)
        if trial % 3 == 0:
            x[:, trial % 4] = 0.0
        elif trial % 3 == 1:
            x[:, trial % 4] *= 10 ** (-rng.uniform(1.5, 2.5))
        ms = np.einsum("ij,ij->j", x, x) / x.shape[0]
        rms = np.sqrt(ms)
        want = []
        for i in range(4):
            ref = float(np.median(np.delete(rms, i)))
            if rms[i] <= 1e-7 or (ref > 1e-7 and rms[i] < ref * 10 ** (-40 / 20)):
                want.append(names[i])
        assert dead_channels(x, names) == want
