"""Calibrated outputs: the threshold chosen on validation data, the direction-sigma model
and its coverage on held-out data, the checkpoint document, the reliability diagram."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aslip_ros.learn.calibration import output as oc
from aslip_ros.learn.checkpoint import load_checkpoint, save_checkpoint, validate_meta

SLOW_SD, FAST_SD = 0.6, 0.15           # rad: the true direction-error spread per speed range


def sample(n, seed, slip_fraction=0.5):
    """Windows whose direction error is normal with a known spread: SLOW_SD below 2 cm/s of
    predicted speed, FAST_SD above; P(|error| <= sd) is 68.27 % by construction."""
    rng = np.random.default_rng(seed)
    slip = rng.random(n) < slip_fraction
    speed = rng.uniform(0.005, 0.05, n)
    ang = rng.uniform(-np.pi, np.pi, n)
    true = np.stack([np.cos(ang), np.sin(ang)], 1) * (speed * slip)[:, None]
    err = rng.normal(0.0, np.where(speed < 0.02, SLOW_SD, FAST_SD))
    pred = np.stack([np.cos(ang + err), np.sin(ang + err)], 1) * speed[:, None]
    prob = np.clip(np.where(slip, 0.7, 0.3) + rng.normal(0, 0.15, n), 0, 1)
    return prob, pred, true, slip


# --- threshold ------------------------------------------------------------------------------

def test_threshold_is_the_validation_accuracy_optimum():
    """No-slip p below 0.695, slip p above 0.705: only 0.70 on the grid separates them."""
    rng = np.random.default_rng(0)
    prob = np.concatenate([rng.uniform(0.0, 0.695, 300), rng.uniform(0.705, 1.0, 200)])
    slip = np.arange(500) >= 300
    fit = oc.choose_threshold(prob, slip)
    assert fit["threshold"] == pytest.approx(0.70)
    assert fit["accuracy"] == 1.0 and fit["accuracy_at_default"] < 1.0


def test_a_flat_optimum_keeps_the_threshold_nearest_one_half():
    rng = np.random.default_rng(1)
    prob = np.concatenate([rng.uniform(0.0, 0.3, 100), rng.uniform(0.8, 1.0, 100)])
    slip = np.arange(200) >= 100
    assert oc.choose_threshold(prob, slip)["threshold"] == 0.5
    # Shifted so 0.5 is no longer perfect: the nearest perfect one, not the far end.
    prob2 = np.concatenate([np.linspace(0.0, 0.625, 100), rng.uniform(0.9, 1.0, 100)])
    assert oc.choose_threshold(prob2, slip)["threshold"] == pytest.approx(0.63)


def test_too_few_validation_windows_keep_one_half_and_say_so():
    rng = np.random.default_rng(2)
    prob = np.concatenate([rng.uniform(0.0, 0.2, 40), rng.uniform(0.9, 1.0, 5)])
    fit = oc.choose_threshold(prob, np.arange(45) >= 40)
    assert fit["threshold"] == 0.5 and "too few" in fit["note"]


# --- direction sigma ------------------------------------------------------------------------

def test_sigma_covers_68_percent_of_held_out_errors_from_the_same_distribution():
    """Fitted on one sample, checked on an independent one drawn from the same errors."""
    doc = oc.fit_output_calibration(*sample(4000, seed=10))
    model = oc.SigmaModel.from_dict(doc["direction_sigma"]["model"])
    assert np.all(np.diff(model.sigma) <= 0)                       # surer when faster
    assert model(0.01) == pytest.approx(SLOW_SD, rel=0.12)
    assert model(0.045) == pytest.approx(FAST_SD, rel=0.12)
    prob, pred, true, slip = sample(4000, seed=11)                  # held out
    cover = oc.sigma_coverage(model, pred, true, slip)
    assert cover["n"] == int(slip.sum())
    assert cover["coverage"] == pytest.approx(oc.ONE_SIGMA, abs=0.03)
    for row in cover["per_bin"]:
        assert row["coverage"] == pytest.approx(oc.ONE_SIGMA, abs=0.07)
    # The check can fail: half the sigma covers far fewer errors.
    half = oc.SigmaModel(model.edges, model.sigma / 2)
    assert oc.sigma_coverage(half, pred, true, slip)["coverage"] < 0.5


def test_sigma_never_shrinks_for_slower_slip_and_is_floored_and_capped():
    prob, pred, true, slip = sample(2000, seed=3)
    speed = np.linalg.norm(pred, axis=1)
    # Reverse the physics: fast windows get random directions, slow ones exact directions.
    fast = speed > 0.03
    pred[fast] = pred[fast] @ np.array([[0.0, 1.0], [-1.0, 0.0]])     # 90 deg off
    pred[~fast] = true[~fast] / np.maximum(np.linalg.norm(true[~fast], axis=1), 1e-9)[:, None] \
        * speed[~fast, None]
    model = oc.fit_sigma_model(pred, true, slip)["model"]
    assert np.all(np.diff(model["sigma_rad"]) <= 0)
    assert len(model["sigma_rad"]) == 1                             # pooled into one bin
    exact = oc.fit_sigma_model(true, true, slip)["model"]
    assert exact["sigma_rad"] == [pytest.approx(oc.SIGMA_FLOOR_RAD)] * len(exact["sigma_rad"])
    backwards = oc.fit_sigma_model(-true, true, slip)["model"]
    assert max(backwards["sigma_rad"]) <= math.pi


def test_too_few_slip_windows_give_no_sigma_model():
    prob, pred, true, slip = sample(40, seed=4)
    doc = oc.fit_output_calibration(prob, pred, true, slip)
    assert doc["direction_sigma"]["model"] is None and "no sigma model" in \
        doc["direction_sigma"]["note"]
    assert oc.meta_problems(doc) == []


def test_reliability_and_expected_calibration_error():
    rng = np.random.default_rng(5)
    p = rng.uniform(0, 1, 20000)
    calibrated = rng.random(p.size) < p
    assert oc.reliability(p, calibrated)["ece"] < 0.02
    overconfident = rng.random(p.size) < 0.5          # p says anything, truth is a coin
    rel = oc.reliability(p, overconfident)
    assert rel["ece"] > 0.2 and sum(b["n"] for b in rel["bins"]) == p.size


# --- checkpoint document --------------------------------------------------------------------

@pytest.mark.parametrize("bad", [
    {"threshold": 1.5, "direction_sigma": {"model": None}},
    {"threshold": 0.5},
    {"threshold": 0.5, "direction_sigma": {"model": {"speed_edges_m_s": [0.01],
                                                     "sigma_rad": [0.5]}}},
    {"threshold": 0.5, "direction_sigma": {"model": {"speed_edges_m_s": [],
                                                     "sigma_rad": [float("nan")]}}},
    {"threshold": 0.5, "direction_sigma": {"model": {"speed_edges_m_s": [0.02, 0.01],
                                                     "sigma_rad": [0.5, 0.4, 0.3]}}},
    {"threshold": 0.5, "direction_sigma": {"model": {"speed_edges_m_s": [],
                                                     "sigma_rad": [0.0]}}},
])
def test_bad_documents_are_refused(bad):
    assert oc.meta_problems(bad)


def test_checkpoint_carries_and_validates_the_document(tmp_path):
    from node_support import make_checkpoint
    ck = load_checkpoint(make_checkpoint(tmp_path / "plain.pt"))
    assert "output_calibration" not in ck.meta             # an older checkpoint
    assert oc.sigma_model(ck.meta) is None
    meta = dict(ck.meta, **oc.checkpoint_fields(*sample(2000, seed=6)))
    save_checkpoint(tmp_path / "cal.pt", meta, ck.tensors)
    back = load_checkpoint(tmp_path / "cal.pt").meta
    assert back["threshold"] == back["output_calibration"]["threshold"]
    assert oc.sigma_model(back) is not None
    meta["output_calibration"]["direction_sigma"]["model"]["sigma_rad"][0] = -1.0
    assert any("sigma_rad" in p for p in validate_meta(meta))
    with pytest.raises(ValueError, match="sigma_rad"):
        save_checkpoint(tmp_path / "bad.pt", meta, ck.tensors)


def test_sigma_of_a_non_finite_speed_is_pi():
    m = oc.SigmaModel([0.01], [0.8, 0.2])
    assert list(m(np.array([0.0, 0.02, np.nan]))) == [0.8, 0.2, math.pi]


# --- diagram --------------------------------------------------------------------------------

def test_reliability_diagram_is_written_atomically(tmp_path):
    doc = oc.fit_output_calibration(*sample(1000, seed=7))
    model = oc.SigmaModel.from_dict(doc["direction_sigma"]["model"])
    check = oc.calibration_check(*sample(1000, seed=8), model)
    out = oc.plot_reliability(tmp_path / "sub" / "rel.png", check, "synthetic")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in out.parent.iterdir()] == ["rel.png"]   # no temporary left
    no_sigma = oc.calibration_check(*sample(200, seed=9), None)
    assert no_sigma["sigma"] is None
    oc.plot_reliability(tmp_path / "plain.png", no_sigma)
    assert (tmp_path / "plain.png").stat().st_size > 1000


# --- aslip evaluate: the check on the held-out split ----------------------------------------

def test_evaluate_checks_sigma_on_the_test_split_and_draws_the_diagram(tmp_path, capsys):
    """A model that always says (0.02, 0) m/s: its direction error per window is the true
    direction's angle, so the coverage of a 45-degree sigma is known for every split."""
    from node_support import make_checkpoint

    from aslip_ros import cli
    from aslip_ros.learn.data_io import open_dataset, select_windows
    from aslip_ros.learn.evaluate import evaluate_checkpoint
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    data = make_synthetic_dataset(tmp_path / "ds", n_trials=12, duration_s=3.0, seed=3)
    ds = open_dataset(data)
    plain = make_checkpoint(tmp_path / "plain.pt", channel_names=ds.channel_names,
                            sample_rate=ds.sample_rate, window_s=ds.window_s, slip_logit=3.0,
                            velocity=(0.02, 0.0))
    ck = load_checkpoint(plain)
    doc = {"threshold": 0.5, "direction_sigma": {"model": {"speed_edges_m_s": [],
                                                           "sigma_rad": [math.pi / 4]}}}
    save_checkpoint(tmp_path / "s.pt", dict(ck.meta, output_calibration=doc), ck.tensors)

    def expected(split):
        idx = select_windows(ds, split)
        v, slip = ds.velocity(idx), ds.slip(idx)
        m = slip & (np.linalg.norm(v, axis=1) > 0)
        return float((np.abs(np.arctan2(v[m, 1], v[m, 0])) <= math.pi / 4).mean()), int(m.sum())

    test, val = expected("test"), expected("val")
    assert test != val                                   # the splits tell apart
    res = evaluate_checkpoint(tmp_path / "s.pt", data, "test")
    sig = res["output_calibration"]["sigma"]
    assert (sig["coverage"], sig["n"]) == (pytest.approx(test[0]), test[1])
    lo, hi = sig["coverage_ci"]                         # whole trials resampled
    assert lo <= sig["coverage"] <= hi and lo < hi
    assert res["output_calibration"]["ece_ci"][0] <= res["output_calibration"]["ece"]
    assert evaluate_checkpoint(plain, data, "test")["output_calibration"]["sigma"] is None
    png = tmp_path / "rel" / "reliability.png"
    assert cli.main(["evaluate", "--checkpoint", str(tmp_path / "s.pt"), "--dataset",
                     str(data), "--threads", "1", "--reliability", str(png)]) == 0
    out = capsys.readouterr().out
    assert f"{test[0]:.1%} of {test[1]} slip windows within direction sigma" in out
    assert png.read_bytes()[:4] == b"\x89PNG"


