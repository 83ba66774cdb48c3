"""Choosing on folds by trial (learn/training/folds.py) where the split holds fewer than
``K_FOLD_BELOW`` validation trials."""

import copy
import dataclasses

import numpy as np
import pytest
import torch

from aslip_ros.learn.checkpoint import load_checkpoint
from aslip_ros.learn.data_io import open_dataset, trial_splits
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.metrics import compute_metrics
from aslip_ros.learn.models import aslip_cnn_fit
from aslip_ros.learn.synthetic import make_synthetic_dataset
from aslip_ros.learn.training import allocation, folds, recipes
from aslip_ros.learn.training.config import TrainConfig, TrainResult
from aslip_ros.learn.training.data import split_windows

SMALL_MODEL = dict(width=8, depth=2, temporal_channels=32, head_hidden=16)


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    root = tmp_path_factory.mktemp("folds")
    return open_dataset(make_synthetic_dataset(root / "ext", n_trials=14, induced="external",
                                               seed=2))


def _cfg(**kw):
    return TrainConfig(**{**dict(epochs=3, patience=3, threads=1, progress=False), **kw})


def test_folds_share_out_the_training_and_validation_trials_and_never_a_test_trial(ds):
    cfg = _cfg()
    got = folds.trial_folds(ds, cfg)
    splits = trial_splits(ds)
    assert splits.count("val") < folds.K_FOLD_BELOW and got is not None
    dev = {k for k, s in enumerate(splits) if s in ("train", "val")}
    flat = [t for f in got for t in f]
    assert sorted(flat) == sorted(dev) and len(got) == folds.N_FOLDS
    assert max(map(len, got)) - min(map(len, got)) <= 2       # about equal folds
    pooled, vas = folds.fold_windows(ds, cfg, got)
    assert np.array_equal(pooled, np.sort(np.concatenate(vas)))
    trial = np.asarray(ds.windows["trial"])
    assert set(np.unique(trial[pooled]).tolist()) == dev
    assert folds.trial_folds(ds, cfg) == got                    # deterministic by split seed


def test_cv_epochs_is_the_folds_mean_best_epoch_counted_from_one():
    assert folds.cv_epochs([3, 5, 7]) == 6
    assert folds.cv_epochs([0, None, 2]) == 2
    assert folds.cv_epochs([None, None]) is None


class _Known:
    """A trainer whose predictions are known: ``noise`` (m/s) on the true velocity of every
    validation window, except that ``memorised`` trials are answered exactly: a model that
    learned those trials' own answers rather than the slip's."""

    def __init__(self, ds, noise, memorised=()):
        self.ds, self.noise, self.memorised = ds, noise, set(memorised)
        self.configs = []

    def __call__(self, c):
        self.configs.append(c)
        ds = self.ds
        tr, va = split_windows(ds, c)
        meta = {"provenance": {"training": {"best_epoch": 4}}, "model_type": "known"}
        if not va.size:
            return TrainResult(meta=meta, tensors={}, history=[])
        rng = np.random.default_rng(len(self.configs))
        v = ds.velocity(va).astype(float)
        trial = np.asarray(ds.windows["trial"])[va]
        noisy = ~np.isin(trial, list(self.memorised))
        v[noisy] += rng.normal(0.0, self.noise, (int(noisy.sum()), 2))
        prob = np.where(ds.slip(va), 0.9, 0.1)
        meta["provenance"]["metrics"] = {"val": compute_metrics(
            prob, v, ds.velocity(va), ds.slip(va), ds.window_s)}
        return TrainResult(meta=meta, tensors={}, history=[],
                           val_pred={"prob": prob, "v": v, "w": None})


def _candidates(trainers):
    return [recipes.Candidate(n, "scratch", 0, lambda c, t=t: allocation.OneShot(t, c))
            for n, t in trainers.items()]


