"""Predictor: input validation, gating, batch consistency."""

import numpy as np
import pytest
import torch

from aslip_ros.learn.checkpoint import Checkpoint
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet
from aslip_ros.learn.inference.predictor import Predictor


def make_predictor(threshold=None, bias=0.0, n_channels=2, sr=16000.0):
    torch.manual_seed(0)
    cfg = ModelConfig(n_channels=n_channels, width=4, n_mels=40)
    net = SlipNet(cfg)
    with torch.no_grad():
        net.heads["slip"][2].bias.fill_(bias)
    meta = {"model_type": "aslip_cnn", "model_config": cfg.to_dict(),
            "feature_config": FeatureConfig().to_dict(),
            "channel_names": [f"m{i}" for i in range(n_channels)], "layout": "x",
            "sample_rate": sr, "window_s": 0.2, "window_samples": int(0.2 * sr),
            "epsilon_m_s": 0.005}
    return Predictor(Checkpoint(meta, net.state_dict()), threshold=threshold)


def window(p, seed=0):
    return (0.01 * np.random.default_rng(seed).standard_normal(
        (p.window_samples, p.n_channels))).astype(np.float32)


def test_rejects_bad_windows():
    p = make_predictor()
    w = window(p)
    with pytest.raises(ValueError):
        p.predict(w[:-1])
    with pytest.raises(ValueError):
        p.predict(w[:, :1])
    with pytest.raises(ValueError):
        p.predict(w[None])
    for bad in (np.nan, np.inf):
        x = w.copy()
        x[10, 1] = bad
        with pytest.raises(ValueError):
            p.predict(x)
    with pytest.raises(ValueError):
        p.predict(w.astype(np.complex64))


def test_gating_gives_zero_vector_and_threshold_is_configurable():
    off = make_predictor(bias=-50.0)
    pred = off.predict(window(off))
    assert not pred.slipping and pred.probability < 0.5
    assert (pred.vx, pred.vz, pred.speed, pred.direction) == (0.0, 0.0, 0.0, (0.0, 0.0))
    assert pred.window_length == pytest.approx(0.2)
    on = make_predictor(bias=50.0)
    pred = on.predict(window(on))
    assert pred.slipping and pred.speed > 0
    assert np.hypot(*pred.direction) == pytest.approx(1.0, abs=1e-5)
    assert pred.speed == pytest.approx(np.hypot(pred.vx, pred.vz), rel=1e-5)
    never = make_predictor(bias=3.0, threshold=0.999)
    assert not never.predict(window(never)).slipping
    with pytest.raises(ValueError):
        make_predictor(threshold=1.5)


def test_batch_matches_single():
    p = make_predictor(bias=50.0, n_channels=1)
    ws = np.stack([window(p, s) for s in range(5)])
    b = p.predict_batch(ws, batch_size=2)
    assert len(b) == 5
    for i in range(5):
        s = p.predict(ws[i])
        assert s.probability == pytest.approx(float(b.probability[i]), abs=1e-6)
        assert s.vx == pytest.approx(float(b.velocity[i, 0]), abs=1e-6)
    np.testing.assert_allclose(b.raw_velocity, b.velocity)


def test_stream_check():
    p = make_predictor(sr=48000.0, n_channels=4)
    p.check_stream(48000.0, ["m0", "m1", "m2", "m3"])
    with pytest.raises(ValueError):
        p.check_stream(48000.0, ["m0", "m1", "m2"])


def test_one_threshold_decides_and_is_reported(tmp_path):
    """p = 0.65, between the checkpoint's 0.5 and a user's 0.8: the set threshold decides."""
    from node_support import make_checkpoint
    ckpt = make_checkpoint(tmp_path / "p.pt", slip_logit=float(np.log(0.65 / 0.35)))
    p = Predictor.from_checkpoint(ckpt)
    w = window(p)
    assert p.threshold == p.checkpoint_threshold == 0.5
    first = p.predict(w)
    assert first.probability == pytest.approx(0.65, abs=1e-4)
    assert first.slipping and first.threshold == 0.5
    assert p.set_threshold(0.8) == 0.8
    high = p.predict(w)
    assert not high.slipping and high.threshold == 0.8 and high.speed == 0.0
    batch = p.predict_batch(np.stack([w, w]))
    assert not batch.slipping.any() and batch.threshold == 0.8
    with pytest.raises(ValueError):
        p.set_threshold(1.2)
    assert p.threshold == 0.8                       # a refused value changes nothing
    assert p.set_threshold(None) == 0.5 and p.predict(w).slipping


SIGMA_DOC = {"threshold": 0.5, "direction_sigma": {"model": {
    "speed_edges_m_s": [0.01, 0.03], "sigma_rad": [0.9, 0.3, 0.1]}}}


def test_direction_sigma_comes_from_the_checkpoint_at_the_raw_speed(tmp_path):
    """Old checkpoints (no output_calibration) load and report -1; a sigma model gives the
    sigma of the estimate's ungated speed, whether or not it is above the threshold."""
    from node_support import make_checkpoint

    from aslip_ros.learn.checkpoint import load_checkpoint, save_checkpoint
    plain = make_checkpoint(tmp_path / "p.pt", slip_logit=4.0, velocity=(0.02, -0.01))
    old = Predictor.from_checkpoint(plain)
    w = window(old)
    assert old.sigma_model is None and old.predict(w).direction_sigma == -1.0
    assert old.predict_batch(np.stack([w, w])).direction_sigma is None
    for velocity, want in (((0.02, -0.01), 0.3), ((0.05, 0.0), 0.1), ((0.005, 0.0), 0.9)):
        ck = load_checkpoint(make_checkpoint(tmp_path / "v.pt", slip_logit=4.0,
                                             velocity=velocity))
        save_checkpoint(tmp_path / "s.pt", dict(ck.meta, output_calibration=SIGMA_DOC),
                        ck.tensors)
        p = Predictor.from_checkpoint(tmp_path / "s.pt")
        assert p.predict(w).direction_sigma == pytest.approx(want)
        np.testing.assert_allclose(p.predict_batch(np.stack([w, w])).direction_sigma, want)
        p.set_threshold(1.0)                             # gated: sigma still of the raw speed
        assert not p.predict(w).slipping and p.predict(w).direction_sigma == pytest.approx(want)


def test_streaming_predictor_reports_the_checkpoint_sigma(tmp_path):
    from aslip_ros.learn.inference.stream_predictor import StreamingPredictor
    from test_learn_streaming_model import audio, blocks, make_checkpoint
    one_bin = {"threshold": 0.0, "direction_sigma": {"model": {"speed_edges_m_s": [],
                                                               "sigma_rad": [0.4]}}}
    bl = blocks(audio(n=9600, seed=1), 480)
    for meta, want in (({}, -1.0), ({"output_calibration": one_bin}, 0.4)):
        p = StreamingPredictor.from_checkpoint(make_checkpoint(tmp_path / "s.pt", **meta))
        ests = [e for b in bl for e in p.push(b)]
        assert ests
        np.testing.assert_allclose([e.prediction.direction_sigma for e in ests], want)
