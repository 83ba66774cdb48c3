"""The SVMs on the CNN's time-averaged log-mel (``SvmConfig.features = "logmel"``, the
``svm_logmel`` candidates of ``aslip train``; issue #36): trained through the pipeline, they
read the CNN's features less the per-grasp offsets, so the live path slides those features
for them as for the CNN, alone or as a part of a ``per_output`` model."""

from __future__ import annotations

import numpy as np
import pytest

from aslip_ros.learn.checkpoint import load_checkpoint, save_checkpoint, validate_meta
from aslip_ros.learn.data_io import open_dataset
from aslip_ros.learn.features import FeatureConfig, LogMel
from aslip_ros.learn.inference.predictor import Predictor
from aslip_ros.learn.models.svm import LogMelMeans, SvmBackend, SvmConfig
from aslip_ros.learn.synthetic import make_synthetic_dataset
from aslip_ros.learn.training.config import TrainConfig
from aslip_ros.learn.training.data import split_windows
from aslip_ros.learn.training.train import train_svm

FCFG = FeatureConfig(n_mels=32)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("svm_logmel")
    ds = open_dataset(make_synthetic_dataset(root / "ds", n_trials=8, seed=4))
    cfg = TrainConfig(stage="svm", calibration="background", threads=1, progress=False)
    res = train_svm(ds, cfg, feature_config=FCFG,
                    svm_config=SvmConfig(features="logmel", max_train=600),
                    log=lambda m: None)
    return ds, cfg, res, save_checkpoint(root / "svm_logmel.pt", res.meta, res.tensors)


def test_it_trains_and_reads_the_cnns_features_less_the_offsets(trained):
    ds, cfg, res, path = trained
    ck = load_checkpoint(path)
    assert ck.meta["model_config"]["features"] == "logmel" and "calibration" in ck.meta
    pred = Predictor(ck)
    assert pred.backend.reads_logmel and isinstance(pred.backend.logmel, LogMel)
    # It learnt the synthetic slip (a pipeline that fed it nothing would score ~0.5).
    val = ck.meta["provenance"]["metrics"]["val"]
    assert val["detection_accuracy"] > 0.8
    _, va = split_windows(ds, cfg)
    x = ds.window_audio(va[:16])
    rng = np.random.default_rng(0)
    off = rng.normal(0.0, 1.0, (16, len(ds.channel_names))).astype(np.float32)
    whole = pred.predict_batch(x, offsets=off)
    feats = LogMel(FCFG, ds.sample_rate)(x)
    # The features it reads: the CNN's log-mel of each channel, less the offsets, averaged.
    by_hand = pred.backend.arrays.predict(
        (feats - off[:, :, None, None]).mean(-1).reshape(16, -1))
    np.testing.assert_allclose(whole.probability, by_hand[0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(whole.raw_velocity, by_hand[1], rtol=1e-4, atol=1e-6)
    # ... and what the live path gives it: log-mel computed elsewhere, offsets removed here.
    live = pred.predict_features(feats, offsets=off)
    np.testing.assert_allclose(live.raw_velocity, whole.raw_velocity, rtol=1e-5, atol=1e-7)
    # Offsets change its answer: the calibration reaches it.
    assert not np.allclose(pred.predict_batch(x).raw_velocity, whole.raw_velocity)


def test_band_features_stay_as_they_were_and_a_bad_feature_name_is_refused(trained):
    _, _, res, _ = trained
    meta = dict(res.meta, model_config=dict(res.meta["model_config"], features="mfcc"))
    assert any("model_config.features must be one of" in p for p in validate_meta(meta))
    old = dict(res.meta["model_config"])
    del old["features"]                          # a checkpoint written before the option
    assert SvmConfig(**old).features == "bands"
    bands = SvmBackend(SvmBackend.from_checkpoint(
        load_checkpoint(trained[3])).arrays, None)
    assert not bands.reads_logmel and not hasattr(bands, "logmel")
    with pytest.raises(ValueError, match="band features"):
        bands.infer_features(np.zeros((1, 4, 32, 5), np.float32))
    assert LogMelMeans.means(np.ones((2, 3, 4, 5))).shape == (2, 12)


class _Counted:
    """A kernel machine that counts its calls."""

    def __init__(self, machine) -> None:
        self.machine, self.calls = machine, 0

    def __call__(self, z):
        self.calls += 1
        return self.machine(z)


class _Fixed:
    """A window part that always answers p and the velocities ``v`` (one row a window)."""

    def __init__(self, p: float, v) -> None:
        self.p, self.v = p, np.asarray(v, np.float32)

    def predict(self, windows, offsets):
        n = len(windows)
        return np.full(n, self.p, np.float32), self.v[:n], None


def test_a_per_output_speed_part_computes_the_speed_alone(trained):
    """An SVM that gives only the speed evaluates only its speed regressor (beside a CNN the
    others cost 0.5 ms a window, cache included), and gives what it gave whole; where the
    direction part has no direction the SVM's own stands in, as before."""
    from aslip_ros.learn.models.per_output import PerOutputBackend
    ds, cfg, _, path = trained
    _, va = split_windows(ds, cfg)
    x = ds.window_audio(va[:3])
    off = np.zeros((3, len(ds.channel_names)), np.float32)
    svm = SvmBackend.from_checkpoint(load_checkpoint(path))
    _, v_whole, _ = svm.predict(x, off)
    others = {"slip": svm.arrays.slip, **{k: m for k, m in svm.arrays.velocity.items()
                                          if k != "speed"}}
    counted = {k: _Counted(m) for k, m in others.items()}
    svm.arrays.slip = counted["slip"]
    svm.arrays.velocity.update({k: c for k, c in counted.items() if k != "slip"})
    roles = {"detection": "cnn", "speed": "svm", "direction": "cnn"}
    up = [[0.0, 1.0]] * 3
    po = PerOutputBackend(roles, {"cnn": _Fixed(0.9, up), "svm": svm},
                          {"cnn": False, "svm": True})
    p, v, _ = po.predict(x, off)
    np.testing.assert_allclose(p, 0.9)
    np.testing.assert_allclose(v[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(v[:, 1], np.linalg.norm(v_whole, axis=1), rtol=1e-5)
    assert {k: c.calls for k, c in counted.items()} == {k: 0 for k in counted}
    # No direction in window 1: the SVM runs whole and its direction stands in there.
    po.backends["cnn"] = _Fixed(0.9, [[0.0, 1.0], [0.0, 0.0], [0.0, 1.0]])
    _, v, _ = po.predict(x, off)
    np.testing.assert_allclose(v[1], v_whole[1], rtol=1e-4, atol=1e-7)
    assert all(c.calls == 1 for c in counted.values())
