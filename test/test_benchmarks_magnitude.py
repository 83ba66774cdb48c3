"""The one-cause-at-a-time benchmark on tiny synthetic datasets (plumbing, not accuracy)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from benchmarks import magnitude


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    root = tmp_path_factory.mktemp("magnitude")
    make_synthetic_dataset(root / "data" / "a", n_trials=10, duration_s=2.0, seed=1)
    make_synthetic_dataset(root / "data" / "b", n_trials=6, duration_s=2.0, seed=2,
                           coupling_db=3.0)
    return root


@pytest.fixture(scope="module")
def result(datasets):
    cfg = magnitude.MagnitudeConfig(
        out=datasets / "out", data=datasets / "data", cells=(("a", "b"),),
        variants=("recipe", "natural_prior", "mag_x4"), epochs=2, patience=2, n_boot=30,
        plain_epochs=1, min_test_trials=4)
    return cfg, magnitude.run(cfg, log=lambda m: None)


def test_every_variant_and_baseline_is_scored_on_all_held_out_trials(result):
    cfg, res = result
    saved = json.loads((cfg.out / "magnitude.json").read_text())
    cell = saved["cells"]["a -> b, seed 0"]
    assert cell["n_trials"] == 6
    assert list(cell["rows"]) == ["recipe", "natural_prior", "mag_x4", "plain_cnn",
                                  "plain_svm"]
    for name, r in cell["rows"].items():
        m = r["metrics"]
        assert m["n_trials"] == 6 and m["n_windows"] > 0
        for key, _, _ in magnitude.KEYS:
            lo, hi = m[key + "_ci"]
            assert lo <= m[key] + 1e-9 and m[key] <= hi + 1e-9, (name, key)
        assert ("minus_recipe" in r) == (name != "recipe")
    md = (cfg.out / "magnitude.md").read_text()
    assert "a -> b, seed 0 (6 test trials)" in md and "| plain_svm |" in md
    assert set(saved["verdicts"]) == {"natural_prior", "mag_x4", "plain_cnn", "plain_svm"}


def test_each_variant_trains_with_its_one_change(result):
    from aslip_ros.learn.checkpoint import load_checkpoint
    cfg, _ = result
    meta = {v: load_checkpoint(cfg.cache / "a" / "seed0" / f"{v}.pt").meta
            for v in ("recipe", "natural_prior", "mag_x4")}
    assert meta["recipe"]["loss_weights"]["mag"] == 0.5
    assert meta["mag_x4"]["loss_weights"]["mag"] == 2.0
    assert meta["mag_x4"]["train_config"] == meta["recipe"]["train_config"]
    nat, rec = meta["natural_prior"]["train_config"], meta["recipe"]["train_config"]
    assert nat["noslip_ratio"] == 1000.0 and rec["noslip_ratio"] == 1.0
    assert nat["calibration"] == rec["calibration"] == "off"
    # Larger epochs get fewer of them: about the same number of optimiser steps.
    assert nat["epochs"] <= rec["epochs"]


def test_fewer_epochs_for_a_variant_with_larger_epochs():
    cfg = magnitude.MagnitudeConfig(epochs=60, patience=30)
    rec = magnitude._train_config(cfg, "recipe", 0, neg_per_pos=3.0)
    nat = magnitude._train_config(cfg, "natural_prior", 0, neg_per_pos=3.0)
    assert (rec.epochs, rec.patience, rec.noslip_ratio) == (60, 30, 1.0)
    assert (nat.epochs, nat.patience) == (30, 15)   # 4 windows per slip window instead of 2


def test_a_cached_variant_is_not_retrained(result):
    cfg, _ = result
    ckpt = cfg.cache / "a" / "seed0" / "mag_x4.pt"
    before = ckpt.stat().st_mtime_ns
    magnitude.run(cfg, log=lambda m: None)
    assert ckpt.stat().st_mtime_ns == before


def test_paired_difference_of_a_model_with_itself_is_zero(result):
    cfg, _ = result
    p = magnitude._predictions(cfg.cache / "a" / "seed0" / "recipe.pred-b.npz")
    for est, lo, hi in magnitude.paired(cfg, p, p).values():
        assert est == lo == hi == 0.0
    other = dict(p, trial=np.roll(p["trial"], 1))
    with pytest.raises(ValueError):
        magnitude.paired(cfg, p, other)


def test_too_few_held_out_trials_is_an_error(datasets):
    cfg = magnitude.MagnitudeConfig(
        out=datasets / "few", data=datasets / "data", cells=(("a", "b"),),
        variants=("recipe",), baselines=(), epochs=1, n_boot=10, min_test_trials=20)
    with pytest.raises(ValueError, match="fewer than 20"):
        magnitude.run(cfg, log=lambda m: None)
    missing = magnitude.MagnitudeConfig(out=datasets / "few", data=datasets / "data",
                                        cells=(("a", "nope"),), variants=("recipe",))
    with pytest.raises(FileNotFoundError):
        magnitude.run(missing, log=lambda m: None)


def test_verdicts_count_cells_whose_interval_excludes_zero():
    cells = {"x": {"rows": {"v": {"minus_recipe": {"detection_accuracy": (2.0, 1.0, 3.0),
                                                   "magnitude_rmse_mm": (-0.1, -0.3, 0.1)}}}},
             "y": {"rows": {"v": {"minus_recipe": {"detection_accuracy": (-2.0, -3.0, -1.0),
                                                   "magnitude_rmse_mm": (-0.2, -0.3, -0.1)}}}}}
    v = magnitude.verdicts(cells)["v"]
    assert v["detection_accuracy"] == {"better": 1, "worse": 1, "cells": 2}
    assert v["magnitude_rmse_mm"] == {"better": 1, "worse": 0, "cells": 2}


def test_cli():
    p = argparse.ArgumentParser()
    magnitude.add_arguments(p)
    cfg = magnitude.config_from_args(p.parse_args(["--cells", "x:y,y:z", "--seeds", "0,1",
                                                   "--variants", "recipe,mag_x4"]))
    assert cfg.cells == (("x", "y"), ("y", "z")) and cfg.seeds == (0, 1)
    assert cfg.variants == ("recipe", "mag_x4")
    for bad in (["--cells", "x:x"], ["--cells", "x"], ["--variants", "nope"]):
        with pytest.raises(ValueError):
            magnitude.config_from_args(p.parse_args(bad))
    assert magnitude.main(["--cells", "x:x"]) == 2
