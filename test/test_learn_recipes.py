"""Recipe selection (``aslip train``, ``--stage auto``) and ``--device``, on tiny datasets."""

import argparse
import dataclasses
import json

import numpy as np
import pytest
import torch

from aslip_ros.learn.training import recipes

from aslip_ros.learn.training import train

from aslip_ros.learn.training import config as train_config

from aslip_ros.learn.training import cli as train_cli
from aslip_ros.learn.checkpoint import load_checkpoint
from aslip_ros.learn.data_io import open_dataset, trial_splits
from aslip_ros.learn.synthetic import make_synthetic_dataset
from aslip_ros.learn.training.loop import resolve_device

SMALL = ["--width", "8", "--depth", "2", "--temporal-channels", "32", "--head-hidden", "16",
         "--n-mels", "32", "--threads", "1", "--no-progress"]
SMALL_MODEL = dict(width=8, depth=2, temporal_channels=32, head_hidden=16)


def cli(argv):
    p = argparse.ArgumentParser()
    train_cli.add_arguments(p)
    return train_cli.run(p.parse_args(argv))


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("recipes")
    robot = make_synthetic_dataset(root / "robot", n_trials=12, induced="robot", seed=1)
    ext = make_synthetic_dataset(root / "ext", n_trials=14, induced="external", seed=2)
    return root, robot, ext


def _cfg(**kw):
    base = dict(epochs=6, patience=6, threads=1, progress=False)
    base.update(kw)
    return train_config.TrainConfig(**base)


# --- the criterion -----------------------------------------------------------------------

def test_select_picks_the_better_candidate_and_says_why():
    good = {"detection_accuracy": 0.95, "direction_mae_deg": 20.0, "magnitude_rmse_mm": 1.0,
            "n_windows": 100}
    bad = {"detection_accuracy": 0.90, "direction_mae_deg": 30.0, "magnitude_rmse_mm": 1.5,
           "n_windows": 100}
    for order in (("a", "b"), ("b", "a")):
        metrics = dict(zip(order, (good, bad) if order[0] == "a" else (bad, good)))
        winner, scores, why = recipes.select(metrics)
        assert winner == "a" and scores["a"] == pytest.approx(3.0)
        assert scores["b"] == pytest.approx(1.5 + 1.5 + 2.0)
        assert why.startswith("a has the lowest") and "runner-up b" in why
    # A trade: 10 % better direction does not pay for 50 % worse magnitude.
    trade = dict(good, direction_mae_deg=18.0, magnitude_rmse_mm=1.5)
    assert recipes.select({"good": good, "trade": trade})[0] == "good"
    # Equal scores: the candidate trained first wins.
    assert recipes.select({"x": good, "y": dict(good)})[0] == "x"


def test_candidate_missing_a_metric_cannot_win():
    good = {"detection_accuracy": 0.9, "direction_mae_deg": 40.0, "magnitude_rmse_mm": 2.0}
    blind = {"detection_accuracy": 0.99}
    assert recipes.select({"blind": blind, "good": good})[0] == "good"


def test_plan_skips_pretrained_recipes_without_a_robot_set():
    msgs = []
    cands, skipped = recipes.plan(recipes.RECIPES, (0, 3), have_pretrain=False,
                                  log=msgs.append)
    assert [c.name for c in cands] == ["scratch_s0", "scratch_s3", "svm"]
    assert {s["name"] for s in skipped} == {"frozen", "partial", "unfrozen"}
    assert all("--pretrain-dataset" in m for m in msgs) and len(msgs) == 3
    default, _ = recipes.plan(have_pretrain=True)
    assert [c.name for c in default] == ["frozen", "unfrozen", "scratch_s0", "svm"]
    cands, skipped = recipes.plan(recipes.RECIPES, (0,), have_pretrain=True)
    assert [c.name for c in cands] == ["frozen", "partial", "unfrozen", "scratch_s0", "svm"]
    assert not skipped
    with pytest.raises(ValueError, match="unknown recipe"):
        recipes.plan(["frozen", "bogus"], (0,), True)
    with pytest.raises(ValueError, match="no recipe left"):
        recipes.plan(["frozen"], (0,), False, log=lambda m: None)


