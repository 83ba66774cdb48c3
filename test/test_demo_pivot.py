"""The demo's pivot-stop task (issue #21) without running an episode: the plan (both arms
on the same seeds, the package's estimator only), the parameters the nodes get, the scene it
builds, the scoring of an episode and its rows in summary.json and table.md."""

from __future__ import annotations

import argparse
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks import demo
from benchmarks import demo_metrics as dm
from aslip_ros.hw.sources import PIVOT_PUSH_DIR_XZ
from benchmarks.demo_episode import (Episode, PivotSettings, StopSettings, TrackSettings,
                                     node_params)

pytestmark = pytest.mark.ros   # the node parameter checks import the built messages

CKPTS = {m: f"{m}.pt" for m in demo.METHODS}


def _plan(trials=10, tasks=("pivot_stop",), **kw):
    return demo.plan_episodes(list(tasks), list(demo.DEFAULT_METHODS),
                              list(demo.OBJECTS), trials, CKPTS, StopSettings(),
                              TrackSettings(), **kw)


def test_the_plan_runs_both_arms_of_the_package_estimator_on_the_same_seeds():
    eps = _plan()
    arms = {a: [e for e in eps if e.arm == a] for a in dm.PIVOT_ARMS}
    assert {len(v) for v in arms.values()} == {50}             # 50 episodes per arm
    assert {e.method for e in eps} == {"aslip"}                 # the first method only
    assert [(e.object, e.seed) for e in arms["rotation_aware"]] == \
        [(e.object, e.seed) for e in arms["ignores_rotation"]]  # paired trial by trial
    assert len({e.key for e in eps}) == len(eps)                # a trace file each
    assert all(3000 <= e.seed < 4000 for e in eps)              # disjoint from the others
    two = _plan(trials=1, pivot_methods=["svm", "aslip_window"], arms=["ignores_rotation"])
    assert {(e.method, e.arm) for e in two} == {("svm", "ignores_rotation"),
                                                ("aslip_window", "ignores_rotation")}
    with pytest.raises(ValueError, match="arm"):
        Episode("pivot_stop", "aslip", "a.pt", "chips_can", 0, 1, arm="sometimes")


def test_each_arm_is_the_slip_stop_node_with_or_without_rotation():
    ep = _plan(trials=1)[0]
    length = 0.2
    aware = node_params(ep, length)
    ignores = node_params(Episode(**{**ep.__dict__, "arm": "ignores_rotation"}), length)
    s = PivotSettings()
    assert aware["pivot_stop"]["stop_on_rotation"] is True
    assert ignores["pivot_stop"]["stop_on_rotation"] is False
    assert {k: v for k, v in aware["pivot_stop"].items() if k != "stop_on_rotation"} == \
        {k: v for k, v in ignores["pivot_stop"].items() if k != "stop_on_rotation"}
    ctl = aware["pivot_stop"]
    assert ctl["max_approach_distance_m"] == pytest.approx(s.retract_distance_m
                                                           + s.overshoot_limit_m)
    assert ctl["rotation_threshold_rad_s"] == s.rotation_threshold_rad_s
    scene = aware["scene_sim"]
    assert scene["scenario"] == "pivot" and scene["wall_distance_m"] == 0.0
    assert scene["pivot_lever_m"] == 0.1
    # Every controller parameter is one the node declares, with a value it accepts.
    from aslip_ros.nodes.introspect import declared_by_name
    declared = declared_by_name("slip_stop")
    for name, value in ctl.items():
        if name == "use_sim_time":       # rclpy's own (lockstep), declared by every node
            continue
        assert name in declared, name
        check = declared[name].check
        assert check is None or check(value) is None, (name, value)
        assert type(value) is type(declared[name].default), name


