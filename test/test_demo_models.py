"""The demo's model set: which checkpoint each method runs, how each is trained (with or
without the per-grasp calibration), and that a set trained for another scene is refused."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from benchmarks import demo, demo_models

ROOT = Path(__file__).resolve().parents[1]


def _option(cmd: list[str], name: str) -> str:
    return cmd[cmd.index(name) + 1]


def test_the_uncalibrated_cnn_is_trained_without_calibration_and_the_others_with_it():
    cmds = {m: demo_models.train_command(m, "D", f"out/{m}.pt") for m in demo_models.MODELS}
    assert _option(cmds["aslip_window"], "--calibration") == "background"
    assert _option(cmds["svm"], "--calibration") == "background"
    assert _option(cmds["aslip_uncalibrated"], "--calibration") == "off"
    # The two window CNNs differ in nothing else: the calibration is what the pair compares.
    strip = [a for a in cmds["aslip_window"]
             if a not in ("background", "out/aslip_window.pt")]
    assert strip == [a for a in cmds["aslip_uncalibrated"]
                     if a not in ("off", "out/aslip_uncalibrated.pt")]
    assert _option(cmds["aslip_window"], "--stage") == "scratch"
    assert _option(cmds["svm"], "--stage") == "svm"
    # The streaming model, on the same trials, calibrated.
    assert _option(cmds["aslip_stream"], "--stage") == "stream"
    assert _option(cmds["aslip_stream"], "--calibration") == "background"
    assert demo_models.MODELS["aslip_stream"][0] == "aslip_stream.pt"
    # Every method of the demo has a model in the set, and the set nothing else, but for the
    # package's estimator, aslip, assembled from two of them.
    assert demo_models.DEFAULT == "aslip" and "aslip" not in demo_models.MODELS
    assert set(demo_models.MODELS) | {demo_models.DEFAULT} == set(demo.METHODS)
    assert demo_models.DEFAULT_PARTS == ("aslip_stream", "aslip_window")


def _write_set(d: Path, version: str, skip: str | None = None) -> dict:
    d.mkdir(parents=True, exist_ok=True)
    files = {m: v[0] for m, v in demo_models.MODELS.items()}
    for m, f in files.items():
        if m != skip:
            (d / f).write_bytes(b"x")
    man = {"scene_version": version, "version": demo_models.MANIFEST_VERSION, "files": files,
           "model_recipes": {m: demo_models.model_recipe(m) for m in files},
           "test_metrics": {m: {"test_set": "demo"} for m in files},
           "train_s_per_model": {m: 1.0 for m in files}}
    (d / demo_models.MANIFEST).write_text(json.dumps(man))
    return man


def test_a_set_for_another_scene_version_is_refused(tmp_path):
    now = demo_models.scene_version()
    assert demo_models.shipped_models(tmp_path / "none") is None
    assert demo_models.shipped_models(tmp_path) is None
    _write_set(tmp_path / "old", "2")
    assert now != "2" and demo_models.shipped_models(tmp_path / "old") is None
    _write_set(tmp_path / "ok", now)
    assert demo_models.shipped_models(tmp_path / "ok")["scene_version"] == now


@pytest.mark.parametrize("missing", sorted(demo_models.MODELS))
def test_a_partial_set_is_refused(tmp_path, missing):
    _write_set(tmp_path, demo_models.scene_version(), skip=missing)
    assert demo_models.shipped_models(tmp_path) is None


def test_a_set_from_before_the_per_model_recipes_is_refused(tmp_path):
    """Manifest version 4 (one recipe for every model) is retrained even for this scene."""
    _write_set(tmp_path, demo_models.scene_version())
    man = json.loads((tmp_path / demo_models.MANIFEST).read_text())
    assert demo_models.MANIFEST_VERSION == 5
    man["version"] = 4
    (tmp_path / demo_models.MANIFEST).write_text(json.dumps(man))
    assert demo_models.shipped_models(tmp_path) is None
    del man["version"]
    (tmp_path / demo_models.MANIFEST).write_text(json.dumps(man))
    assert demo_models.shipped_models(tmp_path) is None


@pytest.mark.parametrize("method", sorted(demo_models.MODELS))
def test_a_set_where_one_models_recipe_changed_is_refused(tmp_path, method):
    _write_set(tmp_path, demo_models.scene_version())
    man = json.loads((tmp_path / demo_models.MANIFEST).read_text())
    man["model_recipes"][method]["data_recipe"]["seed"] = 7
    (tmp_path / demo_models.MANIFEST).write_text(json.dumps(man))
    assert demo_models.shipped_models(tmp_path) is None


def test_a_set_trained_before_its_labels_were_smoothed_is_refused(tmp_path):
    """The export's label smoothing is part of each set's recipe (its default, so a changed
    default retrains): a manifest whose recipes predate it (raw-pose labels) is stale."""
    from aslip_ros.data.labels import DEFAULT_LABEL_SMOOTHING_S
    assert demo_models.RECIPE["label_smoothing_s"] == DEFAULT_LABEL_SMOOTHING_S > 0
    _write_set(tmp_path, demo_models.scene_version())
    assert demo_models.shipped_models(tmp_path) is not None
    man = json.loads((tmp_path / demo_models.MANIFEST).read_text())
    for r in man["model_recipes"].values():
        del r["data_recipe"]["label_smoothing_s"]
    (tmp_path / demo_models.MANIFEST).write_text(json.dumps(man))
    assert demo_models.shipped_models(tmp_path) is None


def _simulated(tmp_path, monkeypatch, sets):
    import aslip_ros.data.export as export
    import aslip_ros.scene.simulate as simulate
    calls, exported = [], []
    monkeypatch.setattr(simulate, "simulate",
                        lambda out, kind, **kw: calls.append((Path(out), kind, kw)) or {})
    configs = []
    monkeypatch.setattr(export, "export", lambda bags, ds, cfg: exported.append((bags, ds))
                        or configs.append(cfg))
    got = demo_models.prepare_data(tmp_path, progress=False, sets=sets)
    # Every set is exported with the recipe's windows and label smoothing.
    r = demo_models.RECIPE
    assert [(c.window_s, c.hop_s, c.label_smoothing_s) for c in configs] \
        == [(r["window_s"], r["hop_s"], r["label_smoothing_s"])] * len(sets)
    return calls, exported, got


def test_the_recipe_trains_on_twisting_pushes_and_gravity_pivots(tmp_path, monkeypatch):
    """The models must hear rotation to estimate it: the externally induced trials twist a
    share of their pushes, and gravity-pivot trials join the set, in the scene-version
    folder the export reads."""
    r = demo_models.RECIPE
    assert 0.0 < r["twist_fraction"] < 1.0 and r["gravity_pivot"] >= 1
    calls, exported, got = _simulated(tmp_path, monkeypatch, ("demo",))
    ext = [kw for _, kind, kw in calls if kind == "external"]
    assert sorted(c for kw in ext for c in kw["conditions"]) == ["robot_moving",
                                                                 "robot_stationary"]
    assert all(kw["twist_fraction"] == r["twist_fraction"] for kw in ext)
    pivot = [kw for _, kind, kw in calls if kind == "pivot"]
    assert len(pivot) == 1 and pivot[0]["trials"] == r["gravity_pivot"]
    assert pivot[0]["conditions"] == [demo_models.PIVOT_CONDITION]
    assert "twist_fraction" not in pivot[0]
    assert not any("robot_noise_range" in kw for _, _, kw in calls)   # the scene's arm
    bags = {out for out, _, _ in calls}
    assert len(bags) == 1 and [b for b, _ in exported] == [[bags.pop()]]
    assert f"scene-{demo_models.scene_version()}" in str(exported[0][0][0])
    assert got == {"demo": exported[0][1]}


def test_the_streaming_parts_set_draws_the_arm_only_where_it_moves(tmp_path, monkeypatch):
    """``arm_drawn``: the demo set's trials, each arm-moving one (external and gravity pivot)
    with its arm's loudness drawn in the recipe's range, the trials with the arm still as
    the scene makes them; its own folder, apart from the demo set's bags."""
    r = demo_models.RECIPE
    calls, exported, got = _simulated(tmp_path, monkeypatch, ("arm_drawn",))
    assert sorted((kind, kw["conditions"][0], kw["trials"]) for _, kind, kw in calls) == [
        ("external", "robot_moving", r["robot_moving"]),
        ("external", "robot_stationary", r["robot_stationary"]),
        ("pivot", "robot_moving", r["gravity_pivot"]),
        ("pivot", "robot_stationary", r["gravity_pivot"])]
    for _, _, kw in calls:
        drawn = kw.get("robot_noise_range")
        assert drawn == (tuple(r["arm_noise_range"]) if kw["conditions"] == ["robot_moving"]
                         else None)
    (bags, ds), = exported
    assert sorted({out for out, _, _ in calls}) == sorted(bags) and len(bags) == 2
    assert all("arm_drawn" in str(b) for b in bags) and got == {"arm_drawn": ds}
    assert demo_models.MODEL_DATA["aslip_stream"] == "arm_drawn"
    assert {demo_models.MODEL_DATA[m] for m in demo_models.MODELS if m != "aslip_stream"} \
        == {"demo"}


