"""The ablation pipeline end to end on tiny synthetic datasets (plumbing, not accuracy)."""

from __future__ import annotations

import json

import pytest

from benchmarks import ablation
from benchmarks.common import DataPlan, Recipe


@pytest.fixture(scope="module")
def run_ablation(tmp_path_factory):
    root = tmp_path_factory.mktemp("ablation")
    cfg = ablation.AblationConfig(
        out=root / "out",
        data=DataPlan(root=root / "data", synthetic=True, progress=False, synthetic_s=2.0),
        recipe=Recipe(epochs=1, patience=1, threads=1, progress=False, svm_max_train=300),
        plain_epochs=2, n_boot=50)
    res = ablation.Ablation(cfg).run()
    return cfg, res


def test_writes_every_table_one_row(run_ablation):
    cfg, _ = run_ablation
    table = json.loads((cfg.out / "table.json").read_text())
    assert [r["key"] for r in table["rows"]] == list(ablation.ROW_KEYS)
    for r in table["rows"]:
        assert set(r["paper"]) == {"det_pct", "dir_mae_deg", "dir_std_deg", "mag_rmse_mm",
                                   "mag_std_mm"}
        assert 0.0 <= r["ours"]["det_pct"] <= 100.0
        assert r["ours"]["dir_mae_deg"] is not None and r["ours"]["mag_rmse_mm"] is not None
    md = (cfg.out / "table.md").read_text()
    for row in ablation.TABLE1:
        assert f"| {row.label} |" in md
    assert "81.8" in md and "14.1 ± 6.9" in md          # the paper's numbers beside ours
    assert table["checks"] and all("holds" in c for c in table["checks"])


def test_per_object_and_robot_noise(run_ablation):
    cfg, _ = run_ablation
    per_obj = json.loads((cfg.out / "per_object.json").read_text())
    assert "pla_rod" in per_obj and "all_object" in per_obj["pla_rod"]
    assert per_obj["pla_rod"]["paper"]["per_object"]["det_pct"] == 94.5
    assert "Per-obj." in (cfg.out / "per_object.md").read_text()
    robot = json.loads((cfg.out / "robot_noise.json").read_text())
    assert set(robot) == {"4mic", "2mic_centered", "2mic_corners", "2mic_same_finger", "1mic"}
    assert robot["4mic"]["paper"]["dir_mae_deg"] == 15.9
    assert robot["4mic"]["robot_val"]["n_windows"] > 0


def test_cached_rows_are_not_retrained(run_ablation):
    cfg, _ = run_ablation
    ckpt = cfg.cache / "ft_4mic_w200.pt"
    before = ckpt.stat().st_mtime_ns
    row = ablation.Ablation(cfg).row(next(r for r in ablation.TABLE1 if r.key == "ft_4mic"))
    assert row["training"]["cached"] is True
    assert ckpt.stat().st_mtime_ns == before


def test_force_retrains_a_shared_checkpoint_once_per_run(run_ablation):
    """Regression: with --force every row that shares a pretrained encoder retrained it."""
    from dataclasses import replace
    cfg, _ = run_ablation
    forced = ablation.Ablation(replace(cfg, force=True))
    pre = cfg.cache / "pre_4mic_w200.pt"
    before = pre.stat().st_mtime_ns
    first = forced.row(next(r for r in ablation.TABLE1 if r.key == "pre_4mic"))
    after_first = pre.stat().st_mtime_ns
    second = forced.row(next(r for r in ablation.TABLE1 if r.key == "ft_4mic"))
    assert after_first != before and first["training"]["cached"] is False
    assert pre.stat().st_mtime_ns == after_first        # not retrained for the second row
    assert second["training"]["cached"] is False          # its own finetuning still runs


def test_a_cached_row_from_another_recipe_is_retrained(run_ablation):
    """Regression: caches were reused whatever recipe trained them, so a recipe change
    silently mixed old and new models in one table."""
    from dataclasses import replace
    cfg, _ = run_ablation
    row = next(r for r in ablation.TABLE1 if r.key == "svm")
    again = ablation.Ablation(cfg).row(row)
    assert again["training"]["cached"] is True
    other = ablation.Ablation(replace(cfg, recipe=replace(cfg.recipe, patience=2))).row(row)
    assert other["training"]["cached"] is False


def test_orderings_on_hand_made_rows():
    def row(key, det, d):
        return {"key": key, "ours": {"det_pct": det, "dir_mae_deg": d}}
    rows = [row("ft_4mic", 90, 10), row("ft_2mic_corners", 80, 15),
            row("ft_2mic_same_finger", 78, 16), row("ft_2mic_centered", 70, 25),
            row("w100", 70, 8), row("w200", 90, 10), row("w300", 85, 12)]
    checks = {c["claim"]: c["holds"] for c in ablation.orderings(rows)}
    assert checks["direction: 4-mic < corners < same-finger < centered (finetuned)"] is True
    assert checks["longer windows raise detection (100 < 200 < 300 ms)"] is False
    assert checks["longer windows worsen direction (100 < 200 < 300 ms MAE)"] is True
    assert checks["4-mic finetuned better direction than the SVM"] is None   # no SVM row


