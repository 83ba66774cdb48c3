"""The A-SLIP multi-objective loss: the CNN's (aslip_cnn.py), trained by aslip_cnn_fit.py.

L = w_slip * BCE(p, 1[|v*| > eps]) + w_mag * Huber(|v_hat|, |v*|) [slip windows]
  + w_dir * (1 - d_hat . d* + w_aux * ||v_dir - d*||^2) [slip windows]
  + w_smooth * (1 - d_hat_t . d*_{t-1}) [consecutive slip windows of one trial]
  + w_rot * Huber(w_hat * R, wy * R) [windows with an angular label]

The rotational term (a model with a rotational output, ``SlipOutput.angular``) compares the
rim speeds ``wy * ROTATION_RADIUS_M`` in units of ``speed_scale``, the magnitude's scale, so
neither term drowns the other. Every window with an angular label counts, rotating or not
(a pure translation teaches |w| ~ 0, a pure rotation is planar no-slip); a NaN label (a
version 1 dataset) is masked out and gives no gradient.

Every masked term is a mean over the windows it applies to and exactly zero (with a valid
graph) when none do, so all-no-slip batches train the detector alone without NaN.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import torch
from torch.nn import functional as F

from aslip_ros.learn.models.aslip_cnn import SlipOutput
from aslip_ros.slip import ROTATION_RADIUS_M

# Below this norm a vector has no direction; used both for targets and predictions.
_DIR_EPS = 1e-8


@dataclass(frozen=True)
class LossWeights:
    """The paper's weights (slip 1.0, magnitude 0.5, direction 2.0, smoothness 0.1).

    ``aux`` weights the auxiliary squared error on the unnormalised direction output inside
    the direction term (the paper gives no value); ``huber_delta`` is in units of the
    model's ``speed_scale``. ``rot`` weights the rotational term (the paper has none): twice
    the magnitude's, since one signed output carries both the rate and the sense of the turn
    that the magnitude and direction terms share for the planar slip.
    """

    slip: float = 1.0
    mag: float = 0.5
    dir: float = 2.0
    smooth: float = 0.1
    aux: float = 0.25
    huber_delta: float = 1.0
    rot: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    m = mask.to(values.dtype)
    # clamp keeps 0/0 away; an empty mask yields sum(0 * values) = 0 with a graph attached.
    return (values * m).sum() / m.sum().clamp(min=1.0)


def unit(v: torch.Tensor) -> torch.Tensor:
    """Row-normalise (B, 2) vectors; zero rows stay zero."""
    return v / v.norm(dim=-1, keepdim=True).clamp(min=_DIR_EPS)


def rotation_loss(angular: torch.Tensor, w_true: torch.Tensor, speed_scale: float,
                  delta: float = 1.0) -> torch.Tensor:
    """Huber loss of the rim speeds ``w * ROTATION_RADIUS_M`` in units of ``speed_scale``,
    mean over the labelled rows of ``w_true`` (NaN: no label; such rows give no gradient),
    exactly zero with a graph when none is labelled."""
    labelled = torch.isfinite(w_true)
    k = ROTATION_RADIUS_M / speed_scale
    # The NaN targets are replaced before the arithmetic: NaN * 0 would still be NaN.
    target = torch.where(labelled, w_true, torch.zeros_like(w_true)).to(angular.dtype) * k
    return _masked_mean(F.huber_loss(angular * k, target, delta=delta, reduction="none"),
                        labelled)


def slip_loss(out: SlipOutput, v_true: torch.Tensor, slip: torch.Tensor, *,
              speed_scale: float, prev_v_true: torch.Tensor | None = None,
              prev_valid: torch.Tensor | None = None,
              weights: LossWeights = LossWeights(),
              sample_weight: torch.Tensor | None = None,
              w_true: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """Total loss and its parts (as floats, for logging).

    ``v_true``: (B, 2) mean slip velocity (m/s, grasp plane x/z); ``slip``: (B,) bool/0-1
    labels (speed > epsilon, as the dataset stores them). ``prev_v_true``/``prev_valid``:
    the label of each window's predecessor in the same trial and whether it exists; the
    smoothness term compares the predicted direction with the previous window's true one.
    ``sample_weight`` (B,) reweights the BCE term only (class balance). ``w_true`` (B,)
    the angular label [rad/s], NaN where there is none: the rotational term, for a model
    with a rotational output (``out.angular``).
    """
    if v_true.ndim != 2 or v_true.shape[1] != 2:
        raise ValueError(f"v_true must be (B, 2), got {tuple(v_true.shape)}")
    if speed_scale <= 0:
        raise ValueError("speed_scale must be positive")
    slip_f = slip.to(out.logit.dtype)
    bce = F.binary_cross_entropy_with_logits(out.logit, slip_f, reduction="none")
    if sample_weight is not None:
        bce = bce * sample_weight
    l_slip = bce.mean()

    speed_true = v_true.norm(dim=1)
    # A direction target exists only for slip windows with a non-zero mean velocity.
    has_dir = slip.bool() & (speed_true > _DIR_EPS)
    l_mag = _masked_mean(
        F.huber_loss(out.magnitude / speed_scale, speed_true / speed_scale,
                     delta=weights.huber_delta, reduction="none"),
        slip.bool())

    d_true = unit(v_true)
    d_hat = unit(out.direction)
    cos = (d_hat * d_true).sum(dim=1)
    # 1 - cos has zero gradient at exactly antipodal predictions; the squared error on the
    # raw output does not, and also keeps the raw output near unit length.
    aux = ((out.direction - d_true) ** 2).sum(dim=1)
    l_dir = _masked_mean(1.0 - cos, has_dir) + weights.aux * _masked_mean(aux, has_dir)

    if prev_v_true is not None and prev_valid is not None:
        prev_speed = prev_v_true.norm(dim=1)
        ok = has_dir & prev_valid.bool() & (prev_speed > _DIR_EPS)
        l_smooth = _masked_mean(1.0 - (d_hat * unit(prev_v_true)).sum(dim=1), ok)
    else:
        l_smooth = out.logit.sum() * 0.0

    if out.angular is not None and w_true is not None:
        l_rot = rotation_loss(out.angular, w_true, speed_scale, weights.huber_delta)
    else:
        l_rot = out.logit.sum() * 0.0

    total = (weights.slip * l_slip + weights.mag * l_mag + weights.dir * l_dir
             + weights.smooth * l_smooth + weights.rot * l_rot)
    parts = {"slip": float(l_slip.detach()), "mag": float(l_mag.detach()),
             "dir": float(l_dir.detach()), "smooth": float(l_smooth.detach()),
             "rot": float(l_rot.detach()), "total": float(total.detach())}
    return total, parts
