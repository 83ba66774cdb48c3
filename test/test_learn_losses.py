"""The multi-objective loss: values, masks and the degenerate cases (no NaN)."""

import math

import torch

from aslip_ros.learn.models.aslip_cnn_loss import LossWeights, slip_loss
from aslip_ros.learn.models.aslip_cnn import SlipOutput


def _out(logit, mag, direction):
    return SlipOutput(torch.tensor(logit, dtype=torch.float32, requires_grad=True),
                      torch.tensor(mag, dtype=torch.float32, requires_grad=True),
                      torch.tensor(direction, dtype=torch.float32, requires_grad=True))


def _grads_finite(out, loss):
    loss.backward()
    return all(t.grad is not None and torch.isfinite(t.grad).all() for t in out
               if t is not None)


def test_all_no_slip_batch_trains_detector_only():
    out = _out([0.3, -1.0], [0.0, 0.01], [[0.0, 0.0], [1.0, 0.0]])
    v = torch.zeros(2, 2)
    loss, parts = slip_loss(out, v, torch.zeros(2, dtype=torch.bool), speed_scale=0.02,
                            prev_v_true=torch.zeros(2, 2), prev_valid=torch.ones(2, dtype=bool))
    assert math.isfinite(loss.item())
    assert parts["mag"] == parts["dir"] == parts["smooth"] == 0.0
    assert _grads_finite(out, loss)
    assert out.logit.grad.abs().sum() > 0


def test_zero_magnitude_prediction_and_zero_direction_output():
    out = _out([2.0], [0.0], [[0.0, 0.0]])
    loss, _ = slip_loss(out, torch.tensor([[0.02, 0.0]]), torch.tensor([True]), speed_scale=0.02)
    assert math.isfinite(loss.item())
    assert _grads_finite(out, loss)
    assert out.direction.grad.abs().sum() > 0    # the auxiliary term pulls it out of zero


def test_slip_label_with_zero_true_velocity_is_ignored_for_direction():
    out = _out([2.0], [0.01], [[1.0, 0.0]])
    loss, parts = slip_loss(out, torch.zeros(1, 2), torch.tensor([True]), speed_scale=0.02)
    assert parts["dir"] == 0.0 and math.isfinite(loss.item())
    assert _grads_finite(out, loss)


def test_antipodal_prediction_still_gets_gradient():
    out = _out([2.0], [0.02], [[-1.0, 0.0]])
    loss, parts = slip_loss(out, torch.tensor([[0.02, 0.0]]), torch.tensor([True]),
                            speed_scale=0.02, weights=LossWeights(slip=0, mag=0, smooth=0))
    assert abs(parts["dir"] - (2.0 + 0.25 * 4.0)) < 1e-5   # 1 - cos(pi) + aux * |(-2, 0)|^2
    loss.backward()
    g = out.direction.grad
    assert torch.isfinite(g).all() and g[0, 0] < 0          # pushes towards +x


def test_cosine_only_gradient_vanishes_at_antipode():
    """Why the auxiliary term exists: without it the antipodal gradient is zero."""
    out = _out([2.0], [0.02], [[-1.0, 0.0]])
    loss, _ = slip_loss(out, torch.tensor([[0.02, 0.0]]), torch.tensor([True]),
                        speed_scale=0.02, weights=LossWeights(slip=0, mag=0, smooth=0, aux=0))
    loss.backward()
    assert out.direction.grad.abs().max() < 1e-6


def test_perfect_prediction_costs_only_bce():
    out = _out([20.0, -20.0], [0.03, 0.0], [[0.0, 1.0], [1.0, 0.0]])
    v = torch.tensor([[0.0, 0.03], [0.0, 0.0]])
    loss, parts = slip_loss(out, v, torch.tensor([True, False]), speed_scale=0.02,
                            prev_v_true=torch.tensor([[0.0, 0.05], [0.0, 0.0]]),
                            prev_valid=torch.tensor([True, False]))
    assert parts["mag"] < 1e-10 and parts["dir"] < 1e-10 and parts["smooth"] < 1e-6
    assert loss.item() < 1e-6


def test_weights_and_smoothness():
    out = _out([0.0], [0.01], [[1.0, 0.0]])
    v = torch.tensor([[0.01, 0.0]])
    prev = torch.tensor([[0.0, 0.01]])                     # 90 degrees away
    _, parts = slip_loss(out, v, torch.tensor([True]), speed_scale=0.02, prev_v_true=prev,
                         prev_valid=torch.tensor([True]))
    assert abs(parts["smooth"] - 1.0) < 1e-6
    w = LossWeights()
    assert (w.slip, w.mag, w.dir, w.smooth) == (1.0, 0.5, 2.0, 0.1)
    expected = w.slip * parts["slip"] + w.mag * parts["mag"] + w.dir * parts["dir"] \
        + w.smooth * parts["smooth"]
    assert abs(parts["total"] - expected) < 1e-6


def test_random_degenerate_batches_never_nan():
    g = torch.Generator().manual_seed(0)
    for trial in range(20):
        b = 6
        v = torch.randn(b, 2, generator=g) * 0.02
        v[: trial % b] = 0.0
        slip = v.norm(dim=1) > 0.005
        d = -v * (trial % 2) + torch.zeros(b, 2)           # antipodal on odd trials
        out = _out(torch.randn(b, generator=g).tolist(), [0.0] * b, d.tolist())
        loss, _ = slip_loss(out, v, slip, speed_scale=0.02, prev_v_true=v.roll(1, 0),
                            prev_valid=torch.rand(b, generator=g) > 0.5)
        assert torch.isfinite(loss)
        assert _grads_finite(out, loss)
