"""The transfer protocol end to end on tiny synthetic datasets (plumbing, not accuracy), its
table's "cannot be told apart" marks, and the lab-motion-capture scene variant."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks import transfer


def test_best_and_ties_follow_the_intervals():
    rows = {"a": {"direction_mae_deg": 10.0, "direction_mae_deg_ci": (8.0, 12.0)},
            "b": {"direction_mae_deg": 11.0, "direction_mae_deg_ci": (11.5, 13.0)},
            "c": {"direction_mae_deg": 20.0, "direction_mae_deg_ci": (18.0, 22.0)},
            "d": {"direction_mae_deg": None}}
    assert transfer.best_and_ties(rows, "direction_mae_deg") == ("a", {"b"})
    det = {"a": {"detection_accuracy": 0.9, "detection_accuracy_ci": (0.88, 0.92)},
           "b": {"detection_accuracy": 0.95, "detection_accuracy_ci": (0.94, 0.96)}}
    assert transfer.best_and_ties(det, "detection_accuracy") == ("b", set())


def fake_scenes(tmp_path, monkeypatch, n_trials=20):
    """Tiny synthetic datasets instead of simulated scenes; records what was asked for."""
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    asked = []

    def fake_scene(cfg, scene, log, held_out=False):
        asked.append((scene, held_out))
        seed = transfer.SCENE_SEED[scene] // 1000 + (77 if held_out else 0)
        name = scene + ("-held-out" if held_out else "")
        return make_synthetic_dataset(tmp_path / "ds" / name, n_trials=n_trials, duration_s=2.0,
                                      seed=seed, coupling_db=0.0 if scene == "default" else 3.0,
                                      background=0.05)
    monkeypatch.setattr(transfer, "scene_dataset", fake_scene)
    return asked


def test_protocol_on_synthetic_scenes(tmp_path, monkeypatch):
    asked = fake_scenes(tmp_path, monkeypatch)
    cfg = transfer.TransferConfig(out=tmp_path / "out", data=tmp_path / "data",
                                  test_on=("default", "coupling"),
                                  methods=("paper_svm", "paper_svm_uncalibrated", "plain_svm"),
                                  n_boot=20, progress=False)
    res = transfer.run_protocol(cfg, log=lambda s: None)
    assert set(res["cells"]) == {"default -> default", "default -> coupling"}
    for rows in res["cells"].values():
        assert set(rows) == set(cfg.methods)
        for r in rows.values():
            assert 0.0 <= r["detection_accuracy"] <= 1.0
            lo, hi = r["detection_accuracy_ci"]
            assert lo <= hi
    # Every scene is tested on all its trials; the training scene on a fresh draw of it, not
    # on the few trials its own split keeps back.
    assert ("default", True) in asked and ("coupling", True) not in asked
    for cell in res["cells"].values():
        assert cell["plain_svm"]["n_trials"] == 20
    saved = json.loads((cfg.out / "transfer.json").read_text())
    assert saved["cells"].keys() == res["cells"].keys()
    md = (cfg.out / "transfer.md").read_text()
    assert "## default -> coupling (20 test trials)" in md and "**" in md
    assert "## default -> default (fresh draw of the training scene, 20 test trials)" in md
    # Where each method fails in direction: its error per true slip direction, per cell.
    assert set(saved["per_direction"]) == set(res["cells"])
    for by_method in saved["per_direction"].values():
        assert set(by_method) == set(cfg.methods)
        for d in by_method.values():
            assert len(d) == 8 and all(v is None or 0 <= v <= 180 for v in d.values())
    assert md.count("Direction MAE (deg) by true slip direction") == 2
    assert saved["trial_identity"] == {}       # only a one_sided -> one_sided cell has one
    # Calibrated and uncalibrated checkpoints differ only in that.
    from aslip_ros.learn.checkpoint import load_checkpoint
    models = transfer.scene_root(cfg) / "models" / "default"
    name = transfer.cached_name
    assert "calibration" in load_checkpoint(models / f"{name('paper_svm')}.pt").meta
    assert load_checkpoint(models / f"{name('paper_svm_uncalibrated')}.pt").meta.get(
        "calibration") is None


def test_the_default_protocol_tests_at_least_20_trials_per_scene():
    cfg = transfer.TransferConfig(out=None)
    assert cfg.trials * len(cfg.objects) * len(transfer.CONDITIONS) >= 20
    assert set(transfer.SCENES) == {"default"} | set(__import__(
        "aslip_ros.scene.variants", fromlist=["VARIANTS"]).VARIANTS)
    assert len(set(transfer.SCENE_SEED.values())) == len(transfer.SCENES)
    assert transfer.HELD_OUT_SEED > max(transfer.SCENE_SEED.values())
    assert "aslip" in cfg.methods and {"plain_cnn", "plain_svm", "paper_svm"} <= set(cfg.methods)


def test_merge_keeps_the_cached_predictions_of_methods_not_run(tmp_path, monkeypatch):
    fake_scenes(tmp_path, monkeypatch)
    base = dict(out=tmp_path / "out", data=tmp_path / "data", test_on=("coupling",),
                n_boot=10, progress=False)
    transfer.run_protocol(transfer.TransferConfig(methods=("plain_svm",), **base),
                          log=lambda s: None)
    alone = transfer.run_protocol(transfer.TransferConfig(methods=("paper_svm",), **base),
                                  log=lambda s: None)
    assert set(alone["cells"]["default -> coupling"]) == {"paper_svm"}
    both = transfer.run_protocol(transfer.TransferConfig(methods=("paper_svm",), merge=True,
                                                         **base), log=lambda s: None)
    assert set(both["cells"]["default -> coupling"]) == {"paper_svm", "plain_svm"}
    # Tables alone, from the cache: nothing is trained again.
    monkeypatch.setattr(transfer, "train_method", None)
    again = transfer.write_tables(transfer.TransferConfig(methods=(), merge=True, **base))
    assert again["cells"] == both["cells"]


def test_cached_data_follow_the_scene_version(tmp_path, monkeypatch):
    from aslip_ros.scene import physics
    cfg = transfer.TransferConfig(out=tmp_path, data=tmp_path / "d")
    now = transfer.scene_root(cfg)
    monkeypatch.setattr(physics, "SCENE_VERSION", physics.SCENE_VERSION + 1)
    assert transfer.scene_root(cfg) != now


def _preds(rng, n_trials, err_deg, mag_scale, p_correct):
    n = n_trials * 40
    trial = np.repeat(np.arange(n_trials), 40)
    ang = rng.uniform(-np.pi, np.pi, n)
    true = 0.01 * np.column_stack([np.cos(ang), np.sin(ang)])
    slip = rng.random(n) < 0.6
    true[~slip] = 0.0
    off = np.radians(err_deg) * rng.choice([-1, 1], n)
    raw = mag_scale * rng.uniform(0.8, 1.2, n)[:, None] * 0.01 * np.column_stack(
        [np.cos(ang + off), np.sin(ang + off)])
    right = rng.random(n) < p_correct
    prob = np.where(slip == right, 0.9, 0.1)
    return {"prob": prob, "raw_velocity": raw, "true_velocity": true, "slip": slip,
            "trial": trial, "window_s": np.float64(0.2)}


def test_target_met_only_when_far_better_with_separated_intervals():
    from benchmarks import transfer_targets as tt
    # The same seed draws the same trials and labels; only the predictions differ.
    good = _preds(np.random.default_rng(0), 24, 10.0, 1.05, 0.95)
    bad = _preds(np.random.default_rng(0), 24, 40.0, 1.6, 0.9)
    same = dict(good)
    t = tt.targets({"aslip": good, "plain_cnn": bad}, n_boot=100)
    assert t["met"] and t["direction_mae_deg"]["gain"] > 0.5
    assert t["direction_mae_deg"]["separated"] and t["direction_mae_deg"]["baseline"] == \
        "plain_cnn"
    # Against an equal baseline nothing is met and the intervals cannot tell them apart.
    t = tt.targets({"aslip": good, "plain_cnn": bad, "plain_svm": same}, n_boot=100)
    d = t["direction_mae_deg"]
    assert d["baseline"] == "plain_svm" and abs(d["gain"]) < 1e-9 and not d["separated"]
    assert not t["met"]
    md = "\n".join(tt.targets_markdown({"default -> default": t}))
    assert "cannot be told apart" in md and "| no |" in md
    assert tt.targets({"plain_cnn": bad}) is None
    # Against the plain baselines alone the paper's SVM is no baseline.
    t = tt.targets({"aslip": good, "plain_cnn": bad, "paper_svm": same}, n_boot=50,
                   baselines=tt.PLAIN)
    assert t["direction_mae_deg"]["baseline"] == "plain_cnn" and t["met"]


def test_unknown_names_are_refused():
    p = transfer.argparse.ArgumentParser()
    transfer.add_arguments(p)
    with pytest.raises(SystemExit, match="unknown scene"):
        transfer.config_from_args(p.parse_args(["--test-on", "default,moon"]))


def test_the_mocap_variant_is_a_labs_motion_capture():
    from aslip_ros.scene import scenarios
    scn = scenarios.external_induced(3)
    lab = scenarios.VARIANTS["mocap"](scn)
    assert lab.mocap_rate_hz == 100.0 and lab.mocap_noise_m == pytest.approx(3e-4)
    assert lab.mocap_drop_prob > scn.mocap_drop_prob
    assert lab.acoustics == scn.acoustics            # the audio is untouched
    one = scenarios.VARIANTS["one_sided"](scn)
    assert one.acoustics == scn.acoustics and one.one_sided_fraction == 0.8


def test_simulate_records_the_mocap_variant(tmp_path):
    from aslip_ros.data.bags import BagReader
    from aslip_ros.scene.simulate import simulate
    simulate(tmp_path, "external", duration_s=1.0, variant="mocap", progress=False)
    bag = next(p for p in tmp_path.iterdir() if p.is_dir())
    with BagReader(bag) as r:
        meta = r.read_metadata()
    assert meta["variant"] == "mocap"
    assert json.dumps(meta).count("100.0") >= 1       # the lab's 100 Hz motion capture


def test_a_dataset_at_another_rate_is_resampled_to_the_models_rate(tmp_path):
    from aslip_ros.learn.data_io import open_dataset
    from aslip_ros.learn.synthetic import make_synthetic_dataset
    src = make_synthetic_dataset(tmp_path / "lab", n_trials=3, duration_s=2.0,
                                 sample_rate=44100.0)
    transfer.resample_dataset(src, tmp_path / "at48", 48000.0)
    a, b = open_dataset(src), open_dataset(tmp_path / "at48")
    assert b.sample_rate == 48000.0 and b.window_samples == 9600
    assert len(b.trials) == len(a.trials) and b.windows.shape == a.windows.shape
    np.testing.assert_array_equal(b.windows["start"], a.windows["start"] * 160 // 147)
    np.testing.assert_array_equal(b.slip(np.arange(4)), a.slip(np.arange(4)))
    # The same sound: equal power per window, and a window's spectrum keeps its frequencies.
    k = len(a.windows) // 2
    x, y = a.window_audio(np.array([k]))[0], b.window_audio(np.array([k]))[0]
    assert y.shape == (9600, x.shape[1])
    np.testing.assert_allclose((y ** 2).mean(), (x ** 2).mean(), rtol=0.05)

    def centroid(sig, rate):
        p = np.abs(np.fft.rfft(sig[:, 0])) ** 2
        return (p * np.fft.rfftfreq(sig.shape[0], 1.0 / rate)).sum() / p.sum()
    assert centroid(y, 48000.0) == pytest.approx(centroid(x, 44100.0), rel=0.05)


def test_the_aslip_method_is_what_aslip_train_does_by_default(tmp_path, monkeypatch):
    from aslip_ros.learn.training import cli as train_cli
    seen = {}

    def fake_run(args):
        seen[args.out] = args
        open(args.out, "wb").close()
        return 0

    monkeypatch.setattr(train_cli, "run", fake_run)
    cfg = transfer.TransferConfig(out=tmp_path, data=tmp_path, progress=False)
    for method in ("aslip", "paper_svm", "aslip_uncalibrated"):
        transfer.train_method(cfg, method, tmp_path / "ds", tmp_path / "m", log=lambda s: None)
    aslip, svm, raw = (seen[str(tmp_path / "m" / f"{transfer.cached_name(m)}.pt")]
                       for m in ("aslip", "paper_svm", "aslip_uncalibrated"))
    p = transfer.argparse.ArgumentParser()
    train_cli.add_arguments(p)
    default = p.parse_args(["--dataset", "x", "--out", "y"])
    assert (aslip.stage, aslip.calibration) == (default.stage, default.calibration) == \
        ("auto", "background")
    assert aslip.time_budget is None and aslip.seeds == default.seeds
    assert svm.stage == "svm" and svm.calibration == "background"
    assert raw.stage == "auto" and raw.calibration == "off"
    assert "--stage auto" in transfer.aslip_recipe()


def test_a_revised_method_is_never_read_from_the_old_cache():
    """The SVMs' estimator changed (revision 2: speed and direction regressed, not vx and
    vz), and so did aslip's (each output from its best candidate): their cached models and
    predictions of before must not come back."""
    assert transfer.cached_name("aslip") != "aslip"
    assert transfer.cached_name("plain_svm") != "plain_svm"
    assert transfer.cached_name("paper_svm") != "paper_svm"
    assert transfer.cached_name("plain_cnn") == "plain_cnn"
    cfg = transfer.TransferConfig(out=None)
    assert transfer._predictions_path(cfg, "default", "coupling", "plain_svm").name == \
        f"{transfer.cached_name('plain_svm')}.npz"


def test_a_one_sided_training_draw_with_even_headings_is_its_own_draw(tmp_path, monkeypatch):
    """``--headings even`` simulates the one_sided training draw with the trials' preferred
    directions spread evenly, under a name of its own in the caches and the tables (a model
    of the random draw is never read for it); the test draw stays the seeds' own."""
    fake_scenes(tmp_path, monkeypatch)
    cfg = transfer.TransferConfig(out=tmp_path / "out", data=tmp_path / "data",
                                  train_on=("one_sided",), test_on=("one_sided",),
                                  methods=("plain_svm",), n_boot=20, progress=False,
                                  headings="even")
    assert transfer.draw_name(cfg, "one_sided") == "one_sided-even-headings"
    assert transfer.draw_name(cfg, "one_sided", held_out=True) == "one_sided-held-out"
    assert transfer.draw_name(cfg, "default") == "default"
    res = transfer.run_protocol(cfg, log=lambda s: None)
    assert set(res["cells"]) == {"one_sided-even-headings -> one_sided"}
    md = (cfg.out / "transfer.md").read_text()
    assert "## one_sided-even-headings -> one_sided (fresh draw of the training scene," in md
    assert (transfer.scene_root(cfg) / "models" / "one_sided-even-headings").is_dir()
    assert not (transfer.scene_root(cfg) / "models" / "one_sided").exists()
    p = transfer.add_arguments
    import argparse
    parser = argparse.ArgumentParser()
    p(parser)
    with pytest.raises(SystemExit, match="one_sided"):
        transfer.config_from_args(parser.parse_args(["--headings", "even"]))


