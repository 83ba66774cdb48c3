"""Rotational slip in the learning code (issue #21): every model family learns the sense of a
turn about the pad normal from a tiny synthetic dataset, NaN labels are masked, old
checkpoints give 0 / -1, the checkpoint says what it estimates, the angular sigma and the
rotational metrics have known answers."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from aslip_ros.learn.calibration import output as oc
from aslip_ros.learn.checkpoint import (estimates_rotation, load_checkpoint, save_checkpoint,
                                        validate_meta)
from aslip_ros.learn.data_io import open_dataset, select_windows
from aslip_ros.learn.evaluate import evaluate_checkpoint, format_report
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.incremental_features import StreamingLogMel, stream_logmel
from aslip_ros.learn.inference.live import LiveConfig, LiveEstimator, load_predictor
from aslip_ros.learn.inference.predictor import Predictor
from aslip_ros.learn.metrics import ROTATION_KEYS, compute_metrics, rotation_metrics
from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet, SlipOutput
from aslip_ros.learn.models.aslip_stream import (GruStepper, StreamConfig, StreamNet,
                                                 offline_outputs)
from aslip_ros.learn.models.svm import SvmConfig, fit_svm
from aslip_ros.learn.stats import bootstrap_metrics
from aslip_ros.learn.synthetic import make_synthetic_dataset, synthetic_trial
from aslip_ros.learn.training.config import TrainConfig
from aslip_ros.learn.models.aslip_cnn_loss import rotation_loss, slip_loss
from aslip_ros.learn.training.stream import (Sequences, StreamTrainConfig, _loss, fit_stream)
from aslip_ros.learn.models.aslip_cnn_fit import train_cnn
from aslip_ros.learn.training.train import train_svm
from aslip_ros.slip import ROTATION_EPSILON_RAD_S, ROTATION_RADIUS_M
from helpers.before_rotation import file_before

ROOT = Path(__file__).resolve().parents[1]
SR = 16000.0
FCFG = FeatureConfig(n_mels=16, n_fft=256, hop=160)
TINY = dict(width=4, depth=2, temporal_layers=1, temporal_channels=16, head_hidden=16)
QUIET = dict(progress=False, threads=1)


@pytest.fixture(scope="module")
def rot_ds(tmp_path_factory):
    """Ten 4 s grasps, half of the stretches turning (1-4 rad/s either way)."""
    return make_synthetic_dataset(tmp_path_factory.mktemp("rot") / "ds", n_trials=10,
                                  duration_s=4.0, rotation_fraction=0.5, seed=4)


@pytest.fixture(scope="module")
def cnn_ckpt(rot_ds, tmp_path_factory):
    cfg = TrainConfig(stage="scratch", epochs=40, patience=40, batch_size=16, lr=1e-3,
                      **QUIET)
    res = train_cnn(open_dataset(rot_ds), cfg, feature_config=FCFG, model_options=TINY,
                    log=lambda s: None)
    return res.save(tmp_path_factory.mktemp("cnn") / "rot_cnn.pt")


@pytest.fixture(scope="module")
def svm_ckpt(rot_ds, tmp_path_factory):
    res = train_svm(open_dataset(rot_ds), TrainConfig(stage="svm", **QUIET),
                    feature_config=FCFG, log=lambda s: None)
    return res.save(tmp_path_factory.mktemp("svm") / "rot_svm.pt")


def _held_out(ds_path, split="test"):
    ds = open_dataset(ds_path)
    idx = np.concatenate([select_windows(ds, s) for s in ("val", "test")]) \
        if split == "heldout" else select_windows(ds, split)
    return ds, idx


def _sense_learned(w_hat, w_true, slip):
    """Sign right on turning windows; turning windows read faster than pure translations."""
    rot = np.abs(w_true) > ROTATION_EPSILON_RAD_S
    trans = slip & ~rot
    assert rot.sum() >= 10 and trans.sum() >= 5
    sign_ok = float((np.sign(w_hat[rot]) == np.sign(w_true[rot])).mean())
    assert sign_ok >= 0.8, sign_ok
    assert np.abs(w_hat[trans]).mean() < 0.5 * np.abs(w_hat[rot]).mean()


# --- every model family ----------------------------------------------------------------------

@pytest.mark.parametrize("which", ["cnn", "svm"])
def test_window_models_learn_the_sense_of_a_turn(which, rot_ds, cnn_ckpt, svm_ckpt):
    path = cnn_ckpt if which == "cnn" else svm_ckpt
    ck = load_checkpoint(path)
    assert ck.meta["outputs"] == ["slip", "vx", "vz", "wy"] and estimates_rotation(ck.meta)
    assert ck.meta["output_calibration"]["angular_sigma"]["model"] is not None
    if which == "svm":
        assert "wy.support" in ck.tensors
    else:
        assert ck.meta["model_config"]["angular"] and "heads.angular.2.bias" in ck.tensors
    pred = Predictor(ck)
    ds, idx = _held_out(rot_ds, "heldout")
    cols = ds.channel_indices(pred.channel_names)
    b = pred.predict_batch(ds.window_audio(idx, cols))
    assert b.angular.shape == (idx.size,) and (b.angular_sigma > 0).all()
    _sense_learned(b.angular, ds.angular(idx), ds.slip(idx))
    # A pure rotation reads as planar no-slip, most of the time.
    pure_rot = (np.abs(ds.angular(idx)) > ROTATION_EPSILON_RAD_S) & ~ds.slip(idx)
    assert b.slipping[pure_rot].mean() <= 0.3
    # Raw, not gated by the planar decision: a pure rotation is planar no-slip.
    quiet_turn = np.flatnonzero(~b.slipping & (np.abs(b.angular) > ROTATION_EPSILON_RAD_S))
    assert quiet_turn.size
    one = b[int(quiet_turn[0])]
    assert not one.slipping and one.vx == one.vz == 0.0
    assert one.angular_velocity == pytest.approx(float(b.angular[quiet_turn[0]]))
    assert one.angular_sigma == pytest.approx(float(b.angular_sigma[quiet_turn[0]]))


def _sequences(seed: int, n: int, nan_every: int = 0) -> Sequences:
    """Whole synthetic grasps as streaming sequences, labelled at each frame's last sample;
    ``nan_every``: every n-th frame has no angular label."""
    rng = np.random.default_rng(seed)
    out = Sequences([], [], [], [], [], [], [])
    for k in range(n):
        audio, v, w = synthetic_trial(rng, 4.0, SR, 4, rotation_fraction=0.5)
        frames = stream_logmel(audio, FCFG, SR)
        ends = StreamingLogMel(FCFG, SR, 4).frame_end_samples(np.arange(frames.shape[0]))
        vv, ww = v[ends - 1], w[ends - 1].copy()
        if nan_every:
            ww[::nan_every] = np.nan
        out.trials.append(k)
        out.frames.append(frames)
        out.v.append(vv)
        out.slip.append(np.hypot(vv[:, 0], vv[:, 1]) > 0.005)
        out.valid.append(np.ones(frames.shape[0], bool))
        out.decided.append(np.ones(frames.shape[0], bool))
        out.w.append(ww)
    return out


def _stream_meta(model: StreamNet, va: Sequences) -> dict:
    outs = [offline_outputs(model, x) for x in va.frames]
    meta = {"model_type": "aslip_stream", "model_config": model.cfg.to_dict(),
            "feature_config": FCFG.to_dict(), "channel_names": ["a", "b", "c", "d"],
            "sample_rate": SR, "window_s": 0.016, "window_samples": 256, "hop_s": 0.01,
            "epsilon_m_s": 0.005, "threshold": 0.5, "label": {"kind": "slip_velocity_now"},
            "outputs": ["slip", "vx", "vz", "wy"]}
    meta.update(oc.sequence_fields(outs, va, 0.5))
    return meta


def test_the_streaming_model_learns_the_sense_of_a_turn(tmp_path):
    tr, va = _sequences(0, 6, nan_every=7), _sequences(1, 2)
    cfg = StreamTrainConfig(epochs=15, steps_per_epoch=10, batch_size=16, seq_frames=100,
                            lr=5e-3, patience=15, progress=False)
    model, fit = fit_stream(tr, va, cfg, model_config=dict(embed=32, hidden=16))
    assert model.cfg.angular and "rotation_mae_deg_s" in fit["val_metrics"]
    p, v, w = offline_outputs(model, va.frames[0])
    _sense_learned(w, va.w[0], va.slip[0])
    # The per-hop stepper gives the batched forward's rate.
    step = GruStepper(model.cfg, model.state_dict())
    got = np.array([step.step(f)[2] for f in va.frames[0][:50]])
    np.testing.assert_allclose(got, w[:50], rtol=1e-4, atol=1e-4)
    # Through a checkpoint and the live predictor: the raw rate on every hop, with a sigma.
    path = save_checkpoint(tmp_path / "s.pt", _stream_meta(model, va), model.state_dict())
    live = load_predictor(path)
    assert live.estimates_rotation and live.angular_sigma_model is not None
    audio, _, _ = synthetic_trial(np.random.default_rng(5), 3.0, SR, 4, rotation_fraction=0.5)
    live.set_threshold(1.0)                 # nothing slips in the plane: the rate stays raw
    ests = [e for i in range(0, audio.shape[0], 160)
            for e in live.push(_block(audio, i, 160))]
    _, _, _, w_off = live.trial_outputs(audio)
    got = np.array([e.prediction.angular_velocity for e in ests])
    np.testing.assert_allclose(got, w_off, rtol=1e-3, atol=1e-3)
    assert np.abs(got).max() > ROTATION_EPSILON_RAD_S
    assert all(not e.prediction.slipping and e.prediction.angular_sigma > 0 for e in ests)


def test_the_baselines_learn_the_sense_of_a_turn(rot_ds):
    from aslip_ros.learn.baselines import (baseline_features, fit_plain_cnn, fit_plain_svm,
                                           run_on_dataset)
    from aslip_ros.learn.training.data import feature_cache
    ds = open_dataset(rot_ds)
    feats = feature_cache(ds, baseline_features(ds.sample_rate), ds.channel_names)
    tr, (_, te) = select_windows(ds, "train"), _held_out(rot_ds, "heldout")
    x_tr, x_te = (np.asarray(feats[i], np.float32) for i in (tr, te))
    for model in (fit_plain_svm(x_tr, ds.velocity(tr), ds.slip(tr), w=ds.angular(tr)),
                  fit_plain_cnn(x_tr, ds.velocity(tr), ds.slip(tr), w=ds.angular(tr),
                                epochs=25)):
        _sense_learned(model.predict_rotation(x_te), ds.angular(te), ds.slip(te))
        assert model.predict(x_te)[1].shape == (te.size, 2)     # the planar API as before
    planar = fit_plain_svm(x_tr, ds.velocity(tr), ds.slip(tr))
    assert planar.predict_rotation(x_te) is None
    res = run_on_dataset(ds, kinds=("svm",), test_split="train", n_boot=20)["plain_svm"]
    assert res["rotation_estimated"] and "rotation_mae_deg_s_ci" in res


# --- labels without rotation, NaN labels -----------------------------------------------------

def test_nan_angular_labels_give_a_finite_loss_and_no_gradient():
    angular = torch.tensor([1.0, -2.0, 0.5, 3.0], requires_grad=True)
    w_true = torch.tensor([float("nan"), -1.0, float("nan"), 0.0])
    loss = rotation_loss(angular, w_true, speed_scale=0.02)
    loss.backward()
    assert math.isfinite(loss.item()) and loss.item() > 0
    assert angular.grad[[0, 2]].abs().sum() == 0 and (angular.grad[[1, 3]] != 0).all()
    # All NaN: exactly zero, with a graph; inside the whole loss, the planar terms remain.
    none = rotation_loss(angular, torch.full((4,), float("nan")), speed_scale=0.02)
    assert none.item() == 0.0 and none.requires_grad
    out = SlipOutput(torch.zeros(4, requires_grad=True), torch.full((4,), 0.01),
                     torch.ones(4, 2), angular)
    total, parts = slip_loss(out, torch.zeros(4, 2), torch.zeros(4, dtype=torch.bool),
                             speed_scale=0.02, w_true=torch.full((4,), float("nan")))
    assert math.isfinite(total.item()) and parts["rot"] == 0.0


def test_the_streaming_loss_masks_nan_frames():
    torch.manual_seed(0)
    net = StreamNet(StreamConfig(n_channels=2, n_mels=4, embed=8, hidden=6, angular=True))
    grads = {}

    def keep(module, inputs, output):
        output.retain_grad()
        grads["out"] = output

    net.head.register_forward_hook(keep)
    x = torch.randn(1, 10, 2, 4)
    w = torch.full((1, 10), 2.0)
    w[0, ::2] = float("nan")
    ones = torch.ones(1, 10, dtype=torch.bool)
    loss = _loss(net, x, torch.zeros(1, 10, 2), ~ones, ones, ones, w, StreamTrainConfig())
    loss.backward()
    g = grads["out"].grad[0, :, 3]
    assert math.isfinite(loss.item())
    assert g[::2].abs().sum() == 0 and (g[1::2] != 0).all()


def test_unlabelled_rows_are_left_out_of_the_svm_rate_and_planar_data_train_as_before(
        tmp_path):
    rng = np.random.default_rng(0)
    x = rng.standard_normal((80, 5))
    slip = x[:, 0] > 0
    v = np.where(slip[:, None], 0.01, 0.0) * np.ones((80, 2))
    w = x[:, 1].copy()
    w[::2] = np.nan
    arrays, est = fit_svm(x, slip, v, SvmConfig(), angular=w)
    assert arrays.angular is not None and est["svr_wy"].support_.max() < 40
    assert fit_svm(x, slip, v, SvmConfig(), angular=np.full(80, np.nan))[0].angular is None
    # A dataset without angular labels: no rotational output, planar checkpoint.
    ds = open_dataset(make_synthetic_dataset(tmp_path / "planar", n_trials=4, duration_s=2.0))
    assert not ds.has_angular() and np.isnan(ds.angular(np.arange(3))).all()
    res = train_svm(ds, TrainConfig(stage="svm", **QUIET), feature_config=FCFG,
                    log=lambda s: None)
    assert res.meta["outputs"] == ["slip", "vx", "vz"] and "wy.support" not in res.tensors
    assert "angular_sigma" not in res.meta["output_calibration"]
    assert "n_angular_labelled" not in res.meta["provenance"]["metrics"]["val"]


# --- old checkpoints, the document ------------------------------------------------------------

@pytest.mark.parametrize("name", ["aslip_cnn.pt", "aslip_cnn_uncalibrated.pt", "svm.pt",
                                  "aslip_stream.pt"])
def test_the_planar_shipped_checkpoints_load_and_report_no_rotation(name, tmp_path):
    """The models shipped before rotational slip (from git) still load and predict, with a
    rate of 0 and no sigma: what the message calls "the source gives none"."""
    path = file_before(f"models/{name}", tmp_path / name)
    ck = load_checkpoint(path)
    assert "outputs" not in ck.meta and not estimates_rotation(ck.meta)
    pred = load_predictor(ck)
    assert not pred.estimates_rotation and pred.angular_sigma_model is None
    rng = np.random.default_rng(0)
    audio = (0.01 * rng.standard_normal((pred.window_samples * 2 + 4800, pred.n_channels))
             ).astype(np.float32)
    if name == "aslip_stream.pt":
        _, _, _, w = pred.trial_outputs(audio)
        assert w is None
        preds = [e.prediction for i in range(0, audio.shape[0], 480)
                 for e in pred.push(_block(audio, i, 480, pred.sample_rate))]
    else:
        b = pred.predict_batch(audio[None, :pred.window_samples])
        assert b.angular is None and b.angular_sigma is None
        preds = [b[0], pred.predict(audio[:pred.window_samples])]
    assert len(preds) > 1
    assert all(p.angular_velocity == 0.0 and p.angular_sigma == -1.0 for p in preds)


def test_outputs_must_agree_with_the_model(tmp_path):
    fc = FeatureConfig()
    base = {"model_type": "aslip_cnn", "feature_config": fc.to_dict(),
            "channel_names": ["a", "b"], "sample_rate": 48000.0, "window_s": 0.2,
            "window_samples": 9600, "epsilon_m_s": 0.005}
    planar = ModelConfig(n_channels=2, n_mels=fc.n_mels).to_dict()
    turning = ModelConfig(n_channels=2, n_mels=fc.n_mels, angular=True).to_dict()
    assert validate_meta({**base, "model_config": planar}) == []
    assert validate_meta({**base, "model_config": turning,
                          "outputs": ["slip", "vx", "vz", "wy"]}) == []
    for bad in ({"model_config": planar, "outputs": ["slip", "vx", "vz", "wy"]},
                {"model_config": turning},
                {"model_config": turning, "outputs": ["slip", "vx", "vz"]},
                {"model_config": planar, "outputs": ["slip", "vx"]},
                {"model_config": planar, "outputs": ["slip", "vx", "vz", "wz"]},
                {"model_config": planar, "outputs": "slip"}):
        assert validate_meta({**base, **bad}), bad
    net = SlipNet(ModelConfig(**turning))
    with pytest.raises(ValueError, match="outputs"):
        save_checkpoint(tmp_path / "x.pt", {**base, "model_config": turning},
                        net.state_dict())


def test_a_finetune_from_a_planar_init_adds_a_rotational_head(rot_ds, tmp_path):
    ds = open_dataset(rot_ds)
    planar_ds = open_dataset(make_synthetic_dataset(tmp_path / "planar", n_trials=6,
                                                    duration_s=2.0, seed=9))
    pre = train_cnn(planar_ds, TrainConfig(stage="pretrain", epochs=1, batch_size=16,
                                           **QUIET),
                    feature_config=FCFG, model_options=TINY, log=lambda s: None)
    assert pre.meta["outputs"] == ["slip", "vx", "vz"]
    ft = train_cnn(ds, TrainConfig(stage="finetune", epochs=1, batch_size=16, **QUIET),
                   init=pre.checkpoint(), log=lambda s: None)
    assert ft.meta["outputs"][-1] == "wy" and ft.meta["model_config"]["angular"]
    for k, t in pre.tensors.items():
        if k.startswith("encoder."):
            torch.testing.assert_close(ft.tensors[k], t)   # the frozen encoder is the init's


# --- the live path ------------------------------------------------------------------------------

def test_the_live_estimator_passes_the_rate_on(cnn_ckpt, rot_ds):
    ds = open_dataset(rot_ds)
    k = int(ds.windows["trial"][select_windows(ds, "test")[0]])
    audio = np.asarray(ds.audio(k))
    live = LiveEstimator(load_predictor(cnn_ckpt), LiveConfig(hop_s=0.1))
    out = [e for i in range(0, audio.shape[0], 1600)
           for e in live.feed(_block(audio, i, 1600, names=ds.channel_names))]
    assert len(out) > 20
    w = np.array([e.prediction.angular_velocity for e in out])
    assert np.isfinite(w).all() and np.abs(w).max() > ROTATION_EPSILON_RAD_S
    assert all(e.prediction.angular_sigma > 0 for e in out)


def _block(audio, i, n, rate=SR, names=None):
    """Block ``i`` of a stream starting at sample 0 (``nodes.convert.AudioData``-like)."""
    from test_learn_streaming_model import Block
    blk = Block(i, 1_000_000_000 + int(round(i * 1e9 / rate)), rate, audio[i:i + n])
    blk.channel_names = list(names or [])
    return blk


# --- metrics, sigma, evaluation ------------------------------------------------------------------

def test_rotation_metrics_known_answer():
    eps = ROTATION_EPSILON_RAD_S
    # rows: pure rotation (2), pure translation (2), both (1), still (1), unlabelled (1)
    w_true = np.array([2.0, -1.0, 0.0, 0.1, 3.0, 0.0, np.nan])
    w_hat = np.array([1.5, 0.2, 0.0, 0.9, 3.0, 0.0, 5.0])
    true_speed = np.array([0.0, 0.001, 0.02, 0.01, 0.005 + 1e-4, 0.0, 0.0])
    slip = true_speed > 0.005
    gated = np.array([0.0, 0.0, 0.02, 0.01, 0.02, 0.0, 0.0])
    prob = np.where(gated > 0, 0.9, 0.1)
    raw = np.stack([np.where(gated > 0, gated, 0.3), np.zeros(7)], 1)    # ungated: big
    v_true = np.stack([np.zeros(7), true_speed], 1)
    m = rotation_metrics(prob, raw, w_hat, v_true, w_true, 0.5, slip=slip)
    assert rotation_metrics(prob, raw, w_hat, v_true, w_true, 0.5) == m   # 5 mm/s default
    assert (m["n_angular_labelled"], m["n_rotating"], m["n_pure_rotation"],
            m["n_pure_translation"], m["n_kind_windows"]) == (6, 3, 2, 2, 5)
    rot_err = np.degrees([0.5, 1.2, 0.0])
    assert m["rotation_mae_deg_s"] == pytest.approx(rot_err.mean())
    assert m["rotation_mean_true_deg_s"] == pytest.approx(np.degrees([2, 1, 3]).mean())
    assert m["rotation_mae_ratio"] == pytest.approx(rot_err.mean() / np.degrees(2.0))
    assert m["pure_rotation_detection"] == 0.5                   # 1.5 > eps, 0.2 is not
    assert m["false_rotation_on_translation"] == 0.5             # 0.9 > eps
    # kinds true: rot, rot, trans, trans, rot (30 mm/s rim > 5.1 mm/s); predicted: rot
    # (15 > 0), rot (2 mm/s > 0), trans, trans (9 < 10 mm/s), rot (30 > 20 mm/s)
    assert m["kind_agreement"] == 1.0
    assert eps == 0.5 and ROTATION_RADIUS_M == 0.01
    # A model without a rotational output is scored as 0.
    z = rotation_metrics(prob, raw, None, v_true, w_true, slip=slip)
    assert not z["rotation_estimated"] and z["pure_rotation_detection"] == 0.0
    assert z["rotation_mae_ratio"] == pytest.approx(1.0)
    # Planar metrics do not move; no labels, no rotational keys.
    v = np.stack([true_speed, np.zeros(7)], 1)
    args = (np.full(7, 0.9), v, v, slip, 0.2)
    plain = compute_metrics(*args)
    both = compute_metrics(*args, angular=w_hat, true_angular=w_true)
    assert all(both[k] == plain[k] for k in plain)
    assert not set(ROTATION_KEYS) & set(plain)


def test_the_bootstrap_gives_rotational_intervals():
    rng = np.random.default_rng(0)
    n = 60
    trial = np.repeat(np.arange(6), 10)
    w_true = rng.choice([-2.0, 0.0, 2.0], n)
    v = np.where(rng.random((n, 1)) < 0.5, 0.02, 0.0) * np.ones((n, 2))
    slip = np.hypot(v[:, 0], v[:, 1]) > 0.005
    out = bootstrap_metrics(trial, np.where(slip, 0.9, 0.1), v, v, slip, 0.2, n_boot=50,
                            angular=w_true + 0.1, true_angular=w_true)
    for k in ("rotation_mae_deg_s", "kind_agreement", "pure_rotation_detection"):
        lo, hi = out[k + "_ci"]
        assert lo <= out[k] <= hi
    assert out["rotation_mae_deg_s"] == pytest.approx(math.degrees(0.1), rel=1e-5)
    assert "rotation_mae_deg_s_ci" not in bootstrap_metrics(trial, np.full(n, 0.5), v, v,
                                                            slip, 0.2, n_boot=10)


def test_angular_sigma_covers_68_percent_and_is_checked():
    rng = np.random.default_rng(1)
    w_true = rng.uniform(-4, 4, 2000)
    w_hat = w_true + rng.normal(0, 0.1 + 0.1 * np.abs(w_true))
    w_true[::10] = np.nan
    doc = oc.fit_angular_sigma(w_hat, w_true)
    model = oc.AngularSigmaModel.from_dict(doc["model"])
    assert doc["n_windows"] == 1800 and len(model.sigma) == oc.MAX_BINS
    assert model(0.0) < model(3.9) and model(-3.9) == model(3.9)
    assert model(np.nan) == model.sigma.max()
    held = rng.uniform(-4, 4, 2000)
    cover = oc.angular_coverage(model, held + rng.normal(0, 0.1 + 0.1 * np.abs(held)), held)
    assert cover["coverage"] == pytest.approx(oc.ONE_SIGMA, abs=0.04)
    assert oc.fit_angular_sigma(w_hat[:20], w_true[:20])["model"] is None
    assert oc.fit_angular_sigma(np.zeros(100), np.zeros(100))["model"]["sigma_rad_s"] == \
        [oc.ANGULAR_SIGMA_FLOOR_RAD_S]
    for bad in ({"rate_edges_rad_s": [], "sigma_rad_s": [0.0]},
                {"rate_edges_rad_s": [1.0], "sigma_rad_s": [0.1]},
                {"rate_edges_rad_s": [2.0, 1.0], "sigma_rad_s": [0.1, 0.2, 0.3]}):
        assert oc.meta_problems({"threshold": 0.5, "direction_sigma": {"model": None},
                                 "angular_sigma": {"model": bad}})


def test_evaluate_reports_rotation_only_where_the_dataset_has_labels(cnn_ckpt, rot_ds,
                                                                     tmp_path):
    res = evaluate_checkpoint(cnn_ckpt, rot_ds, "all")
    o = res["overall"]
    assert o["rotation_estimated"] and o["n_rotating"] > 0
    assert "rotation_mae_deg_s_ci" in o and "kind_agreement" in o
    assert res["output_calibration"]["angular_sigma"]["n"] > 0
    assert "\nrotation: n rotating" in format_report(res)
    assert "kind agreement" in format_report(res)
    assert "n_rotating" in next(iter(res["per_object"].values()))
    planar = make_synthetic_dataset(tmp_path / "planar", n_trials=6, duration_s=2.0, seed=7)
    res2 = evaluate_checkpoint(cnn_ckpt, planar, "all")
    assert "n_angular_labelled" not in res2["overall"]
    assert "\nrotation" not in format_report(res2)
    # A planar checkpoint (shipped before rotational slip) on the labelled data: scored as
    # a rate of 0, and said so.
    planar_ckpt = file_before("models/aslip_cnn_uncalibrated.pt", tmp_path / "planar.pt")
    shipped = evaluate_checkpoint(planar_ckpt, _resampled(rot_ds, tmp_path), "all")
    assert not shipped["overall"]["rotation_estimated"]
    assert "no rotational output" in format_report(shipped)


def _resampled(ds_path, tmp_path):
    """The rotation dataset at the shipped models' stream (48 kHz, their channel names)."""
    from scipy.signal import resample_poly
    from aslip_ros.data.dataset import DatasetWriter
    src = open_dataset(ds_path)
    names = load_checkpoint(ROOT / "models" / "aslip_cnn_uncalibrated.pt").channel_names
    out = tmp_path / "r48"
    with DatasetWriter(out, overwrite=True) as wr:
        for k, t in enumerate(src.trials[:4]):
            wr.begin_trial(len(names)).append(
                resample_poly(np.asarray(src.audio(k)), 3, 1, axis=0).astype(np.float32))
            rows = np.asarray(src.windows[src.windows["trial"] == k]).copy()
            rows["start"] *= 3
            keys = ("id", "object", "pad", "layout", "condition", "induced", "source_bag",
                    "label_source")
            wr.end_trial({kk: t.get(kk, "") for kk in keys}, rows)
        wr.finish(sample_rate=48000.0, channel_names=list(names), layout="4mic",
                  window_s=0.2, hop_s=0.1, epsilon_m_s=0.005, n_window_samples=9600)
    return out
