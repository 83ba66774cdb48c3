"""The transfer protocol end to end on tiny synthetic datasets (plumbing, not accuracy), its
table's "cannot be told apart" marks, and the lab-motion-capture scene variant."""

from __future__ import annotations

import json

import pytest

from aslip_ros.experiments import transfer


def test_best_and_ties_follow_the_intervals():
    rows = {"a": {"direction_mae_deg": 10.0, "direction_mae_deg_ci": (8.0, 12.0)},
            "b": {"direction_mae_deg": 11.0, "direction_mae_deg_ci": (11.5, 13.0)},
            "c": {"direction_mae_deg": 20.0, "direction_mae_deg_ci": (18.0, 22.0)},
            "d": {"direction_mae_deg": None}}
    assert transfer.best_and_ties(rows, "direction_mae_deg") == ("a", {"b"})
    det = {"a": {"detection_accuracy": 0.9, "detection_accuracy_ci": (0.88, 0.92)},
           "b": {"detection_accuracy": 0.95, "detection_accuracy_ci": (0.94, 0.96)}}
    assert transfer.best_and_ties(det, "detection_accuracy") == ("b", set())


def test_protocol_on_synthetic_scenes(tmp_path, monkeypatch):
    from aslip_ros.learn.synthetic import make_synthetic_dataset

    def fake_scene(cfg, scene, log):
        seed = transfer.SCENE_SEED[scene] // 1000
        return make_synthetic_dataset(tmp_path / "ds" / scene, n_trials=14, duration_s=2.0,
                                      seed=seed, coupling_db=0.0 if scene == "default" else 3.0,
                                      background=0.05)
    monkeypatch.setattr(transfer, "scene_dataset", fake_scene)
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
    # The held-out scene is tested on all its trials, the training scene on its test split.
    assert res["cells"]["default -> coupling"]["plain_svm"]["n_trials"] == 14
    assert res["cells"]["default -> default"]["plain_svm"]["n_trials"] < 14
    saved = json.loads((cfg.out / "transfer.json").read_text())
    assert saved["cells"].keys() == res["cells"].keys()
    md = (cfg.out / "transfer.md").read_text()
    assert "## default -> coupling (14 test trials)" in md and "**" in md
    # Calibrated and uncalibrated checkpoints differ only in that.
    from aslip_ros.learn.checkpoint import load_checkpoint
    models = cfg.data / "models" / "default"
    assert "calibration" in load_checkpoint(models / "paper_svm.pt").meta
    assert load_checkpoint(models / "paper_svm_uncalibrated.pt").meta.get("calibration") is None


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
    assert one.acoustics.gain_mismatch_db > 0 and one.one_sided_fraction == 0.8


def test_simulate_records_the_mocap_variant(tmp_path):
    from aslip_ros.data.bags import BagReader
    from aslip_ros.data.simulate import simulate
    simulate(tmp_path, "external", duration_s=1.0, variant="mocap", progress=False)
    bag = next(p for p in tmp_path.iterdir() if p.is_dir())
    with BagReader(bag) as r:
        meta = r.read_metadata()
    assert meta["variant"] == "mocap"
    assert json.dumps(meta).count("100.0") >= 1       # the lab's 100 Hz motion capture
