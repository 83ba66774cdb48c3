"""``python -m benchmarks.label_smoother --windows``: window labels against the scene's truth."""

from benchmarks.label_smoother import compare_window_labels, main


def test_window_labels_from_smoothed_poses_are_nearer_the_truth(tmp_path, capsys):
    """At a lab's motion capture (the ``mocap`` variant: 0.3 mm) the raw poses' labels carry
    several mm/s of noise; the export's default smoothing takes most of it off. Seeded, so
    the same draw every run."""
    res = compare_window_labels(n_trials=2, duration_s=4.0, variant="mocap", lengths=(0.15,))
    raw, smoothed = res["raw"], res["smoothed_150ms"]
    assert raw["windows"] == smoothed["windows"] > 40
    assert raw["rmse_mm_s"] > 2.5 and smoothed["rmse_mm_s"] < 0.6 * raw["rmse_mm_s"]
    assert smoothed["slip_flag_agrees_pct"] > raw["slip_flag_agrees_pct"]
    assert main(["--windows", "--trials", "1", "--duration", "3",
                 "--json", str(tmp_path / "w.json")]) == 0
    assert "smoothed_150ms" in capsys.readouterr().out and (tmp_path / "w.json").is_file()