# --- training writes it ---------------------------------------------------------------------

def test_training_fits_threshold_and_sigma_on_the_validation_windows(tmp_path):
    from aslip_ros.learn.data_io import open_dataset, select_windows
    from aslip_ros.learn.models.svm import SvmConfig
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    from aslip_ros.learn.training.config import TrainConfig
    from aslip_ros.learn.training.train import train_svm
    ds = open_dataset(make_synthetic_dataset(tmp_path / "ds", n_trials=12, seed=4))
    res = train_svm(ds, TrainConfig(stage="svm", progress=False), svm_config=SvmConfig(),
                    log=lambda s: None)
    doc = res.meta["output_calibration"]
    val = select_windows(ds, "val")
    assert doc["threshold_fit"]["n_windows"] == val.size
    assert doc["threshold_fit"]["n_slip"] == int(ds.slip(val).sum())
    assert res.meta["threshold"] == doc["threshold"]
    res.save(tmp_path / "svm.pt")
    assert load_checkpoint(tmp_path / "svm.pt").meta["output_calibration"] == doc
    # The same choice again from the saved model's predictions on the validation split.
    from aslip_ros.learn.evaluate import predict_split
    p = predict_split(tmp_path / "svm.pt", tmp_path / "ds", "val")
    assert oc.choose_threshold(p["prob"], p["slip"])["threshold"] == doc["threshold"]
    sig = oc.fit_sigma_model(p["raw_velocity"], p["true_velocity"], p["slip"])["model"]
    assert sig is not None
    np.testing.assert_allclose(sig["sigma_rad"],
                               doc["direction_sigma"]["model"]["sigma_rad"], rtol=1e-5)


def test_stream_training_keeps_its_threshold_and_adds_a_sigma_fit(tmp_path):
    from aslip_ros import cli
    from aslip_ros.data.export import export
    from aslip_ros.data.synthetic import write_synthetic_bag
    from test_learn_streaming_model import NAMES
    for i, v in enumerate([(0.02, 0.0, 0.0), (0.0, 0.0, -0.03), (0.0, 0.0, 0.0)] * 3):
        write_synthetic_bag(tmp_path / "bags" / f"t{i}", duration_s=1.5, slip_velocity=v,
                            seed=i, channel_names=NAMES)
    export([tmp_path / "bags"], tmp_path / "ds", window_s=0.2, hop_s=0.1, progress=False)
    out = tmp_path / "stream.pt"
    assert cli.main(["train", "--dataset", str(tmp_path / "ds"), "--stage", "stream",
                     "--out", str(out), "--epochs", "2", "--threads", "1",
                     "--no-progress"]) == 0
    meta = load_checkpoint(out).meta
    doc = meta["output_calibration"]
    assert doc["threshold"] == meta["threshold"]
    assert "false alarms" in doc["threshold_fit"]["criterion"]
    assert doc["threshold_fit"]["n_windows"] > 0 and "direction_sigma" in doc
