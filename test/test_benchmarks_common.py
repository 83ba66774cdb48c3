"""benchmarks.common's caches: a kept dataset, checkpoint or evaluation is made again when
what it was made from changed (the export's labels, the dataset)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from aslip_ros.data.labels import DEFAULT_LABEL_SMOOTHING_S
from benchmarks.common import DataPlan, Recipe, evaluate_cached, train_cached


def _scene_bag(bags: Path) -> None:
    """One short scene trial with the scene's motion-capture noise, slipping for 1 s."""
    from aslip_ros.scene import scenarios
    from aslip_ros.scene.simulate import record_world
    from aslip_ros.scene.world import World
    record_world(World(scenarios.scripted(0, [(0.5, 1.5, 0.02, -0.01)], duration_s=2.0)),
                 bags / "t")


def _raw_labelled(tmp_path: Path, logs: list[str]) -> tuple[DataPlan, Path]:
    """A plan whose finetuning set was exported from its bags before labels were smoothed:
    raw-pose labels, and no ``label_smoothing_s`` in its manifest."""
    from aslip_ros.data.export import ExportConfig, export
    plan = DataPlan(root=tmp_path, progress=False, hop_s=0.05, log=logs.append)
    bags, out = plan.bags("4mic", "finetune"), plan.path("4mic", "finetune")
    _scene_bag(bags)
    export([bags], out, ExportConfig(hop_s=0.05, label_smoothing_s=0.0, progress=False))
    man = json.loads((out / "manifest.json").read_text())
    del man["label_smoothing_s"]
    (out / "manifest.json").write_text(json.dumps(man))
    return plan, out


def test_a_kept_dataset_with_raw_pose_labels_is_exported_again(tmp_path):
    from aslip_ros.data.dataset import Dataset
    logs: list[str] = []
    plan, out = _raw_labelled(tmp_path, logs)
    raw = np.asarray(Dataset(out).windows)
    assert plan.dataset("4mic", "finetune") == out
    ds = Dataset(out)
    assert ds.manifest["label_smoothing_s"] == DEFAULT_LABEL_SMOOTHING_S
    # Its own windows and hop, the labels read again.
    assert ds.manifest["hop_s"] == 0.05 and len(ds.windows) == len(raw)
    assert np.array_equal(ds.windows["start"], raw["start"])
    assert not np.allclose(ds.windows["vx"], raw["vx"])
    assert any(m.startswith(f"exporting {out} again") for m in logs)
    # A dataset with the current labels is kept untouched.
    logs.clear()
    made = (out / "manifest.json").stat().st_mtime_ns
    assert plan.dataset("4mic", "finetune") == out
    assert (out / "manifest.json").stat().st_mtime_ns == made and not logs


def test_a_raw_labelled_dataset_without_its_bags_is_kept_and_said(tmp_path):
    import shutil
    logs: list[str] = []
    plan, out = _raw_labelled(tmp_path, logs)
    shutil.rmtree(plan.bags("4mic", "finetune"))
    assert plan.dataset("4mic", "finetune") == out
    assert "label_smoothing_s" not in json.loads((out / "manifest.json").read_text())
    assert len(logs) == 1 and "delete it to rebuild" in logs[0]


def test_a_checkpoint_is_trained_again_when_its_dataset_was_exported_again(tmp_path):
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    ds, ckpt = tmp_path / "ds", tmp_path / "svm.pt"
    recipe = Recipe(threads=1, progress=False, svm_max_train=200)
    logs: list[str] = []

    def train() -> bool:
        return train_cached(ckpt, ds, "svm", recipe, log=logs.append)["cached"]

    make_synthetic_dataset(ds, n_trials=6, duration_s=2.0, seed=1)
    assert not train() and train()
    make_synthetic_dataset(ds, n_trials=6, duration_s=2.0, seed=2)
    assert not train()
    assert any("exported again" in m for m in logs)
    assert train()


def test_an_evaluation_is_made_again_when_its_dataset_was_exported_again(tmp_path,
                                                                         monkeypatch):
    import aslip_ros.learn.evaluate as evaluate
    calls = []
    monkeypatch.setattr(evaluate, "evaluate_checkpoint",
                        lambda *a, **kw: calls.append(a) or {"n": len(calls)})
    ckpt, ds = tmp_path / "m.pt", tmp_path / "ds"
    ds.mkdir()
    ckpt.write_bytes(b"x")
    (ds / "manifest.json").write_text("{}")
    assert evaluate_cached(ckpt, ds, "t") == {"n": 1}
    assert evaluate_cached(ckpt, ds, "t") == {"n": 1}
    later = (tmp_path / "m.eval-t.json").stat().st_mtime + 10
    os.utime(ds / "manifest.json", (later, later))
    assert evaluate_cached(ckpt, ds, "t") == {"n": 2}