def test_folds_choose_the_model_that_holds_on_every_trial_not_the_one_that_fits_the_split(
        ds, monkeypatch):
    """The answer known: ``memoriser`` is exact on the split's validation trials and poor
    elsewhere, ``steady`` is fair everywhere. One split of 2 validation trials picks the
    memoriser; folds over every training and validation trial pick ``steady``, and its final
    model trains on all of them, for the folds' epochs, without a validation split."""
    split_val = {k for k, s in enumerate(trial_splits(ds)) if s == "val"}
    picks = {}
    for mode, below in (("split", 0), ("folds", folds.K_FOLD_BELOW)):
        monkeypatch.setattr(folds, "K_FOLD_BELOW", below)
        steady, memo = _Known(ds, 0.004), _Known(ds, 0.03, memorised=split_val)
        res = recipes.train_selected(
            ds, _cfg(), recipes=_candidates({"memoriser": memo, "steady": steady}),
            budget_s=60, log=lambda m: None)
        sel = res.meta["provenance"]["selection"]
        picks[mode] = sel["winner"]
        if mode == "folds":
            assert sel["folds"]["n"] == folds.N_FOLDS
            final = steady.configs[-1]
            assert final.val_trials == () and final.epochs == 5        # best epoch 4, +1
            assert len(steady.configs) == folds.N_FOLDS + 1           # the folds, the final
            assert [c.val_trials for c in memo.configs] == [tuple(f) for f in
                                                            folds.trial_folds(ds, _cfg())]
            assert res.meta["provenance"]["training"]["refit"] is True
            assert res.meta["provenance"]["metrics"]["val"]["n_windows"] == \
                folds.fold_windows(ds, _cfg(), folds.trial_folds(ds, _cfg()))[0].size
            assert 0.0 < res.meta["threshold"] < 1.0                # fitted on the pooled
    assert picks == {"split": "memoriser", "folds": "steady"}


def test_a_cnn_without_validation_trains_its_epochs_and_keeps_the_last(ds, tmp_path):
    """The final model of a cross-validated choice: no validation windows, so neither early
    stopping nor a best epoch; ``epochs`` ends it and, without ``average_last``, the last
    epoch's weights are kept."""
    cfg = _cfg(epochs=2, patience=1, val_trials=(), average_last=0.0)
    tr, va = split_windows(ds, cfg)
    assert va.size == 0
    job = aslip_cnn_fit.scratch(ds, cfg, feature_config=FeatureConfig(n_mels=32),
                                model_options=SMALL_MODEL, log=lambda m: None)
    job.advance(1e9)
    res = job.result()
    assert job.done and len(res.history) == 2 and res.history[-1]["val_loss"] is None
    prov = res.meta["provenance"]["training"]
    assert prov["stop_reason"] == "max_epochs" and prov["best_epoch"] == 1
    assert res.val_pred is None and "output_calibration" not in res.meta
    last = job.model.state_dict()
    assert all(torch.equal(res.tensors[k], last[k].cpu()) for k in last)
    assert prov["n_train_windows"] == tr.size
    # Its checkpoint is strict JSON and loads (a NaN loss once refused to be written).
    path = res.save(tmp_path / "final.pt")
    assert load_checkpoint(path).meta["provenance"]["training"]["best_epoch"] == 1
    with pytest.raises(ValueError, match="held out"):
        split_windows(ds, dataclasses.replace(cfg, val_trials=tuple(range(len(ds.trials)))))


def test_a_cnn_without_validation_averages_its_last_epochs_weights_and_resumes_the_mean(ds):
    """``average_last``: the final model of a cross-validated choice holds the mean of its
    last epochs' weights (here the last 2 of 4), BatchNorm statistics included; a run paused
    inside the averaged epochs and resumed from its state ends with the same mean."""
    cfg = _cfg(epochs=4, patience=1, val_trials=(), average_last=0.5)

    def job():
        return aslip_cnn_fit.scratch(ds, cfg, feature_config=FeatureConfig(n_mels=32),
                                     model_options=SMALL_MODEL, log=lambda m: None)

    run, seen = job(), []
    for _ in range(4):
        run.advance(0.0)                                    # one epoch a slice
        seen.append({k: v.detach().clone() for k, v in run.model.state_dict().items()})
        if len(seen) == 3:
            paused = copy.deepcopy(run.run.state_dict())
    res = run.result()
    floats = [k for k, v in seen[-1].items() if v.is_floating_point()]
    assert any(not torch.equal(seen[2][k], seen[3][k]) for k in floats)     # it trained
    for k in floats:
        torch.testing.assert_close(res.tensors[k], ((seen[2][k] + seen[3][k]) / 2).cpu())
    assert res.meta["provenance"]["training"]["best_epoch"] == 3
    again = job()
    again.run.load_state_dict(paused)
    again.advance(0.0)
    resumed = again.result()
    for k in floats:
        torch.testing.assert_close(resumed.tensors[k], res.tensors[k])
    with pytest.raises(ValueError, match="average_last"):
        _cfg(average_last=1.5)
