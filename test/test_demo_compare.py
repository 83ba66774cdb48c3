"""benchmarks.demo_compare: two demo runs matched episode by episode."""

from __future__ import annotations

import json

from benchmarks import demo_compare


def _run(tmp_path, name, episodes, hogs=0):
    d = tmp_path / name
    d.mkdir()
    meta = {"mode": "lockstep", "hogs": hogs, "workers": 2, "wall_s": 1.0}
    (d / "summary.json").write_text(json.dumps({"meta": meta, "episodes": episodes}))
    return d


def _ep(trial, err, task="slip_stop"):
    return {"task": task, "method": "aslip", "object": "pla_rod", "trial": trial,
            "success": True, "stopping_error_m": err, "n_slip_msgs": 500}


def test_identical_runs_pass_and_a_different_episode_is_named(tmp_path, capsys):
    a = _run(tmp_path, "a", [_ep(0, 0.007), _ep(1, 0.006)])
    b = _run(tmp_path, "b", [_ep(0, 0.007), _ep(1, 0.006), _ep(2, 0.005)], hogs=2)
    assert demo_compare.main([str(a), str(b)]) == 0
    assert "2/2 shared episodes identical" in capsys.readouterr().out
    c = _run(tmp_path, "c", [_ep(0, 0.007), _ep(1, 0.0061)])
    assert demo_compare.main([str(a), str(c)]) == 1
    out = capsys.readouterr().out
    assert "1/2 shared episodes identical" in out and "slip_stop-aslip-pla_rod-1" in out