def test_a_manifest_from_before_the_uncalibrated_model_is_refused(tmp_path):
    _write_set(tmp_path, demo_models.scene_version())
    man = json.loads((tmp_path / demo_models.MANIFEST).read_text())
    del man["files"]["aslip_uncalibrated"]
    (tmp_path / demo_models.MANIFEST).write_text(json.dumps(man))
    assert demo_models.shipped_models(tmp_path) is None


def _args(models: Path, **kw) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    demo.add_arguments(p)
    a = p.parse_args(["--models", str(models)])
    for k, v in kw.items():
        setattr(a, k, v)
    return a


def test_each_method_runs_its_own_checkpoint(tmp_path):
    _write_set(tmp_path, demo_models.scene_version())
    got = demo.resolve_models(_args(tmp_path))
    assert got["aslip_stream"] == tmp_path / demo_models.STREAM_NAME
    assert got["aslip_window"] == tmp_path / demo_models.CNN_NAME
    assert got["aslip_uncalibrated"] == tmp_path / demo_models.UNCALIBRATED_NAME
    assert got["svm"] == tmp_path / demo_models.SVM_NAME
    assert got["source"].startswith("shipped")


def test_a_stale_set_is_retrained_before_the_demo_runs(tmp_path, monkeypatch):
    _write_set(tmp_path, "2")
    calls = []

    def fake_train(models_dir, data_dir, progress=True):
        calls.append(Path(models_dir))
        return _write_set(Path(models_dir), demo_models.scene_version())
    monkeypatch.setattr(demo_models, "train_models", fake_train)
    got = demo.resolve_models(_args(tmp_path))
    assert calls == [tmp_path] and got["source"] == "trained now"


