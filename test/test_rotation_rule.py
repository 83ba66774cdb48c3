"""benchmarks/rotation_rule.py: recorded traces replayed through the slip-stop controller
under other rotation rules (synthetic traces whose answers are known)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from benchmarks import rotation_rule as rr

HOP = 0.01


def _episode(path, moves_s, spikes=(), turn_from=math.inf, turn_rate=0.0, slip_from=math.inf,
             rotates=True):
    """A trace of 5 s: the arm retracts until 0.5 s, rests, approaches from 1.0 s along -z;
    the object starts moving in the grasp at ``moves_s`` (turning when ``rotates``). The
    estimates are quiet but for rate ``spikes`` ((time, rate)), ``turn_rate`` from
    ``turn_from`` and p(slip) 0.9 from ``slip_from``."""
    t = np.arange(0.0, 5.0, 1 / 120)
    z = np.where(t < 0.5, 0.1 * t, np.where(t < 1.0, 0.05, 0.05 - 0.03 * (t - 1.0)))
    tcp = np.stack([np.zeros_like(t), np.zeros_like(t), z], axis=1)
    after = t >= moves_s
    w_rel = np.where(after & rotates, 0.6, 0.0)
    v_rel = np.zeros((t.size, 2))
    v_rel[after & (not rotates), 1] = 0.02
    pt = np.arange(0.0, 5.0, HOP)
    pw = np.where(pt >= turn_from, turn_rate, 0.01)
    for when, rate in spikes:
        pw[np.abs(pt - when) < HOP / 2] = rate
    pp = np.where(pt >= slip_from, 0.9, 0.1)
    np.savez(path, t=t, tcp=tcp, push_dir=np.array([0.0, 0.0, -1.0]), v_rel=v_rel,
             w_rel=w_rel, pred_t=pt, pred_p=pp, pred_w=pw, pred_v=np.zeros((pt.size, 2)))


@pytest.fixture
def run(tmp_path):
    ep = tmp_path / "episodes"
    ep.mkdir()
    two_spikes = ((1.5, 0.3), (1.51, 0.3))
    # pivot: a turn from 2.0 s heard at 0.6 rad/s from 2.1 s, after two 0.3 spikes at 1.5 s
    _episode(ep / "pivot_stop-aslip-ignores_rotation-loud-00.npz", 2.0, two_spikes,
             turn_from=2.1, turn_rate=0.6)
    # pivot: a quiet turn from 2.0 s heard at 0.22 rad/s only, no spike before it
    _episode(ep / "pivot_stop-aslip-ignores_rotation-quiet-00.npz", 2.0, turn_from=2.1,
             turn_rate=0.22)
    # the arm that acts on rotation is not read
    _episode(ep / "pivot_stop-aslip-rotation_aware-loud-00.npz", 2.0, turn_from=2.1,
             turn_rate=0.6)
    # slip-stop: the wall at 3.0 s, slip heard from 3.05 s; two 0.3 spikes at 1.5 s and a
    # lone 0.9 one at 2.0 s
    _episode(ep / "slip_stop-aslip-box-00.npz", 3.0, two_spikes + ((2.0, 0.9),),
             slip_from=3.05, rotates=False)
    _episode(ep / "slip_stop-aslip-box-00-robot4x.npz", 3.0, slip_from=3.05, rotates=False)
    return tmp_path


def test_the_approach_starts_after_the_retract():
    t = np.arange(0.0, 3.0, 0.01)
    x = np.where(t < 1.0, -0.05 * t, np.where(t < 1.5, -0.05, -0.05 + 0.02 * (t - 1.5)))
    tcp = np.stack([x, np.zeros_like(t), np.zeros_like(t)], axis=1)
    assert rr.approach_start(t, tcp, (1.0, 0.0, 0.0)) == pytest.approx(1.5, abs=0.02)
    assert rr.approach_start(t, tcp * 0.0, (1.0, 0.0, 0.0)) == math.inf


def test_the_controller_stops_on_its_own_rule(run):
    with np.load(run / "episodes" / "slip_stop-aslip-box-00.npz") as rec:
        tr = rr.trace_of(rec)
    assert tr.approach_s == pytest.approx(1.0, abs=0.02)
    assert tr.moves_s == pytest.approx(3.0, abs=0.01)
    # A lone spike never stops (two consecutive estimates); slip does, on its second hop.
    assert rr.first_stop(tr, 0.7, 0.5, 2) == pytest.approx(3.06, abs=1e-6)
    assert rr.first_stop(tr, 0.7, 0.25, 2) == pytest.approx(1.51, abs=1e-6)
    assert rr.first_stop(tr, 0.7, 0.5, 1) == pytest.approx(2.0, abs=1e-6)
    assert rr.first_stop(tr, 0.95, 0.5, 2) == math.inf          # p 0.9 is under 0.95


def test_a_lower_threshold_hears_the_quiet_turn_and_stops_slip_stop_early(run, capsys):
    res = rr.evaluate([run], "aslip", 0.7, [(0.5, 2), (0.2, 2)])
    assert (res["pivot_traces"], res["slip_traces"]) == (2, 2)
    shipped, low = res["rules"]
    assert shipped["pivot_per_object"] == {"loud": 1, "quiet": 0}
    assert shipped["slip_stop_early"] == 0
    # At 0.2 the quiet turn is heard, but the loud trial's spikes stop it before its turn,
    # and the slip-stop's before the wall.
    assert low["pivot_per_object"] == {"loud": 0, "quiet": 1}
    assert low["slip_stop_early_per_scene"] == {"default": "1/1", "robot4x": "0/1"}
    assert rr.main([str(run), "--checkpoint", str(run / "none.pt")]) == 2
    assert "cannot read the threshold" in capsys.readouterr().err


def test_main_prints_and_writes_the_table(run, tmp_path, capsys, monkeypatch):
    from aslip_ros.learn import checkpoint

    class _Ck:
        meta = {"threshold": 0.7}
    monkeypatch.setattr(checkpoint, "load_checkpoint", lambda path: _Ck())
    out = tmp_path / "rr.json"
    assert rr.main([str(run), "--rules", "0.5,2", "0.2", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| 0.5, 2 | 1/2 | 1 | 0 | 0/2 | - |" in text
    assert "| 0.2, 2 | 1/2 | 0 | 1 | 1/2 | default 1/1 |" in text
    assert [r["debounce_count"] for r in json.loads(out.read_text())["rules"]] == [2, 2]
    assert rr.main([str(tmp_path / "nothing")]) == 2