def test_budget_shares_follow_the_weights():
    jobs = ["pretrain", recipes.Candidate("frozen", "frozen"),
            recipes.Candidate("scratch_s0", "scratch")]
    assert recipes._share(800.0, jobs) == pytest.approx(800 * 4 / 8)
    assert recipes._share(100.0, jobs[1:]) == pytest.approx(100 * 1 / 4)
    assert recipes._share(-5.0, jobs[2:]) == 1.0        # out of time: one epoch still runs


# --- on data -----------------------------------------------------------------------------

def test_selection_on_data_picks_the_trained_candidate(data):
    """Two real candidates on one dataset, the answer known: a CNN trained for a few epochs
    against the same CNN with learning rate zero (its random start)."""
    _, _, ext = data
    ds = open_dataset(ext)
    kw = dict(model_options=SMALL_MODEL, log=lambda m: None)
    from aslip_ros.learn.features import FeatureConfig
    fcfg = FeatureConfig(n_mels=32)

    def trained(c):
        return train.train_cnn(ds, c, feature_config=fcfg, **kw)

    def untrained(c):
        return train.train_cnn(ds, dataclasses.replace(c, lr=0.0, epochs=1), feature_config=fcfg,
                               **kw)

    for order in ((("dead", untrained), ("live", trained)),
                  (("live", trained), ("dead", untrained))):
        cands = [recipes.Candidate(n, "scratch", 0, f) for n, f in order]
        res = recipes.train_selected(ds, _cfg(), recipes=cands, budget_s=120, log=lambda m: None)
        sel = res.meta["provenance"]["selection"]
        assert sel["winner"] == "live" and res.meta["provenance"]["recipe"] == "live"
        scores = {r["name"]: r["score"] for r in sel["candidates"]}
        assert scores["live"] < scores["dead"]


def test_validation_never_shares_a_trial_with_training(data, tmp_path):
    root, robot, ext = data
    out = tmp_path / "auto.pt"
    assert cli(["--dataset", str(ext), "--pretrain-dataset", str(robot), "--out", str(out),
                "--recipes", "frozen,scratch,svm", "--seeds", "0", "--epochs", "3",
                "--time-budget", "120", "--keep-candidates"] + SMALL) == 0
    kept = sorted(p.name for p in (tmp_path / "auto.pt.candidates").iterdir())
    assert kept == ["frozen.pt", "scratch_s0.pt", "svm.pt"]
    sel = json.loads((tmp_path / "auto.pt.selection.json").read_text())
    assert (tmp_path / "auto.pt.selection.md").read_text().count("| ") > 3
    train_t, val_t = set(sel["train_trials"]), set(sel["val_trials"])
    test_t = set(sel["test_trials_untouched"])
    assert train_t and val_t and test_t
    assert not train_t & val_t and not (train_t | val_t) & test_t
    ds = open_dataset(ext)
    splits = dict(zip((t["id"] for t in ds.trials), trial_splits(ds)))
    assert {splits[t] for t in val_t} == {"val"} and {splits[t] for t in train_t} == {"train"}
    assert [r["name"] for r in sel["candidates"]] == ["svm", "frozen", "scratch_s0"]
    assert all(r["status"] == "ok" for r in sel["candidates"])
    ck = load_checkpoint(out)
    prov = ck.meta["provenance"]
    assert prov["selection"]["winner"] == prov["recipe"] == sel["winner"]
    trial_of = np.asarray(ds.windows["trial"])
    for name in ("frozen", "scratch_s0", "svm"):     # what each candidate was scored on
        t = load_checkpoint(tmp_path / "auto.pt.candidates" / f"{name}.pt").meta["provenance"]
        n_val = int(np.isin(trial_of, [k for k, x in enumerate(ds.trials)
                                       if x["id"] in val_t]).sum())
        assert t["metrics"]["val"]["n_windows"] == t["training"]["n_val_windows"] == n_val
    assert sel["winner"] in sel["reason"] and sel["criterion"] == recipes.CRITERION
    assert all(t.device.type == "cpu" for t in ck.tensors.values())