def test_explicit_checkpoints_need_no_manifest(tmp_path):
    a = _args(tmp_path / "nothing", stream="a.pt", svm="s.pt")
    got = demo.resolve_models(a, ("aslip_stream", "svm"))
    assert got["aslip_stream"] == Path("a.pt") and got["svm"] == Path("s.pt")
    assert got["source"] == "command line"
    assert "aslip_uncalibrated" not in got          # not asked for, so not made up


def test_the_shipped_models_belong_to_this_scene_with_their_calibration():
    """models/: trained for the current scene version, the calibrated models carry the
    per-grasp calibration (background method) and the uncalibrated CNN none."""
    from aslip_ros.learn.checkpoint import load_checkpoint
    man = demo_models.shipped_models(ROOT / "models")
    assert man is not None, "models/ is stale or partial: make demo ARGS=--train-models"
    for method, (name, _, calibration) in demo_models.MODELS.items():
        meta = load_checkpoint(ROOT / "models" / man["files"][method]).meta
        # Every model estimates rotation, which the pivot-stop task acts on (issue #21).
        assert "wy" in meta.get("outputs", []), method
        if calibration == "off":
            assert "calibration" not in meta, method
        else:
            assert meta["calibration"]["method"] == calibration, method


def test_the_demo_runs_the_package_estimator_first_beside_its_parts_and_two_baselines():
    assert demo.DEFAULT_METHODS == ("aslip", "aslip_stream", "aslip_window",
                                    "aslip_uncalibrated", "svm")