def test_cli_arguments():
    import argparse
    p = argparse.ArgumentParser()
    ablation.add_arguments(p)
    cfg = ablation.config_from_args(p.parse_args(["--quick", "--rows", "svm,ft_4mic"]))
    assert cfg.rows == ("svm", "ft_4mic") and cfg.recipe.epochs == 2
    assert cfg.data.scale == "tiny"
    with pytest.raises(ValueError):
        ablation.config_from_args(p.parse_args(["--rows", "nope"]))


def test_plain_baselines_are_rows_with_trial_intervals(run_ablation):
    cfg, _ = run_ablation
    rows = {r["key"]: r for r in json.loads((cfg.out / "table.json").read_text())["rows"]}
    keys = list(rows)
    assert keys.index("svm") + 1 == keys.index("plain_cnn") == keys.index("plain_svm") - 1
    for key in ("svm", "plain_cnn", "plain_svm", "ft_4mic"):
        r = rows[key]
        assert r["measured"]["scene_version"] == "synthetic"
        assert r["n_test_trials"] >= 2
        for col in ("det_pct", "dir_mae_deg", "mag_rmse_mm"):
            lo, hi = r["ci95"][col]
            assert lo <= r["ours"][col] + 1e-6 and r["ours"][col] <= hi + 1e-6, (key, col)
    for key in ("plain_cnn", "plain_svm"):
        assert set(rows[key]["paper"].values()) == {None}    # the paper has no such row
        assert rows[key]["training"]["stage"] == key
    md = (cfg.out / "table.md").read_text()
    line = next(x for x in md.splitlines() if x.startswith("| Plain CNN"))
    assert line.split(" | ")[1] == "–" and "[" in line and "synthetic" in line


def test_baselines_only_merges_into_the_earlier_table(run_ablation, tmp_path):
    """Measuring the baseline rows alone keeps every other row as it was measured."""
    import shutil
    from dataclasses import replace
    cfg, _ = run_ablation
    out = tmp_path / "out"
    shutil.copytree(cfg.out, out)
    table = json.loads((out / "table.json").read_text())
    for r in table["rows"]:
        r["measured"] = {"scene_version": 2, "date": "1999-01-01"}
    (out / "table.json").write_text(json.dumps(table))
    sub = replace(cfg, out=out, rows=ablation.BASELINE_ROWS, per_object=False,
                  robot_noise=False, merge=True)
    ablation.Ablation(sub).run()
    rows = {r["key"]: r for r in json.loads((out / "table.json").read_text())["rows"]}
    assert list(rows) == list(ablation.ROW_KEYS)
    assert rows["ft_4mic"]["measured"]["date"] == "1999-01-01"
    for key in ablation.BASELINE_ROWS:
        assert rows[key]["measured"]["scene_version"] == "synthetic"
    checks = {c["claim"]: c for c in json.loads((out / "table.json").read_text())["checks"]}
    c = checks["4-mic finetuned better magnitude than the plain_cnn"]
    assert c["holds"] is None and "different scene versions" in c["note"]
    # Without merging, the table holds the measured rows only.
    ablation.Ablation(replace(sub, merge=False)).run()
    rows = json.loads((out / "table.json").read_text())["rows"]
    assert [r["key"] for r in rows] == list(ablation.BASELINE_ROWS)


def test_orderings_compare_only_rows_of_one_scene_version():
    def row(key, mag, version):
        return {"key": key, "ours": {"mag_rmse_mm": mag}, "measured": {"scene_version": version}}
    same = {c["claim"]: c["holds"] for c in ablation.orderings(
        [row("ft_4mic", 1.0, 3), row("plain_cnn", 0.6, 3)])}
    assert same["4-mic finetuned better magnitude than the plain_cnn"] is False
    mixed = {c["claim"]: c["holds"] for c in ablation.orderings(
        [row("ft_4mic", 1.0, 2), row("plain_cnn", 1.5, 3)])}
    assert mixed["4-mic finetuned better magnitude than the plain_cnn"] is None


def test_baselines_only_cli():
    import argparse
    p = argparse.ArgumentParser()
    ablation.add_arguments(p)
    cfg = ablation.config_from_args(p.parse_args(["--baselines-only", "--plain-epochs", "3"]))
    assert cfg.rows == ablation.BASELINE_ROWS == ("svm", "plain_cnn", "plain_svm")
    assert cfg.merge and not cfg.per_object and not cfg.robot_noise and cfg.plain_epochs == 3
    with pytest.raises(ValueError):
        ablation.config_from_args(p.parse_args(["--baselines-only", "--rows", "svm"]))
