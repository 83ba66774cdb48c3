"""``make rotation``: its verdicts, tables and refusals from known rows (no training)."""

import numpy as np

from benchmarks import rotation


def _res(**vals):
    out = {"n_trials": 5}
    for k, (v, lo, hi) in vals.items():
        out[k], out[k + "_ci"] = v, (lo, hi)
    return out


def test_verdict_reads_the_intervals_in_the_metric_s_own_sense():
    a = _res(direction_mae_deg=(20.0, 18.0, 22.0), detection_accuracy=(0.97, 0.96, 0.98))
    b = _res(direction_mae_deg=(30.0, 25.0, 35.0), detection_accuracy=(0.90, 0.88, 0.92))
    assert rotation.overlaps(a, b, "direction_mae_deg", higher_better=False) == "better"
    assert rotation.overlaps(b, a, "direction_mae_deg", higher_better=False) == "worse"
    assert rotation.overlaps(a, b, "detection_accuracy", higher_better=True) == "better"
    c = _res(direction_mae_deg=(21.0, 19.0, 26.0))
    assert rotation.overlaps(c, b, "direction_mae_deg", higher_better=False) == "overlap"
    assert rotation.overlaps({}, b, "direction_mae_deg", higher_better=False) == "n/a"


def test_tables_carry_every_layout_and_the_planar_verdicts():
    layout = _res(rotation_mae_deg_s=(40.0, 35.0, 45.0), rotation_mae_ratio=(0.2, 0.15, 0.25),
                  pure_rotation_detection=(0.9, 0.85, 0.95),
                  false_rotation_on_translation=(0.05, 0.02, 0.08),
                  kind_agreement=(0.93, 0.9, 0.96), detection_accuracy=(0.95, 0.94, 0.96),
                  direction_mae_deg=(22.0, 20.0, 24.0), magnitude_rmse_mm=(1.2, 1.0, 1.4))
    one = dict(layout, rotation_mae_deg_s=np.nan)
    result = {"config": {"trials": 2, "twist_fraction": 0.5, "pivot_trials": 2,
                         "duration_s": 10.0, "time_budget_s": 240.0},
              "layouts": {"4mic": layout, "1mic": one},
              "planar": {"coupling": {"before": layout, "after": dict(
                  layout, direction_mae_deg=30.0, direction_mae_deg_ci=(28.0, 32.0))}}}
    md = rotation.tables(result)
    assert "| 4mic | 5 | 40.0 [35.0, 45.0] | 20.0 [15.0, 25.0] | 90.0 [85.0, 95.0]" in md
    assert "| 1mic | 5 | n/a |" in md
    assert "22.0 [20.0, 24.0] / 30.0 [28.0, 32.0] (worse)" in md


def test_bad_arguments_are_refused_before_any_work(tmp_path, capsys):
    assert rotation.main(["--out", str(tmp_path), "--layouts", "3mic"]) == 2
    assert rotation.main(["--out", str(tmp_path), "--twist-fraction", "0"]) == 2
    assert "error" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