def test_retraining_trains_every_model_and_records_its_scene(tmp_path, monkeypatch):
    _write_set(tmp_path, "2")
    prepared = []

    def fake_prepare(data_dir, progress, sets):
        prepared.append(sets)
        return {s: tmp_path / "data" / s / "ds" for s in sets}
    monkeypatch.setattr(demo_models, "prepare_data", fake_prepare)
    trained = []

    def fake_aslip(argv):
        if argv[0] == "train":
            trained.append((argv[argv.index("--stage") + 1],
                            Path(argv[argv.index("--dataset") + 1]).parent.name))
            Path(argv[argv.index("--out") + 1]).write_bytes(b"model")
        else:
            Path(argv[argv.index("--json") + 1]).write_text(json.dumps({"overall": {}}))
        return 0
    for name in demo_models.DATASETS:
        (tmp_path / "data" / name).mkdir(parents=True)
    monkeypatch.setattr(demo_models, "aslip", fake_aslip)
    assembled = []

    def fake_hybrid(stream, window, out):
        assembled.append((stream, window, out))
        Path(out).write_bytes(b"hybrid")
        return Path(out)
    monkeypatch.setattr(demo_models, "hybrid_checkpoint", fake_hybrid)
    man = demo_models.train_models(tmp_path, tmp_path / "data", progress=False)
    assert sorted(trained) == [("scratch", "demo"), ("scratch", "demo"),
                               ("stream", "arm_drawn"), ("svm", "demo")]
    assert prepared == [("arm_drawn", "demo")]
    assert man["scene_version"] == demo_models.scene_version()
    assert man["version"] == demo_models.MANIFEST_VERSION
    assert man["recipe"]["twist_fraction"] == demo_models.RECIPE["twist_fraction"]
    assert man["calibration"] == {"aslip_stream": "background", "aslip_window": "background",
                                  "aslip_uncalibrated": "off", "svm": "background"}
    files = demo_models.shipped_models(tmp_path)["files"]
    assert files["aslip_stream"] == demo_models.STREAM_NAME
    assert files["aslip"] == demo_models.DEFAULT_NAME == "aslip.pt"
    assert man["train_commands"]["aslip"].startswith("aslip hybrid --stream models/")
    assert assembled == [(tmp_path / demo_models.STREAM_NAME, tmp_path / demo_models.CNN_NAME,
                          tmp_path / "aslip.pt")]
    assert man["test_metrics"]["aslip_stream"]["test_set"] == "arm_drawn"
    # The set is current now: nothing is trained or simulated again.
    trained.clear()
    prepared.clear()
    demo_models.train_models(tmp_path, tmp_path / "data", progress=False)
    assert trained == [] and prepared == [()]
    # Only the streaming part's recipe changes: it alone is retrained, on its own set.
    monkeypatch.setitem(demo_models.RECIPE, "arm_noise_range", [0.5, 3.0])
    assert demo_models.shipped_models(tmp_path) is None
    man = demo_models.train_models(tmp_path, tmp_path / "data", progress=False)
    assert trained == [("stream", "arm_drawn")] and prepared[-1] == ("arm_drawn",)
    assert man["retrained"] == ["aslip_stream"]
    assert man["model_recipes"]["aslip_stream"]["data_recipe"]["arm_noise_range"] == [0.5, 3.0]
    assert demo_models.shipped_models(tmp_path) is not None


def test_track_settings_from_the_command_line_keep_their_types_and_refuse_unknown_names():
    from benchmarks.demo_episode import StopSettings, TrackSettings
    got = demo.settings_overrides(TrackSettings, ["velocity_window_s=0.1", "agent_hold_s=0"])
    assert got == {"velocity_window_s": 0.1, "agent_hold_s": 0.0}
    assert demo.settings_overrides(StopSettings, ["debounce_count=2"]) == {"debounce_count": 2}
    with pytest.raises(ValueError, match="NAME=VALUE"):
        demo.settings_overrides(TrackSettings, ["no_such_field=1"])
    with pytest.raises(ValueError):
        demo.settings_overrides(TrackSettings, ["gain=fast"])


