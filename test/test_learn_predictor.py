"""Predictor: input validation, gating, batch consistency."""

import numpy as np
import pytest
import torch

from aslip_ros.learn.checkpoint import Checkpoint
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.network import ModelConfig, SlipNet
from aslip_ros.learn.predictor import Predictor


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
