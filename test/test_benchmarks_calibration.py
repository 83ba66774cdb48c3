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