def test_the_default_is_the_hybrid_of_the_sets_stream_and_window_models(tmp_path):
    from aslip_ros.learn.checkpoint import load_checkpoint
    from node_support import make_checkpoint
    from test_learn_streaming_model import NAMES
    from test_learn_streaming_model import make_checkpoint as make_stream
    models, data = tmp_path / "models", tmp_path / "data"
    _write_set(models, demo_models.scene_version())
    make_stream(models / demo_models.STREAM_NAME, threshold=0.5, angular=True)
    make_checkpoint(models / demo_models.CNN_NAME, channel_names=NAMES, angular=True)
    args = _args(models, train_data=str(data))
    # No aslip.pt in the set: assembled into the scratch folder.
    got = demo.resolve_models(args, ["aslip"])["aslip"]
    assert got == data / demo_models.DEFAULT_NAME
    hybrid, cnn = load_checkpoint(got), load_checkpoint(models / demo_models.CNN_NAME)
    assert hybrid.model_type == "aslip_hybrid"
    assert hybrid.meta["model_config"]["detection"] == "latched"
    assert all((hybrid.tensors[f"window/{k}"] == v).all() for k, v in cnn.tensors.items())
    # The same parts: the file is kept.
    stamp = got.stat().st_mtime_ns
    assert demo.resolve_models(args, ["aslip"])["aslip"] == got
    assert got.stat().st_mtime_ns == stamp
    # A shipped aslip.pt of these parts is run, wherever they were assembled from.
    shipped = models / demo_models.DEFAULT_NAME
    got.rename(shipped)
    assert demo.resolve_models(args, ["aslip"])["aslip"] == shipped
    # Another window model: the shipped one no longer fits, and a new one is assembled.
    make_checkpoint(models / demo_models.CNN_NAME, channel_names=NAMES, angular=True, seed=9)
    got = demo.resolve_models(args, ["aslip"])["aslip"]
    assert got == data / demo_models.DEFAULT_NAME
    cnn, hybrid = load_checkpoint(models / demo_models.CNN_NAME), load_checkpoint(got)
    assert all((hybrid.tensors[f"window/{k}"] == v).all() for k, v in cnn.tensors.items())
    # One named on the command line is run as it is.
    named = demo.resolve_models(_args(models, aslip=str(tmp_path / "h.pt")), ["aslip"])
    assert named["aslip"] == tmp_path / "h.pt"


def test_the_shipped_default_is_the_hybrid_of_the_shipped_parts():
    """models/aslip.pt, the one checkpoint both closed-loop launch files run, was assembled
    from the streaming model and the window CNN beside it."""
    from aslip_ros import node_table
    from aslip_ros.learn.checkpoint import load_checkpoint
    d = ROOT / "models"
    man = demo_models.shipped_models(d)
    assert man is not None and man["files"]["aslip"] == node_table.DEFAULT_MODEL
    assert {s.default_model for s in node_table.nodes().values() if s.drives_arm
            and s.default_model} == {node_table.DEFAULT_MODEL}
    ck = load_checkpoint(d / node_table.DEFAULT_MODEL)
    assert ck.model_type == "aslip_hybrid" and "wy" in ck.meta["outputs"]
    import hashlib
    from aslip_ros.learn.models.aslip_hybrid import assembled_from
    assert assembled_from(d / node_table.DEFAULT_MODEL) == {
        n: hashlib.sha256((d / f).read_bytes()).hexdigest()
        for n, f in (("stream", demo_models.STREAM_NAME), ("window", demo_models.CNN_NAME))}


def test_a_kept_model_without_figures_in_its_manifest_is_kept_without_them(tmp_path,
                                                                           monkeypatch):
    """A manifest that lists a current model's recipe but not its test metrics or training
    time (written by hand, or cut short) keeps the model; it does not fail the retrain."""
    _write_set(tmp_path, demo_models.scene_version())
    man = json.loads((tmp_path / demo_models.MANIFEST).read_text())
    del man["test_metrics"], man["train_s_per_model"]
    man["model_recipes"]["svm"]["command"] = ["stale"]
    (tmp_path / demo_models.MANIFEST).write_text(json.dumps(man))
    monkeypatch.setattr(demo_models, "prepare_data",
                        lambda data_dir, progress, sets: {s: tmp_path / s / "ds" for s in sets})

    def fake_aslip(argv):
        if argv[0] == "train":
            Path(argv[argv.index("--out") + 1]).write_bytes(b"model")
        else:
            Path(argv[argv.index("--json") + 1]).write_text(json.dumps({"overall": {}}))
        return 0
    (tmp_path / "demo").mkdir()
    monkeypatch.setattr(demo_models, "aslip", fake_aslip)
    monkeypatch.setattr(demo_models, "hybrid_checkpoint",
                        lambda stream, window, out: Path(out).write_bytes(b"h") and Path(out))
    man = demo_models.train_models(tmp_path, tmp_path / "data", progress=False)
    assert man["retrained"] == ["svm"]
    assert man["test_metrics"]["aslip_window"] is None
    assert man["test_metrics"]["svm"]["test_set"] == "demo"
    assert demo_models.shipped_models(tmp_path) is not None
