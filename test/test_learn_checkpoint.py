"""Checkpoints: round trip, weights_only loading, refusal on mismatch; SVM without pickle."""

import json

import numpy as np
import pytest
import torch

from aslip_ros.learn.checkpoint import (CheckpointMismatch, check_compatible, load_checkpoint,
                                        save_checkpoint)
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet
from aslip_ros.learn.inference.predictor import Predictor
from aslip_ros.learn.models.svm import SvmArrays, SvmConfig, SvmFeaturizer, fit_svm

NAMES = ["left_front", "left_back", "right_back", "right_front"]


def cnn_meta(cfg, fcfg, names=NAMES, sr=48000.0):
    return {"model_type": "aslip_cnn", "model_config": cfg.to_dict(),
            "feature_config": fcfg.to_dict(), "channel_names": list(names), "layout": "4mic",
            "sample_rate": sr, "window_s": 0.2, "window_samples": int(0.2 * sr),
            "epsilon_m_s": 0.005, "threshold": 0.5,
            "provenance": {"dataset": "/x", "seed": 3, "metrics": {"val": {"acc": 0.9}}}}


@pytest.fixture
def cnn_ckpt(tmp_path):
    torch.manual_seed(0)
    cfg = ModelConfig(width=4, n_mels=40)
    net = SlipNet(cfg)
    net.set_normalization(torch.linspace(-5, 0, 40), torch.full((40,), 2.0))
    path = save_checkpoint(tmp_path / "m.pt", cnn_meta(cfg, FeatureConfig()), net.state_dict())
    return path, net


def test_round_trip_and_weights_only(cnn_ckpt):
    path, net = cnn_ckpt
    raw = torch.load(path, weights_only=True)             # no arbitrary unpickling needed
    assert raw["format"] == "aslip-checkpoint" and isinstance(raw["meta"], str)
    ck = load_checkpoint(path)
    assert ck.meta["provenance"]["seed"] == 3
    assert ck.channel_names == NAMES and ck.sample_rate == 48000.0
    for k, v in net.state_dict().items():
        assert torch.equal(ck.tensors[k], v)
    p = Predictor(ck)
    x = (0.01 * np.random.default_rng(0).standard_normal((9600, 4))).astype(np.float32)
    feats = torch.from_numpy(p.logmel(x[None]))
    net.eval()
    with torch.no_grad():
        ref = torch.sigmoid(net(feats).logit).item()
    assert abs(p.predict(x).probability - ref) < 1e-5


def test_refuses_mismatch(cnn_ckpt):
    path, _ = cnn_ckpt
    ck = load_checkpoint(path)
    ck.check_compatible(48000.0, NAMES)
    with pytest.raises(CheckpointMismatch, match="sample rate"):
        ck.check_compatible(44100.0, NAMES)
    with pytest.raises(CheckpointMismatch, match="channels"):
        ck.check_compatible(48000.0, NAMES[:2])
    with pytest.raises(CheckpointMismatch, match="channel names"):
        check_compatible(ck.meta, 48000.0, NAMES[::-1])
    with pytest.raises(ValueError):                        # CheckpointMismatch is a ValueError
        Predictor(ck).check_stream(16000.0, NAMES)


