"""The closed loop under stressors (issue #37, ``make demo-variants``): a stressor reaches the
scene through ``scene_sim``'s parameters, an episode in a variant runs and its stop holds (no
moving arm command after it, by the commands' stamps), and the table and the chart are
written from rows (synthetic here; the figures come from benchmark runs)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from aslip_ros.node_table import DEFAULT_MODEL

ROOT = Path(__file__).resolve().parents[1]
#: The package's default estimator (the hybrid), as both closed-loop launch files run it.
DEFAULT = ROOT / "models" / DEFAULT_MODEL
#: What the issue asks the loop to run under at least.
ASKED = {"default", "contact", "confounders", "one_sided", "mocap", "robot2x", "robot4x"}


def _episode(variant=None, robot_noise_x=1.0, task="slip_stop", obj="cracker_box"):
    from benchmarks.demo import SEED_BASE
    from benchmarks.demo_episode import Episode
    from benchmarks.demo_models import OBJECTS
    return Episode(task, "aslip", str(DEFAULT), obj, 0,
                   SEED_BASE[task] + 100 * OBJECTS.index(obj), variant=variant,
                   robot_noise_x=robot_noise_x)


# --- the stressors and the plan -------------------------------------------------------------

def test_the_loop_runs_every_asked_stressor_and_refuses_the_rate_variant():
    from benchmarks import demo_variants as dv
    names = dv.default_stressors()
    assert ASKED <= set(names) and names[0] == "default"
    assert "rate" in dv.stressors() and "rate" not in names
    assert "48 kHz" in dv.refusal("rate") and dv.refusal("confounders") is None
    args = argparse.ArgumentParser()
    dv.add_arguments(args)
    assert dv.run(args.parse_args(["--stressors", "default,rate"])) == 2
    assert dv.run(args.parse_args(["--stressors", "no_such_stressor"])) == 2


def test_every_stressor_runs_the_default_scenes_seeds():
    from benchmarks import demo_variants as dv
    models = {m: f"{m}.pt" for m in ("aslip", "svm")}
    eps = dv.plan(["slip_stop", "slip_track"], ["aslip", "svm"], ["pla_rod", "cracker_box"],
                  2, models, ["default", "contact", "robot4x"])
    assert len(eps) == 2 * 2 * 2 * 2 * 3
    by = {s: sorted((e.task, e.method, e.object, e.seed) for e in eps if e.stressor == s)
          for s in ("default", "contact", "robot4x")}
    assert by["default"] == by["contact"] == by["robot4x"]
    assert all(e.mode == "lockstep" for e in eps)
    assert len({e.key for e in eps}) == len(eps)              # one trace file each
    four = next(e for e in eps if e.stressor == "robot4x")
    assert (four.variant, four.robot_noise_x) == (None, 4.0)


def test_the_arms_noise_runs_at_any_factor_its_name_gives():
    """``robot0x`` (the arm silent) and ``robot0.5x`` are stressors when named: planned on
    the default scene's seeds with that factor, and kept in the run's record; a name that
    gives no factor, or one factor under a second name, is refused."""
    from benchmarks import demo_variants as dv
    assert dv.robot_noise_factor("robot0x") == 0.0
    assert dv.robot_noise_factor("robot0.5x") == 0.5
    for name in ("robotx", "robot-1x", "robotnanx", "robotinfx", "robot0.50x", "robot2",
                 "contact", "robot 2x"):
        assert dv.robot_noise_factor(name) is None, name
    assert "robot0x" not in dv.default_stressors()
    eps = dv.plan(["slip_track"], ["aslip"], ["pla_rod"], 1, {"aslip": "aslip.pt"},
                  ["default", "robot0x", "robot0.5x"])
    by = {e.stressor: e for e in eps}
    assert set(by) == {"default", "robot0x", "robot0.5x"}
    assert (by["robot0x"].variant, by["robot0x"].robot_noise_x) == (None, 0.0)
    assert by["robot0.5x"].robot_noise_x == 0.5
    assert by["robot0x"].seed == by["default"].seed
    args = argparse.ArgumentParser()
    dv.add_arguments(args)
    assert dv.run(args.parse_args(["--stressors", "default,robot0.50x"])) == 2
    assert dv.run(args.parse_args(["--stressors", "robotx"])) == 2


def test_the_default_episode_hands_the_scene_no_stressor():
    """The default path is unchanged: no variant, no noise factor, the demo's trace names."""
    from benchmarks.demo_episode import node_params
    ep = _episode()
    assert ep.stressor == "default" and ep.key == "slip_stop-aslip-cracker_box-00"
    assert not {"variant", "robot_noise_x"} & set(node_params(ep, 0.2)["scene_sim"])
    with pytest.raises(ValueError, match="variant"):
        _episode(variant="no_such_variant")
    with pytest.raises(ValueError, match="robot_noise_x"):
        _episode(robot_noise_x=-1.0)


