"""End to end on a tiny synthetic dataset: train, finetune (frozen encoder), SVM, evaluate."""

import argparse
import json

import numpy as np
import pytest
import torch

from aslip_ros.learn import evaluate

from aslip_ros.learn.training import cli as train_cli
from aslip_ros.learn.checkpoint import load_checkpoint
from aslip_ros.learn.data_io import open_dataset, select_windows, trial_splits
from aslip_ros.learn.synthetic import make_synthetic_dataset

SMALL = ["--width", "8", "--depth", "2", "--temporal-channels", "32", "--head-hidden", "16",
         "--n-mels", "32", "--threads", "1", "--no-progress"]


def cli(module, argv):
    p = argparse.ArgumentParser()
    module.add_arguments(p)
    return module.run(p.parse_args(argv))


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    root = tmp_path_factory.mktemp("learn")
    robot = make_synthetic_dataset(root / "robot", n_trials=12, induced="robot", seed=1)
    ext = make_synthetic_dataset(root / "ext", n_trials=9, induced="external", seed=2)
    assert cli(train_cli, ["--dataset", str(robot), "--stage", "pretrain", "--out",
                           str(root / "pre.pt"), "--epochs", "15", "--patience", "15"]
               + SMALL) == 0
    return root, robot, ext


def test_dataset_split_is_by_trial(work):
    _, robot, _ = work
    ds = open_dataset(robot)
    splits = trial_splits(ds)
    assert set(splits) == {"train", "val", "test"}
    tr, te = select_windows(ds, "train"), select_windows(ds, "test")
    assert not set(ds.windows["trial"][tr]) & set(ds.windows["trial"][te])
    assert trial_splits(ds, seed=0) == splits                     # deterministic