def test_scene_dataset_asks_simulate_for_even_headings_on_the_training_draw_only(
        tmp_path, monkeypatch):
    import aslip_ros.scene.simulate as sim
    asked = []

    def fake_simulate(out, kind, **kw):
        asked.append((out.name, kw["variant"], kw["headings"]))
        raise RuntimeError("stop here")
    monkeypatch.setattr(sim, "simulate", fake_simulate)
    cfg = transfer.TransferConfig(out=tmp_path / "out", data=tmp_path / "data",
                                  progress=False, headings="even")
    for scene, held_out in (("one_sided", False), ("one_sided", True), ("default", False)):
        with pytest.raises(RuntimeError):
            transfer.scene_dataset(cfg, scene, lambda s: None, held_out=held_out)
    assert asked == [("one_sided-even-headings", "one_sided", "even"),
                     ("one_sided-held-out", "one_sided", "random"),
                     ("default", None, "random")]


def test_per_direction_scores_each_true_direction_apart():
    """Windows slipping at 0 deg estimated 10 deg off, at 90 deg estimated 40 deg off, none
    backwards: the per-direction errors say so, sector by sector."""
    ang_true = np.radians([0.0] * 4 + [90.0] * 4)
    ang_est = ang_true + np.radians([10.0] * 4 + [40.0] * 4)
    unit = lambda a: np.column_stack([np.cos(a), np.sin(a)]) * 0.02     # noqa: E731
    p = {"prob": np.ones(8), "raw_velocity": unit(ang_est), "true_velocity": unit(ang_true),
         "slip": np.ones(8, bool), "window_s": 0.2}
    d = transfer.per_direction(p)
    assert d["+0 deg"] == pytest.approx(10.0, abs=0.01)
    assert d["+90 deg"] == pytest.approx(40.0, abs=0.01)
    assert d["+180 deg"] is None and len(d) == 8