@pytest.mark.ros
@pytest.mark.parametrize("name", ["contact", "confounders", "one_sided", "mocap", "coupling",
                                  "robot2x", "robot4x"])
def test_a_stressor_reaches_the_scene_as_its_parameters(name):
    """scene_sim builds, from the parameters an episode hands it, the variant's scenario of
    the default scene (robot noise: the level times the factor), and declares both."""
    from aslip_ros.nodes import scene_sim
    from aslip_ros.nodes.introspect import declared_by_name
    from aslip_ros.nodes.scene_params import scene_params
    from aslip_ros.scene.variants import VARIANTS
    from benchmarks import demo_variants as dv
    from benchmarks.demo_episode import node_params
    variant, x = dv.stressors()[name]
    values = {p.name: p.default for p in scene_params()}

    def world(ep):
        params = node_params(ep, 0.2)["scene_sim"]
        assert set(params) - {"use_sim_time", "lockstep"} <= set(values)
        return scene_sim.build_world({**values, **{k: v for k, v in params.items()
                                                   if k in values}}).scenario
    base = world(_episode())
    want = VARIANTS[variant](base) if variant else base
    want = want.with_(acoustics=dataclasses.replace(
        want.acoustics, robot_level=want.acoustics.robot_level * x))
    got = world(_episode(variant, x))
    assert got == want and got != base
    declared = declared_by_name("scene_sim")
    assert declared["variant"].check("no_such_variant") is not None
    assert declared["variant"].check(variant or "none") is None
    assert declared["robot_noise_x"].check(-1.0) is not None


# --- one episode in a variant ---------------------------------------------------------------

@pytest.fixture(scope="module")
def variant_stop():
    """One slip-stop episode of the package's estimator in the confounders variant with the
    arm's noise twice as loud again."""
    from benchmarks.demo_episode import run_episode
    assert DEFAULT.is_file(), DEFAULT
    return run_episode(_episode("confounders", 2.0))


@pytest.mark.ros
def test_an_episode_in_a_variant_runs_in_the_variants_scene(variant_stop):
    from aslip_ros.scene.physics import Acoustics
    from aslip_ros.scene.variants import CONFOUNDER_GAIN
    r = variant_stop
    brief = {k: v for k, v in r.items() if k != "trace"}
    assert r["stressor"] == "confounders+robot2x", brief
    assert r["scene"]["variant"] == "confounders" and r["scene"]["robot_noise_x"] == 2.0
    # The scene node built the variant's world: the arm CONFOUNDER_GAIN, then 2 times louder.
    assert r["scene"]["robot_level"] == pytest.approx(
        Acoustics().robot_level * CONFOUNDER_GAIN * 2.0)
    assert r["ended"] == "controller_result" and r["controller_reason"] is not None, brief
    assert r["n_slip_msgs"] > 300, brief


@pytest.mark.ros
def test_no_arm_command_follows_the_stop_in_a_variant(variant_stop):
    """By the commands' stamps, not their order of arrival: the newest command is a stop,
    every moving command is older, and the scene ran the controller's settle_result_s on
    past that stop without another moving command."""
    from benchmarks.demo_episode import StopSettings
    tr = variant_stop["trace"]
    t, speed = np.asarray(tr["cmd_t"], dtype=float), np.asarray(tr["cmd_speed"])
    assert (speed > 0).sum() > 50                       # the arm retracted and re-approached
    newest = t.max()
    assert np.all(speed[t == newest] == 0.0), speed[t == newest]
    assert np.all(t[speed > 0] < newest)
    final_stop = t[(speed == 0) & (t > t[speed > 0].max())].min()
    assert float(tr["t"][-1]) - final_stop >= StopSettings.settle_result_s - 0.02
    hold = variant_stop["stop_hold"]
    assert hold["ends_on_stop"] and hold["stop_s"] == pytest.approx(final_stop, abs=1e-6)


def test_the_stop_hold_reads_the_stamps():
    from benchmarks import demo_metrics as dm
    # retract, settle (zero commands), approach, stop: held to the end.
    t = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]
    ok = dm.stop_hold(t, [0.08, 0.0, 0.0, 0.03, 0.03, 0.0], end_s=0.9)
    assert ok["ends_on_stop"] and ok["stop_s"] == 0.5 and ok["held_s"] == pytest.approx(0.4)
    # A moving command after the stop moves the final stop later: held too short.
    late = dm.stop_hold(t + [0.7, 0.8], [0.08, 0.0, 0.0, 0.03, 0.03, 0.0, 0.03, 0.0], 0.9)
    assert late["stop_s"] == 0.8 and late["held_s"] == pytest.approx(0.1)
    # Newest command moving, or a moving one stamped with the newest stop: not on a stop.
    assert not dm.stop_hold(t, [0.0] * 5 + [0.03], 0.9)["ends_on_stop"]
    assert not dm.stop_hold([0.0, 0.5, 0.5], [0.03, 0.0, 0.03], 0.9)["ends_on_stop"]


