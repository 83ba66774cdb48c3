"""SlipNet: shapes for 1/2/4 channels, frozen encoder, inference fusion."""

import numpy as np
import pytest
import torch

from aslip_ros.learn.models.aslip_cnn import (ModelConfig, SlipNet, TracedSlipNet,
                                              fuse_for_inference, output_arrays)


@pytest.mark.parametrize("n_channels", [1, 2, 4])
@pytest.mark.parametrize("n_frames", [7, 17])
def test_output_shapes(n_channels, n_frames):
    torch.manual_seed(0)
    cfg = ModelConfig(n_channels=n_channels, n_mels=32, width=8, depth=3)
    net = SlipNet(cfg).eval()
    out = net(torch.randn(5, n_channels, 32, n_frames))
    assert out.logit.shape == (5,)
    assert out.magnitude.shape == (5,)
    assert out.direction.shape == (5, 2)
    assert (out.magnitude >= 0).all()
    w = net.encoder.attention.weights(torch.randn(5, n_channels, 32, n_frames))
    assert w.shape == (5, n_channels)
    torch.testing.assert_close(w.mean(dim=1), torch.ones(5))  # softmax scaled by C


def test_width_depth_configurable_and_sigmoid_gate():
    small = SlipNet(ModelConfig(width=4, depth=1, temporal_layers=0, gate="sigmoid"))
    big = SlipNet(ModelConfig(width=32, depth=4, temporal_layers=3))
    n = [sum(p.numel() for p in m.parameters()) for m in (small, big)]
    assert n[0] < n[1]
    assert small(torch.randn(2, 4, 40, 9)).direction.shape == (2, 2)
    with pytest.raises(ValueError):
        ModelConfig(gate="max")
    with pytest.raises(ValueError):
        small(torch.randn(2, 3, 40, 9))          # wrong channel count


def test_freeze_encoder_keeps_weights_and_bn_stats():
    torch.manual_seed(1)
    net = SlipNet(ModelConfig(n_channels=2, n_mels=16, width=4))
    net.freeze_encoder()
    before = {k: v.clone() for k, v in net.encoder.state_dict().items()}
    heads_before = {k: v.clone() for k, v in net.heads.state_dict().items()}
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=1e-2)
    net.train()
    for _ in range(3):
        out = net(torch.randn(8, 2, 16, 9) * 3 + 1)
        (out.logit.sum() + out.magnitude.sum() + out.direction.sum()).backward()
        opt.step()
        opt.zero_grad()
    assert not net.encoder.training
    for k, v in net.encoder.state_dict().items():
        torch.testing.assert_close(v, before[k], rtol=0, atol=0)
    assert any(not torch.equal(v, heads_before[k]) for k, v in net.heads.state_dict().items())


def test_fused_inference_model_matches():
    torch.manual_seed(2)
    net = SlipNet(ModelConfig())
    net.train()
    for _ in range(3):
        net(torch.randn(16, 4, 40, 17))            # move BN running stats off identity
    net.eval()
    fused = fuse_for_inference(net)
    x = torch.randn(3, 4, 40, 17)
    for a, b in zip(net(x), fused(x)):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("angular", [False, True])
def test_traced_inference_model_gives_the_eager_estimates(angular):
    torch.manual_seed(3)
    net = SlipNet(ModelConfig(angular=angular))
    net.train()
    for _ in range(3):
        net(torch.randn(16, 4, 40, 17))            # move BN running stats off identity
    net.eval()
    traced = TracedSlipNet(net, 17)
    assert traced.traced
    for batch in (1, 5):                            # traced on one window; any batch runs
        x = torch.randn(batch, 4, 40, 17)
        with torch.no_grad():
            out = net(x)
            prob, v, rate = traced(x)
        want_p, want_v = output_arrays(out)
        np.testing.assert_allclose(prob.numpy(), want_p, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(v.numpy(), want_v, rtol=1e-4, atol=1e-7)
        if angular:
            np.testing.assert_allclose(rate.numpy(), out.angular.numpy(), rtol=1e-4, atol=1e-6)
        else:
            assert rate is None
    with pytest.raises(ValueError, match="features"):
        traced(torch.randn(1, 4, 40, 16))           # a window of another length
    with pytest.raises(ValueError, match="features"):
        traced(torch.randn(4, 40, 17))


def test_untraceable_inference_model_runs_eagerly(monkeypatch):
    def gone(*args, **kwargs):
        raise RuntimeError("TorchScript is not available")

    monkeypatch.setattr(torch.jit, "trace", gone)
    net = SlipNet(ModelConfig()).eval()
    model = TracedSlipNet(net, 17)
    x = torch.randn(2, 4, 40, 17)
    with torch.no_grad():
        prob, v, rate = model(x)
        want_p, want_v = output_arrays(net(x))
    assert not model.traced and rate is None
    np.testing.assert_allclose(prob.numpy(), want_p, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(v.numpy(), want_v, rtol=1e-4, atol=1e-7)


def test_normalization_buffers():
    net = SlipNet(ModelConfig(n_mels=8))
    net.set_normalization(torch.arange(8.0), torch.full((8,), 2.0))
    assert "feat_mean" in net.state_dict()
    with pytest.raises(ValueError):
        net.set_normalization(torch.zeros(7), torch.ones(7))
    with pytest.raises(ValueError):
        net.set_normalization(torch.zeros(8), torch.zeros(8))
