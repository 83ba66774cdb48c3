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
                                  "plain_svm", "recipe+plain_svm"]
    for name, r in cell["rows"].items():
        m = r["metrics"]
        assert m["n_trials"] == 6 and m["n_windows"] > 0
        for key, _, _ in magnitude.KEYS:
            lo, hi = m[key + "_ci"]
            assert lo <= m[key] + 1e-9 and m[key] <= hi + 1e-9, (name, key)
        assert ("minus_recipe" in r) == (name != "recipe")
    md = (cfg.out / "magnitude.md").read_text()
    assert "a -> b, seed 0 (6 test trials)" in md and "| plain_svm |" in md
    assert set(saved["verdicts"]) == {"natural_prior", "mag_x4", "plain_cnn", "plain_svm",
                                      "recipe+plain_svm"}


def test_a_blend_is_the_mean_of_its_parts_outputs():
    trial = np.array([0, 0, 1])
    v_true = np.array([[0.01, 0.0], [0.0, 0.02], [0.01, 0.01]])
    preds = {"recipe": {"prob": np.array([0.9, 0.2, 0.6]), "trial": trial,
                        "raw_velocity": np.array([[0.02, 0.0], [0.0, 0.0], [0.0, 0.01]]),
                        "true_velocity": v_true},
             "plain_svm": {"prob": np.array([0.5, 0.4, 0.6]), "trial": trial,
                           "raw_velocity": np.array([[0.0, 0.04], [0.0, 0.02], [0.0, 0.03]]),
                           "true_velocity": v_true}}
    got = magnitude.blended(preds, ("recipe", "plain_svm"))
    assert got["prob"] == pytest.approx([0.7, 0.3, 0.6])
    # Speed: the mean norm; direction: the unit vector of the sum of the parts' unit ones
    # (a part with no velocity has no say).
    r = np.sqrt(0.5)
    assert got["raw_velocity"] == pytest.approx(
        np.array([[0.03 * r, 0.03 * r], [0.0, 0.01], [0.0, 0.02]]), abs=1e-7)
    assert got["true_velocity"] is v_true
    preds["plain_svm"]["trial"] = np.array([0, 1, 1])
    with pytest.raises(ValueError, match="different windows"):
        magnitude.blended(preds, ("recipe", "plain_svm"))


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


# --- where the speed error is ------------------------------------------------------------

def _where_predictions():
    """10 trials (manifest indices 2..11, objects alternating box / can) of 30 true-slip
    windows each, 10 at each of 10, 50 and 100 mm/s, plus 5 no-slip windows per trial, in
    shuffled order; 0.2 s windows. ``recipe`` is exact below 100 mm/s and twice too fast at
    it; ``plain_svm`` is exact on box trials and 5 mm/s too slow on can trials; ``half``
    halves every speed."""
    rng = np.random.default_rng(0)
    trial = np.repeat(np.arange(2, 12), 35)
    s = np.tile(np.r_[np.repeat([0.01, 0.05, 0.1], 10), np.zeros(5)], 10)
    slip = s > 0
    order = rng.permutation(s.size)
    trial, s, slip = trial[order], s[order], slip[order]
    objects = ["box" if k % 2 == 0 else "can" for k in range(12)]
    can = np.array([objects[k] == "can" for k in trial])
    true = np.stack([s, np.zeros_like(s)], axis=1)

    def model(speed):
        return {"prob": slip.astype(float), "raw_velocity": np.stack(
                    [speed, np.zeros_like(speed)], axis=1), "true_velocity": true,
                "slip": slip, "trial": trial, "window_s": np.float64(0.2)}
    preds = {"recipe": model(np.where(s >= 0.1, 2 * s, s)),
             "plain_svm": model(np.where(can & slip, s - 0.005, s)),
             "half": model(s / 2)}
    loud = np.full(12, np.nan)
    loud[2:] = -40.0 + 3.0 * np.arange(10)       # trials 2..4 quiet, 5..7 middle, 8..11 loud
    return preds, objects, loud


def test_the_breakdown_finds_a_model_wrong_only_on_fast_windows():
    from benchmarks.magnitude_where import breakdown
    preds, objects, loud = _where_predictions()
    w = breakdown(preds, objects, loud, n_boot=50)
    assert w["n_windows"] == 300 and w["n_trials"] == 10
    lo, hi = w["speed_edges_mm_s"]
    assert 10 < lo < 50 < hi < 100
    speed = w["strata"]["speed"]
    assert list(speed) == ["slow", "middle", "fast"]
    for name in ("slow", "middle"):
        r = speed[name]["models"]["recipe"]
        assert r["rmse_mm"] == r["bias_mm"] == 0.0 and tuple(r["rmse_mm_ci"]) == (0.0, 0.0)
    fast = speed["fast"]
    assert (fast["n_trials"], fast["n_windows"]) == (10, 100)
    assert fast["mean_true_mm_s"] == pytest.approx(100.0)
    # 100 mm/s too fast over 0.2 s windows: 20 mm on every fast window.
    assert fast["models"]["recipe"]["rmse_mm"] == pytest.approx(20.0)
    assert fast["models"]["recipe"]["bias_mm"] == pytest.approx(20.0)
    # recipe - plain_svm: 20 mm against sqrt(1/2) mm (1 mm on half the trials), paired.
    est, lo, hi = fast["pair_rmse_diff_mm"]
    assert est == pytest.approx(20.0 - np.sqrt(0.5)) and lo > 0
    assert speed["slow"]["pair_rmse_diff_mm"][2] < 0