# --- the table and the chart ----------------------------------------------------------------

def _rows(stressor: str, method: str, worse: float) -> list:
    """Synthetic episode results: 5 slip-stops (``worse`` fails some) and 5 slip-tracks."""
    from benchmarks import demo_metrics as dm
    curve = list(np.exp(-((dm.LAGS_S - 0.03 * worse) / 0.02) ** 2))
    out = []
    for k in range(5):
        ok = k >= round(worse)
        out.append({"task": "slip_stop", "method": method, "object": "cracker_box",
                    "trial": k, "seed": 1400 + k, "stressor": stressor, "success": ok,
                    "stopping_error_m": (0.006 + 0.001 * k) * (1 + worse),
                    "onset_to_stop_s": 0.04 * (1 + worse) + 0.002 * k,
                    "controller_reason": "slip" if ok else None, "lag_curve": curve,
                    "stop_hold": {"ends_on_stop": True, "held_s": 0.32, "commands": 500,
                                  "moving": 470, "stop_s": 5.4}})
        out.append({"task": "slip_track", "method": method, "object": "cracker_box",
                    "trial": k, "seed": 2400 + k, "stressor": stressor,
                    "pose_rmse_m": (0.008 + 0.001 * k) * (1 + worse), "lag_curve": curve})
    return out


def test_the_table_and_the_chart_are_written_from_rows(tmp_path):
    from benchmarks import demo_variants as dv
    from benchmarks.demo_episode import LOCKSTEP_BUDGET_S
    names, methods = ["default", "one_sided", "robot4x"], ["aslip", "svm"]
    results = [r for s, worse in (("default", 0), ("one_sided", 0), ("robot4x", 2))
               for m in methods for r in _rows(s, m, worse + (m == "svm"))]
    results.append({"task": "slip_stop", "method": "svm", "object": "cracker_box",
                    "trial": 9, "seed": 1, "stressor": "robot4x", "error": "RuntimeError: x"})
    meta = {"command": "python -m benchmarks.demo_variants", "trials": 5,
            "objects": ["cracker_box"], "stressors": names, "methods": methods,
            "mode": "lockstep", "charge": "budget", "lockstep_budget_s": LOCKSTEP_BUDGET_S,
            "wall_s": 1.0, "workers": 2, "cpus": 2}
    doc = dv.write_outputs(tmp_path, results, meta)
    saved = json.loads((tmp_path / "variants.json").read_text())
    assert saved["format"] == "aslip-demo-variants" and len(saved["rows"]) == 6
    row = {(r["stressor"], r["method"]): r for r in doc["rows"]}
    a4, s4 = row[("robot4x", "aslip")], row[("robot4x", "svm")]
    assert a4["slip_stop"]["successes"] == 3 and a4["slip_stop"]["trials"] == 5
    assert a4["slip_stop"]["success_ci95"] == pytest.approx([0.231, 0.882], abs=1e-3)
    assert s4["errors"] == 1 and s4["slip_stop"]["trials"] == 5
    assert a4["slip_stop"]["stopped"] == a4["slip_stop"]["stop_held"] == 3
    err = a4["slip_stop"]["error_mm"]
    assert err["mean"] == pytest.approx(24.0) and err["ci95"][0] < 24.0 < err["ci95"][1]
    assert a4["slip_track"]["rmse_mm"]["mean"] == pytest.approx(30.0)
    assert a4["slip_track"]["delay_ms"]["value"] == pytest.approx(60.0)
    assert row[("default", "aslip")]["slip_track"]["delay_ms"]["value"] == 0.0
    assert doc["same_as_default"] == ["one_sided"]
    md = (tmp_path / "variants.md").read_text()
    assert "| robot4x | aslip | 3/5 [0.23, 0.88] | 24.0 [" in md
    assert "`rate` is not run" in md and "Stops not held (a moving command after a stop): 0" in md
    png = tmp_path / "variants.png"
    assert doc["plots"] == [str(png)] and png.stat().st_size > 10_000


def test_the_wilson_interval():
    from benchmarks.demo_variants import wilson_interval
    assert wilson_interval(10, 10) == pytest.approx((0.722, 1.0), abs=1e-3)
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.278), abs=1e-3)
    assert wilson_interval(5, 10) == pytest.approx((0.237, 0.763), abs=1e-3)
    assert all(math.isnan(x) for x in wilson_interval(0, 0))
