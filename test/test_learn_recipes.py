"""Recipe selection (``aslip train``, ``--stage auto``) and ``--device``, on tiny datasets."""

import argparse
import dataclasses
import json

import numpy as np
import pytest
import torch

from aslip_ros.learn import coverage
from aslip_ros.learn.training import allocation, folds, recipes, selection
from aslip_ros.learn.training.data import split_windows

from aslip_ros.learn.models import aslip_cnn_fit

from aslip_ros.learn.training import config as train_config

from aslip_ros.learn.training import cli as train_cli
from aslip_ros.learn.checkpoint import load_checkpoint
from aslip_ros.learn.data_io import open_dataset, trial_splits
from aslip_ros.learn.synthetic import make_synthetic_dataset
from aslip_ros.learn.training.config import resolve_device

from fake_clock import FakeClock

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
        winner, scores, why = selection.select(metrics)
        assert winner == "a" and scores["a"] == pytest.approx(3.0)
        assert scores["b"] == pytest.approx(1.5 + 1.5 + 2.0)
        assert why.startswith("a has the lowest") and "runner-up b" in why
    # A trade: 10 % better direction does not pay for 50 % worse magnitude.
    trade = dict(good, direction_mae_deg=18.0, magnitude_rmse_mm=1.5)
    assert selection.select({"good": good, "trade": trade})[0] == "good"
    # Equal scores: the candidate trained first wins.
    assert selection.select({"x": good, "y": dict(good)})[0] == "x"


def test_rotating_validation_windows_add_the_rotational_error_to_the_criterion():
    planar = {"detection_accuracy": 0.95, "direction_mae_deg": 20.0, "magnitude_rmse_mm": 1.0}
    # Planar metrics alone: the criterion is as before (3.0 for the best at all three).
    assert selection.score({"a": planar})["a"] == pytest.approx(3.0)
    # Equal on the planar metrics, one hears the rotation at half the other's error.
    deaf = dict(planar, rotation_mae_deg_s=80.0)
    hears = dict(planar, rotation_mae_deg_s=40.0)
    for order in (("deaf", "hears"), ("hears", "deaf")):
        cands = {n: {"deaf": deaf, "hears": hears}[n] for n in order}
        winner, scores, _ = selection.select(cands)
        assert winner == "hears"
        assert scores == pytest.approx({"hears": 4.0, "deaf": 5.0})
    # A candidate 10 % better in direction but twice the rotational error loses.
    assert selection.select({"sharp": dict(deaf, direction_mae_deg=18.0),
                             "hears": hears})[0] == "hears"


def test_candidate_missing_a_metric_cannot_win():
    good = {"detection_accuracy": 0.9, "direction_mae_deg": 40.0, "magnitude_rmse_mm": 2.0}
    blind = {"detection_accuracy": 0.99}
    assert selection.select({"blind": blind, "good": good})[0] == "good"


def test_plan_skips_pretrained_recipes_without_a_robot_set():
    msgs = []
    cands, skipped = recipes.plan(recipes.RECIPES, (0, 3), have_pretrain=False,
                                  log=msgs.append)
    assert [c.name for c in cands] == ["scratch_s0", "scratch_s3", "svm", "svm_logmel",
                                       "scratch_s0_uncalibrated", "scratch_s3_uncalibrated",
                                       "svm_uncalibrated", "svm_logmel_uncalibrated"]
    assert {s["name"] for s in skipped} == {"frozen", "partial", "unfrozen"}
    assert all("--pretrain-dataset" in m for m in msgs) and len(msgs) == 3
    default, _ = recipes.plan(have_pretrain=True)
    assert [c.name for c in default] == ["unfrozen", "scratch_s0", "scratch_s0_uncalibrated",
                                         "svm", "svm_uncalibrated", "svm_logmel",
                                         "svm_logmel_uncalibrated"]
    assert [c.calibrated for c in default] == [True, True, False, True, False, True, False]
    assert [c.is_svm for c in default] == [False, False, False, True, True, True, True]
    cands, skipped = recipes.plan(recipes.RECIPES[:5], (0,), have_pretrain=True)
    assert [c.name for c in cands] == ["frozen", "partial", "unfrozen", "scratch_s0", "svm"]
    assert not skipped
    # With --calibration off the uncalibrated variants would train the same thing twice.
    cands, skipped = recipes.plan(have_pretrain=False, calibration="off", log=msgs.append)
    assert [c.name for c in cands] == ["scratch_s0", "svm", "svm_logmel"]
    assert {s["name"] for s in skipped} == {"unfrozen", "scratch_uncalibrated",
                                            "svm_uncalibrated", "svm_logmel_uncalibrated"}
    with pytest.raises(ValueError, match="unknown recipe"):
        recipes.plan(["frozen", "bogus"], (0,), True)
    with pytest.raises(ValueError, match="no recipe left"):
        recipes.plan(["frozen"], (0,), False, log=lambda m: None)