def test_the_breakdown_maps_trials_to_objects_and_loudness():
    from benchmarks.magnitude_where import breakdown
    preds, objects, loud = _where_predictions()
    w = breakdown(preds, objects, loud, n_boot=50)
    obj = w["strata"]["object"]
    assert list(obj) == ["box", "can"]
    assert obj["box"]["n_trials"] == obj["can"]["n_trials"] == 5
    svm = {k: obj[k]["models"]["plain_svm"] for k in obj}
    assert svm["box"]["rmse_mm"] == 0.0 and svm["box"]["bias_mm"] == 0.0
    # 5 mm/s too slow over 0.2 s: -1 mm on every window of a can trial.
    assert svm["can"]["rmse_mm"] == pytest.approx(1.0)
    assert svm["can"]["bias_mm"] == pytest.approx(-1.0)
    assert svm["can"]["bias_mm_ci"] == pytest.approx((-1.0, -1.0))
    assert w["loudness_edges_db"] == pytest.approx([-31.0, -22.0])
    loudness = w["strata"]["loudness"]
    assert [loudness[k]["n_trials"] for k in ("quiet", "middle", "loud")] == [3, 3, 4]
    # Fewer than MIN_TRIALS_CI trials: no interval, no paired difference.
    assert "rmse_mm_ci" not in loudness["loud"]["models"]["recipe"]
    assert "pair_rmse_diff_mm" not in loudness["loud"]


def test_the_overall_scale_and_the_oracle_scale():
    from aslip_ros.learn.metrics import compute_metrics
    from benchmarks.magnitude_where import breakdown
    preds, objects, loud = _where_predictions()
    w = breakdown(preds, objects, loud, n_boot=20)
    half = w["overall"]["half"]
    assert half["scale_ratio"] == pytest.approx(0.5)
    assert half["oracle_scale"] == pytest.approx(2.0)
    assert half["oracle_rmse_mm"] == pytest.approx(0.0, abs=1e-9)
    assert half["rank_corr"] == pytest.approx(1.0) and half["bias_mm"] < 0
    for name, p in preds.items():   # the RMSE is the benchmark table's magnitude
        m = compute_metrics(p["prob"], p["raw_velocity"], p["true_velocity"], p["slip"], 0.2)
        assert w["overall"][name]["rmse_mm"] == pytest.approx(m["magnitude_rmse_mm"])
    # A speed ranking that a scale cannot fix: the oracle does not save recipe.
    assert w["overall"]["recipe"]["oracle_rmse_mm"] > 1.0
    other = dict(preds["half"], trial=np.roll(preds["half"]["trial"], 1))
    with pytest.raises(ValueError, match="same windows"):
        breakdown(dict(preds, half=other), objects, loud, n_boot=0)


def test_the_breakdown_section_of_the_report():
    from benchmarks.magnitude_where import breakdown, where_markdown
    preds, objects, loud = _where_predictions()
    md = "\n".join(where_markdown(breakdown(preds, objects, loud, n_boot=20)))
    assert "### Where the speed error is" in md and "DIAGNOSTIC ONLY" in md
    assert "| fast (10, 100, 100.0) | 20.00 [20.00, 20.00] / +20.00 [+20.00, +20.00] |" in md
    assert "| half | " in md and "recipe - plain_svm" in md
    assert "| loud (4, 120, 53.3) | 11.55 / +6.67 |" in md


def test_trial_facts_read_the_test_dataset(datasets):
    from aslip_ros.learn.data_io import open_dataset
    from benchmarks.magnitude_where import trial_facts
    ds = open_dataset(datasets / "data" / "b")
    objects, loud = trial_facts(ds.root, [1, 3])
    assert list(objects) == [t["object"] for t in ds.trials]
    assert np.array_equal(objects[ds.windows["trial"]], ds.trial_field("object"))
    # dB re full scale, for the trials asked for only.
    assert (loud[[1, 3]] < 0).all() and np.isnan(np.delete(loud, [1, 3])).all()


def test_every_cell_reports_where_the_speed_error_is(result):
    cfg, res = result
    saved = json.loads((cfg.out / "magnitude.json").read_text())
    where = saved["cells"]["a -> b, seed 0"]["where"]
    assert list(where["overall"]) == list(saved["cells"]["a -> b, seed 0"]["rows"])
    assert set(where["strata"]) == {"object", "speed", "loudness"}
    md = (cfg.out / "magnitude.md").read_text()
    assert md.count("### Where the speed error is") == 1 and "By object" in md
