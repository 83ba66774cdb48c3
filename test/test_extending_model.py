"""Extending: a model added in test code alone (test/helpers/fake_model.py), with its training
stage, run through the real pipeline: ``evaluate_checkpoint`` and ``Predictor`` in this
process (registered); ``aslip train``, ``aslip evaluate`` and the ``slip_inference`` node in
child processes (declared as an entry point) (docs/design.md, "Extending")."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from aslip_ros.learn.models import registry as backends
from aslip_ros.learn.checkpoint import load_checkpoint
from aslip_ros.learn.data_io import open_dataset
from aslip_ros.learn.evaluate import evaluate_checkpoint
from aslip_ros.learn.inference.predictor import Predictor
from aslip_ros.learn.synthetic import make_synthetic_dataset
from conftest import HELPERS
from helpers.fake_model import LevelModel, write_checkpoint


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_synthetic_dataset(tmp_path_factory.mktemp("ds") / "synth", n_trials=4,
                                  duration_s=3.0, seed=3)


@pytest.fixture
def registered():
    backends.register_model(LevelModel)
    yield LevelModel
    backends.unregister_model(LevelModel.model_type)


def test_a_model_from_test_code_runs_through_evaluate_and_the_predictor(
        dataset, registered, tmp_path):
    ds = open_dataset(dataset)
    ckpt = write_checkpoint(tmp_path / "level.pt", ds)
    res = evaluate_checkpoint(ckpt, dataset, "all")
    assert res["model_type"] == "test_level" and res["layout"] == "4mic"
    overall = res["overall"]
    assert overall["n_windows"] == len(ds) and overall["n_slip"] > 0
    # Level alone detects the synthetic slip; a pipeline that dropped the model's output
    # (all zeros: never slipping) would score the no-slip fraction, about one half.
    assert overall["detection_accuracy"] > 0.9
    assert overall["direction_mae_deg"] < 60.0           # orthogonal would be 90

    p = Predictor.from_checkpoint(ckpt)
    assert p.model_type == "test_level" and p.window_samples == ds.window_samples
    speed = ds.speed(np.arange(len(ds)))
    cols = ds.channel_indices(p.channel_names)
    loud = ds.window_audio(np.flatnonzero(speed > 0.02)[:1], cols)[0]
    quiet = ds.window_audio(np.flatnonzero(speed == 0)[:1], cols)[0]
    yes, no = p.predict(loud), p.predict(quiet)
    assert yes.slipping and yes.speed == pytest.approx(0.03, rel=1e-5)
    assert not no.slipping and no.speed == 0.0


def test_an_unregistered_model_type_is_refused_with_its_name(dataset, tmp_path):
    ds = open_dataset(dataset)
    with pytest.raises(ValueError, match="unknown model_type 'test_level'"):
        write_checkpoint(tmp_path / "level.pt", ds)
    backends.register_model(LevelModel)
    try:
        path = write_checkpoint(tmp_path / "level.pt", ds)
    finally:
        backends.unregister_model(LevelModel.model_type)
    with pytest.raises(ValueError, match="unknown model_type 'test_level'.*aslip_cnn"):
        load_checkpoint(path)


def test_registration_checks_the_backend():
    class NoPredict:
        model_type, config, streaming = "x_no_predict", LevelModel.config, False
        meta_problems = from_checkpoint = classmethod(lambda cls, *a: None)

    with pytest.raises(ValueError, match="predict"):
        backends.register_model(NoPredict)

    class Taken(LevelModel):
        model_type = "svm"

    with pytest.raises(ValueError, match="already SvmBackend"):
        backends.register_model(Taken)
    with pytest.raises(ValueError, match="built-in"):
        backends.unregister_model("aslip_cnn")
    from aslip_ros.learn.models.aslip_cnn import CnnBackend
    assert backends.model_backend("aslip_cnn") is CnnBackend


def test_a_model_that_returns_bad_shapes_or_nan_is_refused(dataset, registered, tmp_path,
                                                           monkeypatch):
    ds = open_dataset(dataset)
    p = Predictor.from_checkpoint(write_checkpoint(tmp_path / "level.pt", ds))
    w = ds.window_audio(np.arange(2), ds.channel_indices(p.channel_names))
    monkeypatch.setattr(p.backend, "predict", lambda x, o: (np.zeros(3), np.zeros((3, 2))))
    with pytest.raises(ValueError, match="test_level.*expected"):
        p.predict_batch(w)
    monkeypatch.setattr(p.backend, "predict",
                        lambda x, o: (np.full(2, np.nan), np.zeros((2, 2))))
    with pytest.raises(ValueError, match="NaN"):
        p.predict_batch(w)


def test_a_streaming_checkpoint_is_refused_by_the_window_predictor():
    from aslip_ros.learn.checkpoint import Checkpoint
    from aslip_ros.learn.features import FeatureConfig
    meta = {"model_type": "aslip_stream", "feature_config": FeatureConfig().to_dict(),
            "channel_names": ["m0"], "sample_rate": 16000.0, "window_s": 0.032,
            "window_samples": 512}
    assert backends.model_backend("aslip_stream").streaming
    with pytest.raises(ValueError, match="per audio block.*StreamingPredictor"):
        Predictor(Checkpoint(meta))


def _declare_entry_point(root) -> str:
    """An installed-distribution stand-in declaring ``test_level`` in the aslip_ros.models
    group, as a package with the model would in its pyproject; returns the path to add."""
    info = root / "aslip_test_level-0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: aslip-test-level\n"
                                   "Version: 0\n")
    (info / "entry_points.txt").write_text(
        f"[{backends.ENTRY_POINT_GROUP}]\ntest_level = fake_model:LevelModel\n")
    return str(root)


def _child_env(tmp_path, base=None) -> dict:
    env = dict(base or os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        [_declare_entry_point(tmp_path / "site"), str(HELPERS)]
        + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    return env


def test_aslip_evaluate_finds_a_model_declared_as_an_entry_point(dataset, tmp_path):
    """The command line imports nothing of the test: the model comes from its entry point."""
    backends.register_model(LevelModel)
    try:
        ckpt = write_checkpoint(tmp_path / "level.pt", open_dataset(dataset))
    finally:
        backends.unregister_model(LevelModel.model_type)
    out = subprocess.run([sys.executable, "-m", "aslip_ros.cli", "evaluate", "--checkpoint",
                          ckpt, "--dataset", str(dataset), "--split", "all", "--json",
                          str(tmp_path / "m.json"), "--threads", "1"],
                         env=_child_env(tmp_path), capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    res = json.loads((tmp_path / "m.json").read_text())
    assert res["model_type"] == "test_level"
    assert res["overall"]["detection_accuracy"] > 0.9
    # Without the declaration: refused in one line naming the type, no traceback.
    bare = subprocess.run([sys.executable, "-m", "aslip_ros.cli", "evaluate", "--checkpoint",
                           ckpt, "--dataset", str(dataset)], capture_output=True, text=True,
                          timeout=300, env=dict(os.environ, PYTHONPATH=str(HELPERS)))
    assert bare.returncode != 0 and "unknown model_type 'test_level'" in bare.stderr
    assert "Traceback" not in bare.stderr


@pytest.mark.ros
def test_slip_inference_runs_a_model_declared_as_an_entry_point(
        dataset, rclpy_context, ros_env, tmp_path):
    from aslip_ros.msg import AudioFrame, SlipVector
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
    from aslip_ros.nodes import convert
    from node_support import Bus, NodeProcess

    ds = open_dataset(dataset)
    backends.register_model(LevelModel)
    try:
        ckpt = write_checkpoint(tmp_path / "level.pt", ds)
    finally:
        backends.unregister_model(LevelModel.model_type)
    bus = Bus(rclpy_context)
    bus.listen(SlipVector, "/aslip/slip", RELIABLE_QOS)
    pub = bus.node.create_publisher(AudioFrame, c.AUDIO_TOPIC, SENSOR_QOS)
    rng = np.random.default_rng(0)
    n = int(ds.sample_rate * 0.01)
    with NodeProcess("slip_inference", _child_env(tmp_path, ros_env),
                     {"checkpoint": ckpt}) as node:
        node.wait_ready()
        assert bus.wait(lambda: pub.get_subscription_count() > 0, 20), node.output
        index, stamp = 0, 1_000_000_000_000
        deadline = time.monotonic() + 60.0
        while not bus.messages("/aslip/slip") and time.monotonic() < deadline:
            block = (0.1 * rng.standard_normal((n, len(ds.channel_names)))).astype(np.float32)
            pub.publish(convert.audio_to_msg(index, stamp, ds.sample_rate, ds.channel_names,
                                             block, ds.layout))
            index, stamp = index + n, stamp + 10_000_000
            time.sleep(0.005)
        got = bus.messages("/aslip/slip")
    bus.close()
    assert got, node.output
    assert got[-1].source == "test_level" and got[-1].slipping
    assert math.hypot(got[-1].velocity.x, got[-1].velocity.z) == pytest.approx(0.03, rel=1e-4)


@pytest.mark.ros
def test_a_model_from_test_code_is_trained_evaluated_and_served_through_the_commands(
        dataset, rclpy_context, ros_env, tmp_path):
    """Nothing of the package names the model: ``aslip train --stage test_level`` finds its
    training stage through the entry point, the pipeline writes the checkpoint (split,
    metadata, validation metrics, output calibration), ``aslip evaluate`` scores it and a
    real ``slip_inference`` process serves it."""
    env = _child_env(tmp_path)
    ckpt = tmp_path / "trained.pt"
    out = subprocess.run([sys.executable, "-m", "aslip_ros.cli", "train", "--dataset",
                          str(dataset), "--stage", "test_level", "--out", str(ckpt),
                          "--threads", "1", "--no-progress"],
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    meta = load_checkpoint_with(LevelModel, ckpt).meta
    assert meta["model_type"] == "test_level"
    assert meta["provenance"]["stage"] == "test_level"
    assert meta["provenance"]["metrics"]["val"]["detection_accuracy"] > 0.9
    assert "output_calibration" in meta and 0.0 <= meta["threshold"] <= 1.0
    # Without the declaration the stage is refused in one line, no traceback.
    bare = subprocess.run([sys.executable, "-m", "aslip_ros.cli", "train", "--dataset",
                           str(dataset), "--stage", "test_level", "--out",
                           str(tmp_path / "x.pt")], capture_output=True, text=True,
                          timeout=300, env=dict(os.environ, PYTHONPATH=str(HELPERS)))
    assert bare.returncode == 1 and "test_level" in bare.stderr
    assert "Traceback" not in bare.stderr and not (tmp_path / "x.pt").exists()

    res = subprocess.run([sys.executable, "-m", "aslip_ros.cli", "evaluate", "--checkpoint",
                          str(ckpt), "--dataset", str(dataset), "--split", "all", "--json",
                          str(tmp_path / "m.json"), "--threads", "1"],
                         env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert json.loads((tmp_path / "m.json").read_text())["overall"]["detection_accuracy"] > 0.9

    from aslip_ros.msg import AudioFrame, SlipVector
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
    from aslip_ros.nodes import convert
    from node_support import Bus, NodeProcess

    ds = open_dataset(dataset)
    speed = ds.speed(np.arange(len(ds)))
    loud = ds.window_audio(np.flatnonzero(speed > 0.02)[:1], np.arange(len(ds.channel_names)))[0]
    bus = Bus(rclpy_context)
    bus.listen(SlipVector, "/aslip/slip", RELIABLE_QOS)
    pub = bus.node.create_publisher(AudioFrame, c.AUDIO_TOPIC, SENSOR_QOS)
    n = int(ds.sample_rate * 0.01)
    with NodeProcess("slip_inference", _child_env(tmp_path / "node", ros_env),
                     {"checkpoint": str(ckpt)}) as node:
        node.wait_ready()
        assert bus.wait(lambda: pub.get_subscription_count() > 0, 20), node.output
        index, stamp = 0, 1_000_000_000_000
        deadline = time.monotonic() + 60.0
        while not any(m.slipping for m in bus.messages("/aslip/slip")) and \
                time.monotonic() < deadline:
            at = index % (loud.shape[0] - n)
            pub.publish(convert.audio_to_msg(index, stamp, ds.sample_rate, ds.channel_names,
                                             loud[at:at + n].astype(np.float32), ds.layout))
            index, stamp = index + n, stamp + 10_000_000
            time.sleep(0.005)
        got = bus.messages("/aslip/slip")
    bus.close()
    assert any(m.slipping and m.source == "test_level" for m in got), node.output


def load_checkpoint_with(backend, path):
    backends.register_model(backend)
    try:
        return load_checkpoint(path)
    finally:
        backends.unregister_model(backend.model_type)
