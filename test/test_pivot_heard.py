"""``python -m benchmarks.pivot_heard``: from pivot-stop traces, whether the estimate hears
the turn, per object (synthetic traces here; the figures come from ``make demo`` runs)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks import pivot_heard


def _trace(heard: bool, p_slip: float = 0.1) -> dict:
    """3 s at 100 Hz; the object turns at 0.7 rad/s from 2.0 s. The estimate sits at a
    floor of 0.02-0.08 rad/s, and follows the turn when ``heard``."""
    t = np.arange(300) * 0.01
    w = np.where(t >= 2.0, 0.7, 0.0)
    rng = np.random.default_rng(0)
    floor = rng.uniform(0.02, 0.08, t.size)
    est = np.where(t >= 2.02, 0.7, floor) if heard else floor
    return {"t": t, "w_rel": w, "pred_t": t, "pred_w": est,
            "pred_p": np.full(t.size, p_slip)}


def _write(run, obj, trial, trace, method="aslip", arm=pivot_heard.ARM):
    d = run / "episodes"
    d.mkdir(parents=True, exist_ok=True)
    np.savez(d / f"pivot_stop-{method}-{arm}-{obj}-{trial:02d}.npz", **trace)


def test_a_heard_turn_stands_out_of_the_floor_and_an_unheard_one_does_not():
    heard = pivot_heard.episode_figures(_trace(True))
    quiet = pivot_heard.episode_figures(_trace(False))
    assert heard["true_rad_s"] == pytest.approx(0.7)
    assert heard["estimated_median_rad_s"] == pytest.approx(0.7)
    assert heard["floor_p99_rad_s"] < 0.08 and quiet["estimated_median_rad_s"] < 0.08
    assert quiet["estimated_max_rad_s"] <= quiet["floor_p99_rad_s"] + 0.01
    # Nothing turns: nothing to read.
    still = dict(_trace(True), w_rel=np.zeros(300))
    assert pivot_heard.episode_figures(still) is None


def test_objects_are_summarized_from_the_ignoring_arms_traces_only(tmp_path, capsys):
    _write(tmp_path, "cracker_box", 0, _trace(True))
    _write(tmp_path, "cracker_box", 1, _trace(True))
    _write(tmp_path, "glass_cleaner", 0, _trace(False, p_slip=0.05))
    # The rotation-aware arm's traces stop early; they are not read.
    _write(tmp_path, "glass_cleaner", 1, _trace(True), arm="rotation_aware")
    out = tmp_path / "heard.json"
    assert pivot_heard.main([str(tmp_path), "--json", str(out)]) == 0
    got = json.loads(out.read_text())["objects"]
    assert got["cracker_box"]["episodes"] == 2 and got["glass_cleaner"]["episodes"] == 1
    assert got["glass_cleaner"]["estimated_median_rad_s"] < 0.1
    assert got["glass_cleaner"]["p_slip_median"] == pytest.approx(0.05)
    table = capsys.readouterr().out
    assert table.index("| cracker_box |") < table.index("| glass_cleaner |")
    # Another method's traces: none here, one line and exit 1.
    assert pivot_heard.main([str(tmp_path), "--method", "svm"]) == 1
    assert "no pivot-stop traces of svm" in capsys.readouterr().err