def test_too_few_trials_gives_the_clear_message(tmp_path, capsys):
    small = make_synthetic_dataset(tmp_path / "few", n_trials=4, induced="external", seed=3)
    ds = open_dataset(small)
    assert trial_splits(ds).count("val") < recipes.MIN_VAL_TRIALS
    with pytest.raises(ValueError, match="at least 2 validation trials"):
        recipes.train_selected(ds, _cfg(), recipes=["svm"], log=lambda m: None)
    rc = cli(["--dataset", str(small), "--out", str(tmp_path / "x.pt")] + SMALL)
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err
    assert "validation trial" in err and "record and export more trials" in err
    assert not (tmp_path / "x.pt").exists()


# --- device ------------------------------------------------------------------------------

def test_device_cpu_and_auto_without_cuda(monkeypatch):
    assert resolve_device("cpu").type == "cpu"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto").type == "cpu"
    with pytest.raises(ValueError, match="no CUDA GPU"):
        resolve_device("cuda")
    with pytest.raises(ValueError, match="device must be one of"):
        train_config.TrainConfig(device="tpu")


def test_auto_takes_cuda_where_torch_sees_it(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto").type == "cuda"
    assert resolve_device("cuda").type == "cuda"
    assert resolve_device("cpu").type == "cpu"


def test_cuda_without_a_gpu_is_a_clear_error(data, tmp_path, capsys, monkeypatch):
    _, _, ext = data
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    rc = cli(["--dataset", str(ext), "--stage", "scratch", "--device", "cuda", "--out",
              str(tmp_path / "c.pt"), "--epochs", "1"] + SMALL)
    err = capsys.readouterr().err
    assert rc == 1 and "no CUDA GPU" in err and "Traceback" not in err
    assert not (tmp_path / "c.pt").exists()


def test_device_auto_trains_on_cpu_here(data, tmp_path, monkeypatch):
    _, _, ext = data
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    out = tmp_path / "a.pt"
    assert cli(["--dataset", str(ext), "--stage", "scratch", "--device", "auto", "--out",
                str(out), "--epochs", "1"] + SMALL) == 0
    ck = load_checkpoint(out)
    assert ck.meta["provenance"]["device"] == "cpu"
    assert ck.meta["train_config"]["device"] == "auto"


def test_encoder_learning_rate_groups():
    from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet
    from aslip_ros.learn.training.loop import param_groups
    net = SlipNet(ModelConfig(n_channels=2, n_mels=16, width=4, depth=1, temporal_channels=8,
                              head_hidden=8))
    net.freeze_encoder(("conv1d", "pool"))
    heads, enc = param_groups(net, 1e-3, 0.1)
    assert enc["lr"] == pytest.approx(1e-4) and heads["lr"] == pytest.approx(1e-3)
    enc_ids = {id(p) for p in enc["params"]}
    assert enc_ids == {id(p) for m in (net.encoder.conv1d, net.encoder.pool)
                       for p in m.parameters()}
    assert not any(p.requires_grad for p in net.encoder.conv2d.parameters())
    net.train()
    assert not net.encoder.training                # batch-norm statistics stay fixed
    net.freeze_encoder(())
    assert len(param_groups(net, 1e-3, 0.1)) == 1
    with pytest.raises(ValueError, match="unknown encoder parts"):
        net.freeze_encoder(("heads",))


def test_partial_finetune_moves_only_the_temporal_layers(data, tmp_path):
    root, robot, ext = data
    pre = tmp_path / "pre.pt"
    assert cli(["--dataset", str(robot), "--stage", "pretrain", "--out", str(pre),
                "--epochs", "2"] + SMALL) == 0
    ds = open_dataset(ext)
    cfg = _cfg(stage="finetune", epochs=2, finetune_trainable=("conv1d", "pool"),
               encoder_lr_scale=0.1, calibration="background")
    res = train.train_cnn(ds, cfg, init=load_checkpoint(pre), log=lambda m: None)
    before = load_checkpoint(pre).tensors
    moved = {k for k in res.tensors if not torch.equal(before[k], res.tensors[k])}
    assert any(k.startswith("encoder.conv1d.") and k.endswith("weight") for k in moved)
    assert not any(k.startswith(("encoder.conv2d.", "encoder.attention.")) for k in moved)
    assert not any("running_" in k for k in moved)
    assert np.isfinite(res.meta["provenance"]["metrics"]["val"]["direction_mae_deg"])