def test_the_pivot_scene_is_the_scenes_pivoting_wall_push():
    """scene_sim's ``pivot`` scenario, from the parameters it declares, pushes down onto a
    surface met off the grasp axis."""
    from aslip_ros.nodes import scene_sim
    from aslip_ros.nodes.scene_params import scene_params
    ep = _plan(trials=1)[0]
    params = node_params(ep, 0.2)["scene_sim"]
    values = {p.name: p.default for p in scene_params()}
    # Nothing the node would not know (but the timing: rclpy's use_sim_time and the node's
    # own lockstep, which are no part of the scene).
    assert set(params) - {"use_sim_time", "lockstep"} <= set(values)
    params = {k: v for k, v in params.items() if k in values}
    values.update(params)
    world = scene_sim.build_world(values)
    assert world.scenario.pivot_lever_m == pytest.approx(0.1) and world.scenario.pivots
    assert tuple(world.scenario.push_dir_xz) == PIVOT_PUSH_DIR_XZ == (0.0, -1.0)
    assert world.scenario.seed == ep.seed and world.scenario.object == ep.object
    meta = scene_sim.world_metadata(world)
    assert np.dot(meta["task"]["push_direction"], [0.0, 0.0, 1.0]) == pytest.approx(-1.0)


class _World:
    """What _score_pivot reads of the scene: a lowered arm that stopped, and a turn."""

    def __init__(self) -> None:
        self.arm = SimpleNamespace(stop_times=[0.2, 3.05])
        self.rotation_onset_time = 3.0

    def angle_turned(self) -> float:
        return math.radians(-2.5)


def test_an_episode_is_scored_by_the_angle_turned_before_the_arm_came_to_rest():
    from benchmarks.demo_episode import _score_pivot
    t = np.arange(0.0, 5.0, 0.01)
    tcp = np.zeros((t.size, 3))
    tcp[:, 2] = -0.03 * np.minimum(t, 3.05)
    ep = _plan(trials=1)[0]
    rec = SimpleNamespace(result={"reason": "rotation", "stopping_distance_m": 0.004})
    out = _score_pivot(ep, _World(), {"t": t, "tcp": tcp}, rec)
    assert out["arm"] == "rotation_aware" and out["controller_reason"] == "rotation"
    assert out["angle_deg"] == pytest.approx(2.5) and out["at_rest"] and out["turned"]
    assert out["onset_to_stop_s"] == pytest.approx(0.05) and out["success"] is True
    rec.result = {"reason": "max_travel"}
    assert _score_pivot(ep, _World(), {"t": t, "tcp": tcp}, rec)["success"] is False


def test_the_pivot_rows_reach_summary_json_and_table_md(tmp_path, monkeypatch):
    ckpt = tmp_path / "s.pt"
    ckpt.write_bytes(b"x")
    seen = []

    def fake_run(eps, workers, trace_dir, progress=True):
        seen.extend(eps)
        return [{"task": e.task, "method": e.method, "arm": e.arm, "object": e.object,
                 "trial": e.trial, "seed": e.seed, "reruns": [], "turned": True,
                 "at_rest": True, "onset_to_stop_s": 0.04,
                 "angle_deg": 2.0 if e.arm == "rotation_aware" else 25.0,
                 "controller_reason": "rotation" if e.arm == "rotation_aware"
                 else "max_travel"} for e in eps]
    monkeypatch.setattr(demo, "run_episodes", fake_run)
    p = argparse.ArgumentParser()
    demo.add_arguments(p)
    args = p.parse_args(["--out", str(tmp_path / "out"), "--tasks", "pivot_stop",
                         "--trials", "2", "--objects", "chips_can", "--aslip", str(ckpt),
                         "--no-plots", "--no-progress"])
    assert demo.run(args) == 0
    assert len(seen) == 4 and {e.checkpoint for e in seen} == {str(ckpt)}
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    cells = summary["table"]["pivot_stop"]
    assert cells["aslip/rotation_aware"]["overall"]["angle_mean_deg"] == 2.0
    assert cells["aslip/paired"]["overall"]["saved_mean_deg"] == 23.0
    assert summary["meta"]["pivot_arms"] == list(dm.PIVOT_ARMS)
    assert summary["meta"]["pivot_settings"]["pivot_lever_m"] == 0.1
    md = (tmp_path / "out" / "table.md").read_text()
    assert "| aslip | rotation aware | 2/2 | rotation 2 |" in md
    assert "| aslip | ignores rotation | 0/2 | max_travel 2 |" in md


def test_pivot_settings_from_the_command_line():
    got = demo.settings_overrides(PivotSettings, ["pivot_lever_m=0.08", "debounce_count=3"])
    assert got == {"pivot_lever_m": 0.08, "debounce_count": 3}
