"""``python -m benchmarks.track_reversals``: from slip-track traces, the estimates that point
backwards and what they cost (synthetic traces here; the figures come from ``make demo``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks import track_reversals as tr

#: The grasp plane's x along the world's -z and its z along the world's +x: a plane that is
#: not the world's xz, so the arm's motion must be mapped into it.
PLANE = np.array([[0.0, 1.0], [0.0, 0.0], [-1.0, 0.0]])


def _trace(reversed_from: float | None = None, reversed_to: float = 3.0) -> dict:
    """3 s at 100 Hz. The object slips along the plane's +x at 20 mm/s from 1.0 s while the
    arm moves along the plane's -x at 10 mm/s; the estimate is the true slip, and points
    the other way (along the arm) from ``reversed_from`` to ``reversed_to``."""
    t = np.arange(300) * 0.01
    v = np.where(t[:, None] >= 1.0, [0.02, 0.0], [0.0, 0.0])
    arm_plane = np.where(t[:, None] >= 1.0, [-0.01, 0.0], [0.0, 0.0])
    tcp = np.cumsum(arm_plane @ PLANE.T, axis=0) * 0.01 + [0.4, 0.0, 0.3]
    # A small vertical wobble of the object in the grasp: both plane axes appear in rel.
    rel = np.cumsum(v, axis=0) * 0.01 + np.outer(0.001 * np.sin(3.0 * t), [0.0, 1.0])
    est = v.copy()
    if reversed_from is not None:
        flip = (t >= reversed_from) & (t < reversed_to)
        est[flip] *= -1.0
    return {"t": t, "tcp": tcp, "object": tcp + rel @ PLANE.T, "rel": rel, "v_rel": v,
            "pred_t": t + tr.LAG_S, "pred_v": est}


def test_a_true_estimate_is_never_backward_and_a_reversed_one_is_timed_and_along_the_arm():
    np.testing.assert_allclose(tr.plane_of(_trace()), PLANE, atol=1e-9)
    good = tr.episode_figures(_trace())
    assert good["backward"] == 0 and good["estimates"] == 200
    assert good["longest_backward_s"] == 0.0
    bad = tr.episode_figures(_trace(reversed_from=1.5, reversed_to=2.0), rmse_mm=12.0)
    assert bad["backward"] == 50 and bad["backward_share"] == pytest.approx(0.25)
    assert bad["longest_backward_s"] == pytest.approx(0.49, abs=1e-6)
    assert bad["backward_along_arm"] == 50 and bad["rmse_mm"] == 12.0
    # Nothing slips: nothing to read.
    still = dict(_trace(), v_rel=np.zeros((300, 2)))
    assert tr.episode_figures(still) is None


def _write(run, method, obj, trial, trace):
    d = run / "episodes"
    d.mkdir(parents=True, exist_ok=True)
    np.savez(d / f"slip_track-{method}-{obj}-{trial:02d}.npz", **trace)


def test_methods_are_summarized_with_the_scored_rmse(tmp_path, capsys):
    for k in range(3):
        _write(tmp_path, "aslip", "chips_can", k, _trace())
    _write(tmp_path, "aslip", "chips_can", 3, _trace(reversed_from=1.2, reversed_to=2.2))
    _write(tmp_path, "svm", "pla_rod", 0, _trace(reversed_from=1.2, reversed_to=1.3))
    eps = [{"task": "slip_track", "method": "aslip", "object": "chips_can", "trial": k,
            "pose_rmse_m": r} for k, r in enumerate((0.003, 0.004, 0.005, 0.040))]
    (tmp_path / "summary.json").write_text(json.dumps({"episodes": eps}))
    out = tmp_path / "rev.json"
    assert tr.main([str(tmp_path), "--json", str(out)]) == 0
    got = json.loads(out.read_text())["methods"]
    a = got["aslip"]
    assert a["episodes"] == 4 and a["rmse_mean_mm"] == pytest.approx(13.0)
    assert a["tail_episodes"] == 1 and a["sustained_episodes"] == 1
    assert a["sustained_share_of_squared_error"] == pytest.approx(1600 / 1650)
    assert a["rmse_mean_without_sustained_mm"] == pytest.approx(4.0)
    assert a["backward_share_rest"] == 0.0 and a["backward_share_tail"] == pytest.approx(0.5)
    assert a["backward_along_arm_share"] == 1.0
    # No summary entry for svm: its RMSE comes from the trace; a 0.1 s reversal is brief.
    assert got["svm"]["sustained_episodes"] == 0
    assert "| aslip |" in capsys.readouterr().out
    assert tr.main([str(tmp_path / "nothing")]) == 1
    assert "no slip-track traces" in capsys.readouterr().err