def test_pretrain_learns_and_evaluate_writes_json(work):
    root, robot, _ = work
    out = root / "eval.json"
    assert cli(evaluate, ["--checkpoint", str(root / "pre.pt"), "--dataset", str(robot),
                          "--split", "test", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    m = res["overall"]
    assert m["detection_accuracy"] > 0.85                         # chance is ~0.5
    assert m["direction_mae_deg"] < 45.0                          # chance is 90
    assert np.isfinite(m["magnitude_rmse_mm"]) and m["magnitude_std_mm"] >= 0
    assert set(res["per_object"]) == {"box", "can"}
    ck = load_checkpoint(root / "pre.pt")
    prov = ck.meta["provenance"]
    assert prov["stage"] == "pretrain" and prov["seed"] == 0 and "val" in prov["metrics"]
    assert ck.meta["normalization"]["mean"] and ck.meta["feature_config"]["n_mels"] == 32


def test_finetune_trains_heads_only(work):
    root, _, ext = work
    assert cli(train_cli, ["--dataset", str(ext), "--stage", "finetune", "--init",
                           str(root / "pre.pt"), "--out", str(root / "ft.pt"), "--epochs", "3"]
               + SMALL) == 0
    pre, ft = load_checkpoint(root / "pre.pt"), load_checkpoint(root / "ft.pt")
    enc = [k for k in pre.tensors if not k.startswith("heads.")]
    assert any(k.startswith("encoder.") and "running_mean" in k for k in enc)
    for k in enc:                                                 # weights and BN stats
        assert torch.equal(pre.tensors[k], ft.tensors[k]), k
    assert any(not torch.equal(pre.tensors[k], ft.tensors[k]) for k in ft.tensors
               if k.startswith("heads."))
    assert ft.meta["provenance"]["init_provenance"]["stage"] == "pretrain"


def test_gain_augmentation_flags_reach_the_checkpoint(work, tmp_path, capsys):
    root, _, ext = work
    out = tmp_path / "g.pt"
    assert cli(train_cli, ["--dataset", str(ext), "--stage", "finetune", "--init",
                           str(root / "pre.pt"), "--out", str(out), "--epochs", "1",
                           "--gain-db", "2.5", "--channel-gain-db", "0"] + SMALL) == 0
    cfg = load_checkpoint(out).meta["train_config"]
    assert (cfg["gain_db"], cfg["channel_gain_db"]) == (2.5, 0.0)
    assert cli(train_cli, ["--dataset", str(ext), "--stage", "finetune", "--init",
                           str(root / "pre.pt"), "--out", str(tmp_path / "bad.pt"),
                           "--gain-db", "-1"] + SMALL) == 1
    assert "gain_db" in capsys.readouterr().err and not (tmp_path / "bad.pt").exists()


def test_finetune_refuses_other_channels(work, tmp_path):
    root, _, _ = work
    other = make_synthetic_dataset(tmp_path / "other", n_trials=3, channel_names=("a", "b"))
    assert cli(train_cli, ["--dataset", str(other), "--stage", "finetune", "--init",
                           str(root / "pre.pt"), "--out", str(tmp_path / "x.pt")] + SMALL) == 1
    assert cli(evaluate, ["--checkpoint", str(root / "pre.pt"), "--dataset", str(other)]) == 1


def test_svm_baseline_and_single_channel(work, tmp_path, capsys):
    root, robot, _ = work
    assert cli(train_cli, ["--dataset", str(robot), "--stage", "svm", "--out",
                           str(tmp_path / "svm.pt"), "--no-progress"]) == 0
    # The slip directions it learned from: those of the split's training windows, in the
    # checkpoint, and a warning exactly when a sector is sparse (learn/coverage.py).
    from aslip_ros.learn import coverage
    from aslip_ros.learn.training.config import TrainConfig
    from aslip_ros.learn.training.data import split_windows
    ds = open_dataset(robot)
    want = coverage.of_windows(ds, split_windows(ds, TrainConfig(stage="svm"))[0])
    got = load_checkpoint(tmp_path / "svm.pt").meta["provenance"]["direction_coverage"]
    assert got == json.loads(json.dumps(want)) and want["slip_s"] > 0
    assert ("warning: Slip directions" in capsys.readouterr().out) == coverage.warns(want)
    res = evaluate.evaluate_checkpoint(tmp_path / "svm.pt", robot, "test")
    assert res["model_type"] == "svm" and res["overall"]["detection_accuracy"] > 0.8
    # Scored per true slip direction too: every slip window in one sector, the rest apart.
    by_dir = res["per_direction"]
    assert sum(m["n_slip"] for k, m in by_dir.items() if k != "no slip") == \
        res["overall"]["n_slip"] > 0
    assert sum(m["n_windows"] for m in by_dir.values()) == res["overall"]["n_windows"]
    assert "direction MAE by true slip direction" in evaluate.format_report(res)
    # A single-microphone model picked by name from the 4-mic dataset.
    assert cli(train_cli, ["--dataset", str(robot), "--stage", "scratch", "--channels",
                           "left_front", "--out", str(tmp_path / "one.pt"), "--epochs", "2"]
               + SMALL) == 0
    res = evaluate.evaluate_checkpoint(tmp_path / "one.pt", robot, "test")
    assert res["channel_names"] == ["left_front"]


#: One candidate of each training path: the CNN (with the grasp calibration), the SVM on
#: band features (calibrated) and on log-mel features (uncalibrated). The default set's
#: other candidates repeat these paths.
DETERMINISM_RECIPES = "scratch,svm,svm_logmel_uncalibrated"


def test_training_is_deterministic(work, tmp_path):
    """Every candidate of two ``aslip train`` runs (seed 5) is trained to the same tensors.
    The per-output composition is left out: between parts whose validation predictions the
    trials cannot tell apart it takes the one measured cheaper on this machine
    (``selection._cheaper_part``), a wall-clock measurement (a fresh-clone CI run composed
    ``svm_uncalibrated`` where the other run took ``svm``, at 0.797 of its time against
    the 0.8 threshold)."""
    _, robot, _ = work
    for name in ("a", "b"):
        assert cli(train_cli, ["--dataset", str(robot), "--out", str(tmp_path / f"{name}.pt"),
                               "--epochs", "1", "--seed", "5", "--keep-candidates",
                               "--recipes", DETERMINISM_RECIPES]
                   + SMALL) == 0
    kept = sorted(p.name for p in (tmp_path / "a.pt.candidates").iterdir())
    assert kept == sorted(p.name for p in (tmp_path / "b.pt.candidates").iterdir())
    assert len(kept) == 3 and any(k.startswith("scratch") for k in kept), kept
    for name in kept:
        a = load_checkpoint(tmp_path / "a.pt.candidates" / name)
        b = load_checkpoint(tmp_path / "b.pt.candidates" / name)
        assert sorted(a.tensors) == sorted(b.tensors), name
        for k in a.tensors:
            assert torch.equal(a.tensors[k], b.tensors[k]), (name, k)


def test_metrics_definitions():
    true = np.array([[0.01, 0.0], [0.0, 0.02], [0.0, 0.0]])
    raw = np.array([[0.0, 0.01], [0.0, 0.01], [0.05, 0.0]])
    m = evaluate.compute_metrics(np.array([0.9, 0.2, 0.7]), raw, true,
                                 np.array([True, True, False]), window_s=0.2)
    assert m["detection_accuracy"] == pytest.approx(1 / 3)
    assert m["direction_mae_deg"] == pytest.approx(45.0)          # 90 and 0 degrees
    assert m["direction_std_deg"] == pytest.approx(45.0)
    e = np.array([0.0, 0.01]) * 0.2 * 1e3                         # mm per window
    assert m["magnitude_rmse_mm"] == pytest.approx(np.sqrt((e ** 2).mean()))
    assert m["magnitude_std_mm"] == pytest.approx(e.std())


# ------------------------------------------------------------------ per-grasp calibration

def test_calibrated_checkpoint_round_trips_and_evaluate_applies_it(work, tmp_path):
    """`aslip train` (default --calibration background) stores the constants fitted on the
    training trials; evaluate reads windows with each trial's causal offsets removed."""
    from aslip_ros.learn.calibration.grasp import CalibrationConstants
    from aslip_ros.learn.calibration.frames import dataset_offsets
    from aslip_ros.learn.checkpoint import save_checkpoint
    from aslip_ros.learn.inference.predictor import Predictor
    root, _, _ = work
    robot = make_synthetic_dataset(root / "coupled", n_trials=9, seed=3, coupling_db=3.0,
                                   background=0.02)
    path = tmp_path / "svm.pt"
    assert cli(train_cli, ["--dataset", str(robot), "--stage", "svm", "--out", str(path),
                           "--no-progress"]) == 0
    ck = load_checkpoint(path)
    k = CalibrationConstants.from_dict(ck.meta["calibration"])
    assert k.method == "background" and k.channel_names == tuple(ck.channel_names)
    assert ck.meta["calibration"]["convergence_s"] == pytest.approx(k.convergence_s)
    assert k.convergence_s > 0
    assert CalibrationConstants.from_dict(k.to_dict()) == k
    assert ck.meta["train_config"]["calibration"] == "background"
    p = Predictor(ck)
    assert p.calibrated and p.calibration == k
    ds = open_dataset(robot)
    idx = select_windows(ds, "test")
    off = dataset_offsets(ds, ck.channel_names, p.feature_config, k, idx)[idx]
    assert np.abs(off).max() > 0.1           # +-3 dB per microphone and trial
    res = evaluate.evaluate_checkpoint(path, robot, "test")
    assert res["calibration"] == "background"
    want = p.predict_batch(ds.window_audio(idx, ds.channel_indices(p.channel_names)),
                           offsets=off)
    raw = p.predict_batch(ds.window_audio(idx, ds.channel_indices(p.channel_names)))
    # The same checkpoint without its calibration key evaluates the raw windows.
    meta = {key: v for key, v in ck.meta.items() if key != "calibration"}
    save_checkpoint(tmp_path / "raw.pt", meta, ck.tensors)
    res_raw = evaluate.evaluate_checkpoint(tmp_path / "raw.pt", robot, "test")
    assert res_raw["calibration"] is None
    m = evaluate.compute_metrics(want.probability, want.raw_velocity, ds.velocity(idx),
                                 ds.slip(idx), p.window_s)
    m_raw = evaluate.compute_metrics(raw.probability, raw.raw_velocity, ds.velocity(idx),
                                     ds.slip(idx), p.window_s)
    assert res["overall"]["direction_mae_deg"] == pytest.approx(m["direction_mae_deg"])
    assert res_raw["overall"]["direction_mae_deg"] == pytest.approx(m_raw["direction_mae_deg"])
    assert not np.allclose(want.raw_velocity, raw.raw_velocity)


def test_calibration_off_writes_no_calibration_key(work, tmp_path):
    _, robot, _ = work
    assert cli(train_cli, ["--dataset", str(robot), "--stage", "svm", "--calibration", "off",
                           "--out", str(tmp_path / "svm.pt"), "--no-progress"]) == 0
    ck = load_checkpoint(tmp_path / "svm.pt")
    assert "calibration" not in ck.meta
    assert evaluate.evaluate_checkpoint(tmp_path / "svm.pt", robot)["calibration"] is None


def test_finetune_keeps_the_init_calibration(work, tmp_path):
    root, _, ext = work
    pre = load_checkpoint(root / "pre.pt")
    assert "calibration" in pre.meta                   # the fixture trained with the default
    out = tmp_path / "ft.pt"
    assert cli(train_cli, ["--dataset", str(ext), "--stage", "finetune", "--init",
                           str(root / "pre.pt"), "--out", str(out), "--epochs", "2"] + SMALL) == 0
    assert load_checkpoint(out).meta["calibration"] == pre.meta["calibration"]
    # Raw features into an encoder trained on calibrated ones: refused.
    assert cli(train_cli, ["--dataset", str(ext), "--stage", "finetune", "--init",
                           str(root / "pre.pt"), "--out", str(tmp_path / "x.pt"), "--epochs", "2",
                           "--calibration", "off"] + SMALL) == 1
