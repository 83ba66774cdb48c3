"""``make recipe-budget``: its table and chart from rows, and its refusals (no training)."""

import argparse

import pytest

from benchmarks import recipe_budget


def _row(budget, direction, winner):
    keys = recipe_budget.KEYS
    test = dict(zip(keys, (0.97, direction, 1.1)))
    return {"budget_s": budget, "wall_s": budget * 0.7, "winner": winner,
            "val": dict(zip(keys, (0.95, direction - 2, 1.2))), "test": test,
            "test_ci": {k: (v * 0.9, v * 1.1) for k, v in test.items()}}


def test_table_and_chart_from_rows(tmp_path):
    rows = [_row(240.0, 26.0, "svm"), _row(960.0, 20.5, "unfrozen")]
    md = recipe_budget.markdown(rows, "python -m benchmarks.recipe_budget")
    assert md.count("\n| ") == 3                      # header and two budgets
    assert "| 4 | 2.8 | svm | 97.0 [87.3, 106.7] | 26.0 [23.4, 28.6]" in md
    assert "| 16 | 11.2 | unfrozen |" in md
    # The plain baselines on the same test trials, one row each.
    base = {"plain_svm": _row(0.0, 30.0, "-"), "plain_cnn": _row(0.0, 35.0, "-"),
            "wall_s": 90.0}
    md = recipe_budget.markdown(rows, "python -m benchmarks.recipe_budget", base)
    assert md.count("\n| ") == 5
    assert "| - | - | plain_svm (train + val trials) | 97.0 [87.3, 106.7] | 30.0" in md
    recipe_budget.plot(rows, tmp_path / "b.png")
    assert (tmp_path / "b.png").stat().st_size > 1000


def test_bad_budgets_are_refused(tmp_path):
    args = argparse.Namespace(out=str(tmp_path), data=str(tmp_path / "d"), budgets="0,60",
                              n_boot=10, no_baselines=False)
    with pytest.raises(ValueError, match="positive"):
        recipe_budget.run(args)
    with pytest.raises(ValueError, match="positive"):      # nothing to run at all
        recipe_budget.run(argparse.Namespace(**{**vars(args), "budgets": "",
                                                "no_baselines": True}))
