"""The `svm` candidate regresses the slip speed itself and its direction's unit components
(issue 36); checkpoints from before, one regressor per velocity component, load and predict
as they did."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from aslip_ros.learn.checkpoint import load_checkpoint, save_checkpoint
from aslip_ros.learn.inference.live import load_predictor
from aslip_ros.learn.models.svm import (KernelMachine, SvmArrays, SvmBackend, SvmConfig,
                                        fit_svm)
from aslip_ros.slip import VELOCITY_COMPONENTS

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "models" / "svm.pt"


def speed_heard_direction_not(n=200, n_feats=4, seed=0):
    """Handcrafted features: one follows the speed, the rest are noise; the direction is
    random and inaudible."""
    rng = np.random.default_rng(seed)
    slip = rng.random(n) < 0.6
    speed = np.where(slip, rng.uniform(0.01, 0.05, n), 0.0)
    ang = rng.uniform(-np.pi, np.pi, n)
    v = np.stack([np.cos(ang), np.sin(ang)], 1) * speed[:, None]
    x = rng.normal(0.0, 0.1, (n, n_feats))
    x[:, 0] += np.where(slip, 1.0 + 40.0 * speed, 0.0)
    return x, slip, v


def _rbf(t, prefix, z):
    """A kernel expansion straight from the tensors, independent of ``KernelMachine``."""
    s = t[f"{prefix}.support"].double().numpy()
    d2 = ((z[:, None, :] - s[None, :, :]) ** 2).sum(-1)
    return np.exp(-float(t[f"{prefix}.gamma"][0]) * d2) @ t[f"{prefix}.dual"].double().numpy() \
        + float(t[f"{prefix}.intercept"][0])


def _per_component_tensors(x, slip, v, cfg=SvmConfig(), angular=None):
    """A tensor set as ``fit_svm`` wrote it before issue 36: SVRs on vx, vz / the median
    slip speed (and the rotation's, given ``angular``). Returns it and the sklearn
    estimators."""
    from sklearn.svm import SVR

    arrays, est = fit_svm(x, slip, v, cfg, angular=angular)
    t = {k: val for k, val in arrays.to_tensors().items()
         if k.split(".")[0] in ("scaler", "target_scale", "slip", "wy")}
    z = (x - arrays.mean) / arrays.std
    svr = {}
    for j, c in enumerate(VELOCITY_COMPONENTS):
        svr[c] = SVR(kernel="rbf", C=cfg.svr_C, gamma=cfg.gamma, epsilon=cfg.svr_epsilon).fit(
            z[slip], v[slip, j] / arrays.target_scale)
        t.update(KernelMachine.from_sklearn(svr[c]).to_tensors(c))
    return t, svr, arrays


def _speed_rmse(vel, v, slip):
    return float(np.sqrt(np.mean((np.linalg.norm(vel[slip], axis=1)
                                  - np.linalg.norm(v[slip], axis=1)) ** 2)))


def test_the_speed_is_regressed_itself_where_the_direction_is_not_heard():
    x, slip, v = speed_heard_direction_not()
    xt, st, vt = speed_heard_direction_not(seed=1)
    arrays, est = fit_svm(x, slip, v)
    assert not arrays.per_component and set(est) == {"svc", "svr_speed", "svr_dir_vx",
                                                     "svr_dir_vz"}
    prob, vel, rate = arrays.predict(xt)
    assert rate is None and np.isfinite(prob).all() and np.isfinite(vel).all()
    # velocity = clamped speed x unit direction, from the sklearn estimators
    z = (xt - arrays.mean) / arrays.std
    speed = np.maximum(est["svr_speed"].predict(z), 0.0) * arrays.target_scale
    d = np.stack([est["svr_dir_vx"].predict(z), est["svr_dir_vz"].predict(z)], 1)
    np.testing.assert_allclose(vel, d / np.linalg.norm(d, axis=1, keepdims=True)
                               * speed[:, None], atol=1e-6)
    # The per-component format on the same windows shrinks towards 0.
    t, _, _ = _per_component_tensors(x, slip, v)
    _, old_vel, _ = SvmArrays.from_tensors(t).predict(xt)
    new, old = _speed_rmse(vel, vt, st), _speed_rmse(old_vel, vt, st)
    assert new < 0.5 * old, (new, old)                    # 4.5 against 16.2 mm/s


def test_a_new_checkpoint_round_trips_with_speed_and_direction_tensors(tmp_path):
    x, slip, v = speed_heard_direction_not()
    arrays, _ = fit_svm(x, slip, v, angular=np.where(slip, 1.0, 0.0))
    t = arrays.to_tensors()
    names = {k.split(".")[0] for k in t}
    assert {"speed", "dir_vx", "dir_vz", "wy"} <= names and not names & {"vx", "vz"}
    torch.save({"tensors": t}, tmp_path / "t.pt")
    back = SvmArrays.from_tensors(torch.load(tmp_path / "t.pt", weights_only=True)["tensors"])
    assert not back.per_component
    for a, b in zip(arrays.predict(x), back.predict(x)):
        np.testing.assert_array_equal(a, b)


def test_a_zero_direction_gives_zero_velocity_not_nan():
    x, slip, v = speed_heard_direction_not()
    arrays, _ = fit_svm(x, slip, v)
    for name in ("dir_vx", "dir_vz"):
        km = arrays.velocity[name]
        arrays.velocity[name] = KernelMachine(km.support, np.zeros_like(km.dual), 0.0, km.gamma)
    _, vel, _ = arrays.predict(x)
    assert np.array_equal(vel, np.zeros_like(vel))


def test_a_per_component_tensor_set_predicts_as_before():
    x, slip, v = speed_heard_direction_not()
    t, svr, _ = _per_component_tensors(x, slip, v)
    arrays = SvmArrays.from_tensors(t)
    assert arrays.per_component
    _, vel, _ = arrays.predict(x)
    z = (x - arrays.mean) / arrays.std
    want = np.stack([svr[c].predict(z) for c in VELOCITY_COMPONENTS], 1) * arrays.target_scale
    np.testing.assert_allclose(vel, want, atol=1e-6)
    assert set(arrays.to_tensors()) == set(t)          # written back as it was read


def test_a_tensor_set_without_velocity_regressors_or_with_both_is_refused():
    x, slip, v = speed_heard_direction_not()
    t, _, arrays = _per_component_tensors(x, slip, v)
    bare = {k: val for k, val in t.items() if k.split(".")[0] not in VELOCITY_COMPONENTS}
    with pytest.raises(ValueError, match="no velocity regressors"):
        SvmArrays.from_tensors(bare)
    with pytest.raises(ValueError, match="both"):
        SvmArrays.from_tensors({**t, **arrays.to_tensors()})
    with pytest.raises(ValueError, match="lacks"):
        SvmArrays.from_tensors({k: val for k, val in arrays.to_tensors().items()
                                if k != "dir_vz.dual"})


def test_fit_needs_slip_that_moves():
    x, slip, v = speed_heard_direction_not()
    with pytest.raises(ValueError, match="move"):
        fit_svm(x, slip, np.zeros_like(v))


@pytest.mark.skipif(not SHIPPED.is_file(), reason="models/svm.pt is not in this checkout")
def test_a_per_component_checkpoint_predicts_as_before_and_the_shipped_one_runs(tmp_path):
    """A checkpoint as written before issue 36 (one SVR per velocity component), with the
    shipped SVM's document, loads and predicts what its tensors say through the backend
    and the predictor; the shipped SVM (the new format since its retraining) runs too."""
    ck = load_checkpoint(SHIPPED)
    shipped = SvmBackend.from_checkpoint(ck)
    assert not shipped.arrays.per_component
    rng = np.random.default_rng(0)
    audio = (0.01 * rng.standard_normal((3, int(ck.meta["window_samples"]),
                                         len(ck.channel_names)))).astype(np.float32)
    feats = shipped.featurizer(audio)
    x = rng.standard_normal((120, feats.shape[1]))
    slip = x[:, 0] > 0
    v = np.where(slip[:, None], 0.01 * np.stack([np.cos(x[:, 1]), np.sin(x[:, 1])], 1), 0.0)
    t, _, _ = _per_component_tensors(x, slip, v, angular=np.where(slip, 0.5, 0.0))
    path = save_checkpoint(tmp_path / "old.pt", ck.meta, t)
    old = SvmBackend.from_checkpoint(load_checkpoint(path))
    assert old.arrays.per_component
    z = (feats.astype(np.float64) - t["scaler.mean"].numpy()) / t["scaler.std"].numpy()
    want = np.stack([_rbf(t, c, z) for c in VELOCITY_COMPONENTS], 1) * float(t["target_scale"])
    _, vel, _ = old.predict(audio, None)
    np.testing.assert_allclose(vel, want, rtol=1e-5, atol=1e-7)
    for p in (path, SHIPPED):
        assert np.isfinite(load_predictor(p).predict_batch(audio).velocity).all()
