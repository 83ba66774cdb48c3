"""The calibration experiment runs end to end on a tiny scene and writes its report."""

import json

import numpy as np

from benchmarks import calibration as ex


def test_tiny_run_writes_report_and_predictions(tmp_path, capsys):
    rc = ex.main(["--out", str(tmp_path), "--train", "3", "--test", "2", "--duration", "6",
                  "--models", "svm", "--modes", "raw,calibrated", "--variants", "one_sided"])
    assert rc == 0
    rep = json.loads((tmp_path / "report.json").read_text())["one_sided"]
    none, bg = rep["gain_error_db/none"], rep["gain_error_db/background"]
    # Calibration on the background is better than assuming equal gains once it has audio.
    assert bg["5s"] < none["5s"]
    assert set(rep["models"]) == {"svm/raw", "svm/calibrated"}
    row = rep["models"]["svm/calibrated"]
    lo, hi = row["direction_mae_deg_ci"]
    assert lo <= row["direction_mae_deg"] <= hi
    z = np.load(tmp_path / "pred-one_sided-svm-calibrated.npz")
    assert z["p"].shape[0] == z["v"].shape[0] == z["trial"].shape[0] > 0
    # Cached renders are reused: a second run renders nothing.
    capsys.readouterr()
    ex.main(["--out", str(tmp_path), "--train", "3", "--test", "2", "--duration", "6",
             "--models", "svm", "--modes", "raw", "--variants", "one_sided"])
    assert "rendered" not in capsys.readouterr().out
    ex.main(["--out", str(tmp_path), "--summary"])
    assert "calibrated - raw" in capsys.readouterr().out


def test_tiny_self_check_writes_flag_rates_per_scene(tmp_path):
    rc = ex.main(["--out", str(tmp_path), "--self-check", "--train", "2", "--test", "2",
                  "--duration", "3"])
    assert rc == 0
    rep = json.loads((tmp_path / "self_check.json").read_text())
    assert rep["trust_spread_db"] > 0 and rep["train_grasps"] == 4
    rows = rep["rows"]
    assert {(r["scene"], r["condition"]) for r in rows} == {
        (s, c) for s in ex.CHECK_SCENES for c in ex.CHECK_CONDITIONS}
    assert {r["t_s"] for r in rows} == {2.0}                   # times within the duration
    for r in rows:
        assert r["grasps"] == 2 and 0 <= r["flagged"] <= r["converged"] <= 2
        assert r["gain_error_db"] is not None and r["gain_error_db"] >= 0