def test_follows_the_trial_tells_an_estimate_of_the_slip_from_one_of_the_trials_sound():
    """Test trial a slips at 0 deg, its training twin at 90: estimated at 0 (the slip). Trial
    b slips at 0, its twin at 180: estimated at 180 (the twin's). Trial c's twin slipped
    10 deg away: it cannot tell the two apart and is left out."""
    test = [(("a", "x"), 0.0), (("b", "x"), 0.0), (("c", "x"), 0.0)]
    train = [(("a", "x"), np.pi / 2), (("b", "x"), np.pi), (("c", "x"), np.radians(10.0))]
    est = np.array([[1.0, 0.0], [-1.0, 0.0], [1.0, 0.0]]).repeat(3, axis=0) * 0.01
    p = {"trial": np.arange(3).repeat(3), "slip": np.ones(9, bool), "raw_velocity": est}
    r = transfer.follows_the_trial(p, test, train)
    assert r["n_trials"] == 2
    assert r["to_own_deg"] == pytest.approx(90.0) and r["to_twin_deg"] == pytest.approx(45.0)


def test_follows_the_trial_keeps_trials_of_one_object_and_condition_apart():
    """With two trials per object and condition (``--trials 2``), each test trial is judged by
    its own direction, not by the last trial of its key; a test trial with a twin slipping
    near it is left out. Test trials a/x slip at 0 and 180 deg and are estimated so; their
    twins slipped at 90 and at 170."""
    test = [(("a", "x"), 0.0), (("a", "x"), np.pi)]
    train = [(("a", "x"), np.pi / 2), (("a", "x"), np.radians(170.0))]
    est = np.array([[1.0, 0.0], [-1.0, 0.0]]).repeat(3, axis=0) * 0.01
    p = {"trial": np.arange(2).repeat(3), "slip": np.ones(6, bool), "raw_velocity": est}
    r = transfer.follows_the_trial(p, test, train)
    assert r["n_trials"] == 1                   # the 180-deg trial has a twin 10 deg away
    assert r["to_own_deg"] == pytest.approx(0.0, abs=1e-6)
    assert r["to_twin_deg"] == pytest.approx(90.0)


def test_preferred_directions_sum_each_trials_slip_windows_only():
    """Trial 0 slips in two windows (its window without slip, fast along +x, carries no
    weight), trial 1 at 180 deg: each trial's direction of its summed slip velocities, in
    trial order, keyed by its object and condition."""
    class _Set:
        windows = {"trial": np.array([0, 0, 0, 1])}
        trials = [{"object": "a", "condition": "x"}, {"object": "b", "condition": "y"}]

        def __len__(self):
            return 4

        def velocity(self, idx):
            return np.array([[0.0, 0.02], [0.01, 0.01], [0.5, 0.0], [-0.01, 0.0]])[idx]

        def slip(self, idx):
            return np.array([True, True, False, True])[idx]

    (k0, d0), (k1, d1) = transfer.preferred_directions(_Set())
    assert (k0, k1) == (("a", "x"), ("b", "y"))
    assert d0 == pytest.approx(np.arctan2(0.03, 0.01)) and abs(d1) == pytest.approx(np.pi)