def test_rejects_foreign_files(tmp_path):
    torch.save({"hello": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(ValueError):
        load_checkpoint(tmp_path / "other.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a zip")
    with pytest.raises(ValueError):
        load_checkpoint(tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")
    with pytest.raises(ValueError):
        save_checkpoint(tmp_path / "bad.pt", {"model_type": "aslip_cnn"}, {})


def test_svm_arrays_match_sklearn_and_survive_checkpoint(tmp_path):
    rng = np.random.default_rng(0)
    x = rng.standard_normal((120, 6))
    slip = x[:, 0] + 0.3 * x[:, 1] > 0
    v = np.where(slip[:, None], np.stack([x[:, 2], x[:, 3]], 1) * 0.01, 0.0)
    arrays, est = fit_svm(x, slip, v, SvmConfig())
    z = (x - arrays.mean) / arrays.std
    np.testing.assert_allclose(arrays.slip(z), est["svc"].decision_function(z), atol=1e-6)
    for name in ("speed", "dir_vx", "dir_vz"):
        np.testing.assert_allclose(arrays.velocity[name](z), est[f"svr_{name}"].predict(z),
                                   atol=1e-6)
    prob, vel, rate = arrays.predict(x)
    assert rate is None                       # no angular labels: no rate regressor
    np.testing.assert_array_equal(prob >= 0.5, est["svc"].predict(z) == 1)
    save_checkpoint(tmp_path / "svm.pt", {**cnn_meta(ModelConfig(), FeatureConfig()),
                                          "model_type": "svm",
                                          "model_config": SvmConfig().to_dict()},
                    arrays.to_tensors())
    back = SvmArrays.from_tensors(torch.load(tmp_path / "svm.pt", weights_only=True)["tensors"])
    p2, v2, _ = back.predict(x)
    np.testing.assert_allclose(p2, prob)
    np.testing.assert_allclose(v2, vel)


def test_svm_featurizer_shape_and_finite():
    f = SvmFeaturizer(FeatureConfig(), 48000.0, n_bands=8)
    x = np.zeros((3, 9600, 2), np.float32)                # silence must not give NaN
    out = f(x)
    assert out.shape == (3, 2 * f.n_per_channel)
    assert np.isfinite(out).all()


class _Touch:
    """Unpickling this runs ``Path.touch(marker)``: what a malicious checkpoint would do."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        from pathlib import Path
        return (Path.touch, (Path(self.marker),))


def test_malicious_pickle_is_refused_without_running(tmp_path):
    marker = tmp_path / "ran"
    torch.save({"format": "aslip-checkpoint", "version": 1, "meta": "{}",
                "tensors": {"w": _Touch(marker)}}, tmp_path / "evil.pt")
    with pytest.raises(ValueError, match="evil.pt"):
        load_checkpoint(tmp_path / "evil.pt")
    assert not marker.exists()


def _raw_checkpoint(path, meta, tensors=None, drop=()):
    """A checkpoint file written without save_checkpoint's validation (as a foreign tool
    or a damaged copy could produce it); ``meta`` None leaves the key out."""
    payload = {"format": "aslip-checkpoint", "version": 1, "tensors": tensors or {}}
    if meta is not None:
        payload["meta"] = meta if isinstance(meta, str) else json.dumps(meta)
    for k in drop:
        payload.pop(k)
    torch.save(payload, path)
    return path


def _good_meta():
    return cnn_meta(ModelConfig(width=4, n_mels=40), FeatureConfig())


_MC = ModelConfig(width=4).to_dict()
BAD_META = {
    "no meta": None,
    "meta not JSON": "{oops",
    "meta a list": [1, 2],
    "no model_config": {k: v for k, v in _good_meta().items() if k != "model_config"},
    "window_samples -5": {**_good_meta(), "window_samples": -5},
    "window_samples disagrees": {**_good_meta(), "window_samples": 4800},
    "sample_rate text": {**_good_meta(), "sample_rate": "48k"},
    "sample_rate zero": {**_good_meta(), "sample_rate": 0},
    "window_s NaN-like": {**_good_meta(), "window_s": -0.2},
    "no channels": {**_good_meta(), "channel_names": []},
    "duplicate channels": {**_good_meta(), "channel_names": ["a", "a", "b", "c"]},
    "threshold 3": {**_good_meta(), "threshold": 3},
    "output calibration threshold": {**_good_meta(), "output_calibration": {
        "threshold": 2.0, "direction_sigma": {"model": None}}},
    "output calibration negative sigma": {**_good_meta(), "output_calibration": {
        "threshold": 0.5, "direction_sigma": {"model": {"speed_edges_m_s": [],
                                                        "sigma_rad": [-1.0]}}}},
    "unknown model type": {**_good_meta(), "model_type": "transformer"},
    "width text": {**_good_meta(), "model_config": {**_MC, "width": "4"}},
    "width fraction": {**_good_meta(), "model_config": {**_MC, "width": 2.5}},
    "channel count": {**_good_meta(), "model_config": {**_MC, "n_channels": 2}},
    "mel count": {**_good_meta(), "model_config": {**_MC, "n_mels": 32}},
    "feature config": {**_good_meta(), "feature_config": {"n_fft": -1}},
    "window too short": {**_good_meta(), "window_s": 0.01, "window_samples": 480},
    "svm without n_bands type": {**_good_meta(), "model_type": "svm",
                                 "model_config": {"n_bands": "eight"}},
}


@pytest.mark.parametrize("case", sorted(BAD_META))
def test_unusable_metadata_is_refused_by_the_loader(tmp_path, case):
    """Regression: a checkpoint without meta/model_config or with window_samples -5 passed
    the loader and crashed its consumer (KeyError in evaluate, the node on -5)."""
    path = _raw_checkpoint(tmp_path / "m.pt", BAD_META[case])
    with pytest.raises(ValueError, match="m.pt") as err:
        load_checkpoint(path)
    assert "Traceback" not in str(err.value)
    with pytest.raises(ValueError):
        Predictor.from_checkpoint(path)
    with pytest.raises(ValueError):             # the same checks guard writing
        if isinstance(BAD_META[case], dict):
            save_checkpoint(tmp_path / "again.pt", BAD_META[case], {})
        else:
            raise ValueError("not a dict: nothing to save")


def test_non_finite_or_foreign_tensors_are_refused(tmp_path, cnn_ckpt):
    path, net = cnn_ckpt
    state = dict(net.state_dict())
    key = next(k for k, v in state.items() if v.is_floating_point())
    state[key] = state[key].clone().fill_(float("nan"))
    _raw_checkpoint(tmp_path / "nan.pt", _good_meta(), state)
    with pytest.raises(ValueError, match="NaN"):
        load_checkpoint(tmp_path / "nan.pt")
    _raw_checkpoint(tmp_path / "nt.pt", _good_meta(), drop=("tensors",))
    with pytest.raises(ValueError, match="tensors"):
        load_checkpoint(tmp_path / "nt.pt")


def test_evaluate_refuses_a_bad_checkpoint_in_one_line(tmp_path, capsys):
    from aslip_ros import cli
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    ds = make_synthetic_dataset(tmp_path / "ds", n_trials=3)
    for case in ("no meta", "no model_config", "window_samples -5"):
        path = _raw_checkpoint(tmp_path / "m.pt", BAD_META[case])
        rc = cli.main(["evaluate", "--checkpoint", str(path), "--dataset", str(ds),
                       "--split", "all"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 1 and len(err) == 1 and str(path) in err[0], (case, err)


def test_unwritable_checkpoint_path_is_one_error_naming_it(tmp_path, cnn_ckpt):
    _, net = cnn_ckpt
    blocker = tmp_path / "file"
    blocker.write_text("a file where a directory should be")
    with pytest.raises(OSError, match=f"cannot write checkpoint {blocker / 'm.pt'}"):
        save_checkpoint(blocker / "m.pt", _good_meta(), net.state_dict())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "m.pt"]


def test_checkpoint_meta_is_the_document_every_trainer_writes(tmp_path):
    from types import SimpleNamespace

    from aslip_ros.learn.checkpoint import checkpoint_meta
    ds = SimpleNamespace(channel_names=NAMES, layout="4mic", sample_rate=48000.0,
                         window_s=0.2, window_samples=9600, epsilon=0.005)
    fcfg = FeatureConfig()
    full = checkpoint_meta("aslip_cnn", ModelConfig(width=4, n_mels=fcfg.n_mels), fcfg, ds,
                           NAMES, normalization=None, provenance={"seed": 1},
                           train_config={"lr": 1e-3})
    assert full["layout"] == "4mic" and full["threshold"] == 0.5
    assert (full["window_s"], full["window_samples"], full["epsilon_m_s"]) == (0.2, 9600, 0.005)
    assert full["train_config"] == {"lr": 1e-3} and "calibration" not in full
    net = SlipNet(ModelConfig(width=4, n_mels=fcfg.n_mels))
    assert load_checkpoint(save_checkpoint(tmp_path / "m.pt", full,
                                           net.state_dict())).meta["provenance"] == {"seed": 1}
    # A channel subset names itself in the layout; a streaming model reads one frame.
    cal = SimpleNamespace(to_dict=lambda: {"method": "background"})
    sub = checkpoint_meta("aslip_stream", ModelConfig(n_channels=2), fcfg, ds, NAMES[:2],
                          normalization=None, provenance={}, window_s=0.032,
                          window_samples=1536, calibration=cal, hop_s=0.01)
    assert sub["layout"] == "4mic:left_front+left_back"
    assert (sub["window_s"], sub["window_samples"], sub["hop_s"]) == (0.032, 1536, 0.01)
    assert sub["calibration"] == {"method": "background"}


def test_an_unknown_model_type_is_refused_with_the_known_ones_named(cnn_ckpt, tmp_path):
    meta = dict(load_checkpoint(cnn_ckpt[0]).meta, model_type="transformer")
    with pytest.raises(ValueError, match="unknown model_type 'transformer'.*aslip_cnn.*svm"):
        save_checkpoint(tmp_path / "x.pt", meta, {})