class _CurveJob:
    """A job whose validation direction error falls with its training time along a known
    curve, ``floor + 60 / (1 + rate * t)``, on the allocator's clock."""

    def __init__(self, clock, floor, rate, epochs_s=5.0):
        self.clock, self.floor, self.rate, self.epochs_s = clock, floor, rate, epochs_s
        self.train_time_s = 0.0
        self.slices = []
        self.done = False

    def advance(self, seconds):
        spent = max(self.epochs_s, self.epochs_s * -(-seconds // self.epochs_s))  # whole epochs
        self.slices.append(seconds)
        self.train_time_s += spent
        self.clock.t += spent

    def val_metrics(self):
        d = self.floor + 60.0 / (1.0 + self.rate * self.train_time_s)
        return {"detection_accuracy": 0.95, "direction_mae_deg": d, "magnitude_rmse_mm": 1.0}

    def result(self, stop_reason="time_budget"):
        return stop_reason


@pytest.mark.parametrize("good_first", [True, False])
def test_successive_halving_finds_the_better_job_and_stops_the_other_early(good_first):
    """The answer known: ``good`` learns faster and to a lower floor. The allocator must keep
    it, stop ``poor`` after the first round, and give ``good`` the rest of the budget."""
    clock = FakeClock()
    good, poor = _CurveJob(clock, 10.0, 0.1), _CurveJob(clock, 20.0, 0.05)
    jobs = dict([("good", good), ("poor", poor)] if good_first
                else [("poor", poor), ("good", good)])
    budget = 600.0
    halve = allocation.successive_halving
    winner, rounds, rest = halve(jobs, budget, clock=clock, log=lambda m: None)
    assert winner == "good" and [r["name"] for r in rest] == ["good"]
    assert len(rounds) == 1 and rounds[0]["stopped"] == ["poor"]
    assert rounds[0]["kept"] == ["good"]
    slice_s = allocation.EARLY_FRACTION * budget / 2
    assert poor.slices == [slice_s] and poor.train_time_s <= slice_s + poor.epochs_s
    assert good.train_time_s >= budget - poor.train_time_s - 1e-9  # the rest went to good
    assert clock.t <= budget + good.epochs_s                       # within the budget


def test_time_an_early_stopped_survivor_leaves_goes_to_the_next_best():
    clock = FakeClock()
    good, poor = _CurveJob(clock, 10.0, 0.1), _CurveJob(clock, 20.0, 0.05)
    orig = good.advance

    def advance_then_stop(seconds):      # the survivor early-stops after 50 s more
        orig(min(seconds, 50.0) if good.train_time_s >= 150.0 else seconds)
        good.done = good.train_time_s >= 200.0
    good.advance = advance_then_stop
    winner, rounds, rest = allocation.successive_halving(
        {"good": good, "poor": poor}, 600.0, clock=clock, log=lambda m: None)
    assert winner == "good" and good.done
    assert [r["name"] for r in rest] == ["good", "poor"]
    assert rest[1]["seconds"] >= 600.0 - 300.0 - 50.0 - 1e-9      # the rest went to poor
    assert clock.t <= 600.0 + poor.epochs_s


def test_successive_halving_halves_each_round_and_scores_beside_the_finished():
    clock = FakeClock()
    curves = {"a": (30.0, 0.1), "b": (12.0, 0.1), "c": (25.0, 0.1), "d": (11.0, 0.05)}
    jobs = {n: _CurveJob(clock, f, r) for n, (f, r) in curves.items()}
    halve = allocation.successive_halving
    winner, rounds, _ = halve(jobs, 800.0, clock=clock, log=lambda m: None)
    assert [len(r["scores"]) for r in rounds] == [4, 2]      # 4 -> 2 -> 1
    assert rounds[0]["kept"] == ["b", "d"] and winner == "b"
    assert rounds[1]["stopped"] == ["d"]
    # A finished candidate (the SVM) is scored beside the jobs: the scores are relative to
    # the best of all, and it is never dropped or trained (it is not a job).
    svm = {"detection_accuracy": 0.99, "direction_mae_deg": 5.0, "magnitude_rmse_mm": 0.5}
    clock2 = FakeClock()
    jobs2 = {n: _CurveJob(clock2, f, r) for n, (f, r) in curves.items()}
    _, rounds2, _ = halve(jobs2, 800.0, others={"svm": svm}, clock=clock2,
                          log=lambda m: None)
    assert "svm" not in rounds2[0]["scores"]
    assert rounds2[0]["scores"]["b"] > rounds[0]["scores"]["b"]
    # One job: no round, it gets the whole budget.
    clock3 = FakeClock()
    only = _CurveJob(clock3, 10.0, 0.1)
    assert halve({"x": only}, 100.0, clock=clock3, log=lambda m: None) == (
        "x", [], [{"name": "x", "seconds": 100.0}])
    assert only.train_time_s == pytest.approx(100.0)
    with pytest.raises(ValueError, match="no job"):
        halve({}, 10.0)


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
        return aslip_cnn_fit.train_cnn(ds, c, feature_config=fcfg, **kw)

    def untrained(c):
        return aslip_cnn_fit.train_cnn(ds, dataclasses.replace(c, lr=0.0, epochs=1),
                                       feature_config=fcfg, **kw)

    for order in ((("dead", untrained), ("live", trained)),
                  (("live", trained), ("dead", untrained))):
        cands = [recipes.Candidate(n, "scratch", 0, lambda c, f=f: allocation.OneShot(f, c))
                 for n, f in order]
        res = recipes.train_selected(ds, _cfg(epochs=3), recipes=cands, budget_s=120,
                                     log=lambda m: None)
        sel = res.meta["provenance"]["selection"]
        assert sel["winner"] == "live" and res.meta["provenance"]["recipe"] == "live"
        scores = {r["name"]: r["score"] for r in sel["candidates"]}
        assert scores["live"] < scores["dead"]
        # What the choice is worth: intervals over the validation trials, and the lead.
        w = sel["worth"]
        assert w["runner_up"] == "dead" and w["told_apart"]
        lo, hi = w["winner_ci"]["direction_mae_deg"]
        assert lo <= w["winner"]["direction_mae_deg"] <= hi
        assert w["score_difference"]["ci"][1] < 0
        assert "validation trials (95 % intervals" in recipes.comparison_markdown(sel)
        # Per output: why the winner keeps it, or which candidate gives it instead.
        kept = {r: dict(row, **{"from": "live", "why": f"{r} reason"})
                for r, row in sel["outputs"].items()}
        assert set(kept) >= {"detection", "speed", "direction"}
        md = recipes.comparison_markdown(dict(sel, outputs=kept))
        assert "Each output stays the winner's: detection: detection reason;" in md
        moved = dict(kept, speed=dict(kept["speed"], **{"from": "dead"}))
        md = recipes.comparison_markdown(dict(sel, outputs=moved))
        assert "speed from **dead** (speed reason)" in md and "stays the winner's" not in md


class _ValSet:
    """The few fields of a WindowSet that selection reads: trials, labels (planar only: no
    angular label), window length."""

    window_s = 0.2

    def __init__(self, n_trials=6, per_trial=40):
        n = n_trials * per_trial
        self.windows = {"trial": np.repeat(np.arange(n_trials), per_trial)}
        self._v = np.tile([0.01, 0.0], (n, 1))

    def velocity(self, idx):
        return self._v[idx]

    def slip(self, idx):
        return np.ones(len(idx), bool)

    def has_angular(self, idx=None):
        return False


def _result(angles_deg):
    a = np.radians(np.asarray(angles_deg, float))
    v = 0.01 * np.stack([np.cos(a), np.sin(a)], axis=1)
    return train_config.TrainResult(meta={}, tensors={}, history=[],
                                    val_pred={"prob": np.full(a.size, 0.9), "v": v})


def test_an_uncalibrated_winner_within_noise_gives_way_to_its_calibrated_twin():
    ds = _ValSet()
    va = np.arange(len(ds.windows["trial"]))
    rng = np.random.default_rng(0)
    cal = _result(rng.normal(0, 25, va.size))
    near = _result(rng.normal(0, 24, va.size))           # a hair better: noise
    keep, why = recipes.prefer_calibrated(ds, va, {"scratch_s0": cal,
                                                   "scratch_s0_uncalibrated": near},
                                          "scratch_s0_uncalibrated")
    assert keep == "scratch_s0" and "cannot be told apart" in why
    clear = _result(rng.normal(0, 3, va.size))           # better on every trial
    keep, why = recipes.prefer_calibrated(ds, va, {"scratch_s0": cal,
                                                   "scratch_s0_uncalibrated": clear},
                                          "scratch_s0_uncalibrated")
    assert keep == "scratch_s0_uncalibrated" and why is None
    # A calibrated winner, or an uncalibrated one without its twin, stands as chosen.
    assert recipes.prefer_calibrated(ds, va, {"svm": cal}, "svm") == ("svm", None)
    assert recipes.prefer_calibrated(ds, va, {"svm_uncalibrated": near},
                                     "svm_uncalibrated") == ("svm_uncalibrated", None)


def test_worth_says_when_the_two_cannot_be_told_apart():
    w = {"n_trials": 3, "winner": {"detection_accuracy": 0.95, "direction_mae_deg": 20.0,
                                   "magnitude_rmse_mm": 1.0},
         "winner_ci": {"detection_accuracy": (0.9, 0.97), "direction_mae_deg": (15.0, 26.0),
                       "magnitude_rmse_mm": (0.8, 1.3)},
         "runner_up": "svm", "score_difference": {"estimate": -0.1, "ci": (-0.4, 0.2)},
         "told_apart": False}
    line = selection.worth_line(w)
    assert "20.0 [15.0, 26.0]" in line and "cannot be told apart" in line
    assert "better on these trials" in selection.worth_line(
        dict(w, score_difference={"estimate": -0.3, "ci": (-0.5, -0.1)}, told_apart=True))
    assert selection.worth_line({}) == ""


def test_validation_never_shares_a_trial_with_training(data, tmp_path):
    """With fewer than K_FOLD_BELOW validation trials (2 of this dataset's 14) the choice is
    made on folds by trial: each fold's models validate on trials they never trained on,
    the folds pool every training and validation trial of the split and no test trial, the
    candidates are scored on those pooled windows and the final model trains on them all."""
    root, robot, ext = data
    out = tmp_path / "auto.pt"
    assert cli(["--dataset", str(ext), "--pretrain-dataset", str(robot), "--out", str(out),
                "--recipes", "frozen,scratch,svm", "--seeds", "0", "--epochs", "3",
                "--time-budget", "120", "--keep-candidates"] + SMALL) == 0
    kept = sorted(p.name for p in (tmp_path / "auto.pt.candidates").iterdir())
    assert kept == ["frozen.pt", "scratch_s0.pt", "svm.pt"]
    sel = json.loads((tmp_path / "auto.pt.selection.json").read_text())
    assert (tmp_path / "auto.pt.selection.md").read_text().count("| ") > 3
    ds = open_dataset(ext)
    splits = dict(zip((t["id"] for t in ds.trials), trial_splits(ds)))
    assert list(splits.values()).count("val") < folds.K_FOLD_BELOW
    fold_trials = [set(f) for f in sel["folds"]["trials"]]
    assert len(fold_trials) == min(folds.N_FOLDS, len(splits) // 2)
    assert all(a.isdisjoint(b) for i, a in enumerate(fold_trials) for b in fold_trials[i + 1:])
    dev = {t for t, s in splits.items() if s in ("train", "val")}
    assert set().union(*fold_trials) == dev == set(sel["val_trials"]) == set(sel["train_trials"])
    assert not dev & set(sel["test_trials_untouched"])
    # The slip directions the final model learns from: every trial of the folds.
    on = np.isin(np.asarray(ds.windows["trial"]),
                 [k for k, x in enumerate(ds.trials) if x["id"] in dev])
    idx = np.flatnonzero(on)
    want = coverage.direction_coverage(ds.velocity(idx), ds.slip(idx), ds.hop_s)
    assert sel["direction_coverage"] == json.loads(json.dumps(want))
    assert coverage.coverage_text(want) in (tmp_path / "auto.pt.selection.md").read_text()
    cfg = _cfg()
    ids = [t["id"] for t in ds.trials]
    for f in fold_trials:                 # each fold model: its validation trials unseen
        tr, va = split_windows(ds, dataclasses.replace(
            cfg, val_trials=tuple(ids.index(t) for t in f)))
        tr_t = {ids[k] for k in np.unique(np.asarray(ds.windows["trial"])[tr])}
        va_t = {ids[k] for k in np.unique(np.asarray(ds.windows["trial"])[va])}
        assert va_t == f and tr_t == dev - f
    assert [r["name"] for r in sel["candidates"]] == ["svm", "frozen", "scratch_s0"]
    assert all(r["status"] == "ok" for r in sel["candidates"])
    ck = load_checkpoint(out)
    prov = ck.meta["provenance"]
    assert prov["selection"]["winner"] == prov["recipe"] == sel["winner"]
    trial_of = np.asarray(ds.windows["trial"])
    n_pooled = int(np.isin(trial_of, [k for k, x in enumerate(ds.trials)
                                      if x["id"] in dev]).sum())
    for name in ("frozen", "scratch_s0", "svm"):     # what each candidate was scored on
        t = load_checkpoint(tmp_path / "auto.pt.candidates" / f"{name}.pt").meta["provenance"]
        assert t["metrics"]["val"]["n_windows"] == n_pooled
        # The fold models validated on every pooled window; a final model on none.
        refitted = t["training"].get("refit", False)
        assert t["training"]["n_val_windows"] == (0 if refitted else n_pooled)
        assert refitted == (name == sel["winner"])
        assert [set(f) for f in t["folds"]["trials"]] == fold_trials
    # The chosen model itself: trained on every pooled trial, without a validation split.
    assert prov["training"]["refit"] is True and prov["folds"]["trials"]
    assert ck.meta["train_config"]["val_trials"] == []
    assert sel["winner"] in sel["reason"] and sel["criterion"] == selection.CRITERION
    assert all(t.device.type == "cpu" for t in ck.tensors.values())


def test_enough_validation_trials_keep_the_one_split(data, monkeypatch):
    """At K_FOLD_BELOW validation trials or more the split's own validation trials choose."""
    _, _, ext = data
    ds = open_dataset(ext)
    n_val = trial_splits(ds).count("val")
    assert folds.trial_folds(ds, _cfg()) is not None
    monkeypatch.setattr(folds, "K_FOLD_BELOW", n_val)
    assert folds.trial_folds(ds, _cfg()) is None
    tr, va, none = recipes.validation_split(ds, _cfg())
    assert none is None and np.array_equal(va, split_windows(ds, _cfg())[1])


def test_selection_never_reads_a_test_trial(data, tmp_path):
    """The same dataset with every test trial's audio replaced by NaN gives the same choice
    and the same validation scores: selection reads training and validation trials only."""
    import shutil
    _, _, ext = data
    nan_root = tmp_path / "nan_test"
    shutil.copytree(ext, nan_root, ignore=shutil.ignore_patterns(".feature_cache"))
    ds_nan = open_dataset(nan_root)
    test_idx = ds_nan.dataset.select("test", seed=0)
    test_trials = np.unique(np.asarray(ds_nan.windows["trial"])[test_idx])
    assert test_trials.size >= 1
    for k in test_trials:
        path = nan_root / ds_nan.trials[int(k)]["file"]
        audio = np.load(path)
        np.save(path, np.full_like(audio, np.nan))
    ds_nan = open_dataset(nan_root)
    assert np.isnan(ds_nan.window_audio(test_idx[:5])).all()
    from aslip_ros.learn.features import FeatureConfig
    # The calibrated candidates, CNN and SVM: the calibration fit is what could read the
    # test trials' audio (the uncalibrated twins read less).
    kw = dict(recipes=["scratch", "svm"], budget_s=600,
              feature_config=FeatureConfig(n_mels=32), model_options=SMALL_MODEL,
              log=lambda m: None)
    cfg = _cfg(epochs=3, calibration="background")
    sels = [recipes.train_selected(d, cfg, **kw).meta["provenance"]["selection"]
            for d in (open_dataset(ext), ds_nan)]
    assert sels[0]["winner"] == sels[1]["winner"]
    scores = [{r["name"]: r["score"] for r in s["candidates"]} for s in sels]
    assert scores[0].keys() == scores[1].keys() and len(scores[0]) == 2
    for name, value in scores[0].items():
        assert np.isfinite(value) and scores[1][name] == pytest.approx(value, rel=1e-6)
    assert sels[1]["test_trials_untouched"] == [ds_nan.trials[int(k)]["id"]
                                                for k in test_trials]


def test_too_few_trials_gives_the_clear_message(tmp_path, capsys):
    small = make_synthetic_dataset(tmp_path / "few", n_trials=3, induced="external", seed=3)
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


def test_the_default_device_is_auto_and_the_checkpoint_names_the_one_used(data, tmp_path,
                                                                          monkeypatch):
    """No --device: a GPU where torch sees one (#38), here the CPU, which provenance names."""
    _, _, ext = data
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert train_config.TrainConfig().device == "auto"
    out = tmp_path / "a.pt"
    assert cli(["--dataset", str(ext), "--stage", "scratch", "--out", str(out),
                "--epochs", "1"] + SMALL) == 0
    ck = load_checkpoint(out)
    assert ck.meta["provenance"]["device"] == "cpu"
    assert ck.meta["train_config"]["device"] == "auto"


def test_encoder_learning_rate_groups():
    from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet
    from aslip_ros.learn.models.aslip_cnn_fit import param_groups
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
    res = aslip_cnn_fit.train_cnn(ds, cfg, init=load_checkpoint(pre), log=lambda m: None)
    before = load_checkpoint(pre).tensors
    moved = {k for k in res.tensors if not torch.equal(before[k], res.tensors[k])}
    assert any(k.startswith("encoder.conv1d.") and k.endswith("weight") for k in moved)
    assert not any(k.startswith(("encoder.conv2d.", "encoder.attention.")) for k in moved)
    assert not any("running_" in k for k in moved)
    assert np.isfinite(res.meta["provenance"]["metrics"]["val"]["direction_mae_deg"])
