"""The demo's closed loops with the shipped A-SLIP checkpoint, one short episode per task.

- slip-stop through separate node processes (the installed executables), scored from the
  ``trajectory_out`` file of ``scene_sim``;
- slip-track through the composed path the demo uses (the node classes in one process,
  its own context and domain), scored from the scene's trajectory.

Bounds are looser than the demo's targets: one episode on a shared 2-core machine is
subject to scheduling noise that the 50-trial means average out. As in ``make demo``
(``demo.MAX_RERUNS``), an episode that a watchdog ended on stale input, or whose scene fell
behind real time, measured the machine rather than the loop and is repeated; the
watchdog's own behaviour under load is tested in test_stale_input.py.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from aslip_ros import node_table
from node_support import Bus, NodeProcess

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
CNN = ROOT / "models" / "aslip_cnn.pt"                # the 200 ms window CNN (aslip_window)
STREAM = ROOT / "models" / "aslip_stream.pt"          # the streaming model (aslip_stream)
#: The package's estimator (aslip): the one model both closed-loop launch files run.
DEFAULT = ROOT / "models" / node_table.DEFAULT_MODEL
STOP_ERROR_BOUND_M = 0.015
# Below the paper's A-SLIP overall pose RMSE (15.8 mm); the demo's aim (8 mm) is not met.
TRACK_RMSE_BOUND_M = 0.015


def _skip_if_far_beyond_real_time(why: str) -> None:
    """Every attempt measured the machine: skip, but only when it is loaded far beyond the
    two CPU-busy processes the loop must hold beside (the rule of test_stale_input.py)."""
    load = os.getloadavg()[0]
    if load > 3 * (os.cpu_count() or 1):
        pytest.skip(f"machine at load {load:.1f} on {os.cpu_count()} cores; every episode "
                    f"ended on stale input or behind real time ({why})")


def _checkpoint() -> str:
    assert CNN.is_file(), f"shipped checkpoint missing: {CNN} (make demo ARGS=--train-models)"
    return str(CNN)


#: The controller's stale-input watchdog in the node-process episodes [s]: what they test
#: is the stop on slip; a busy machine's stall must not latch a stale-input stop first (the
#: watchdog's own tests: test_control_watchdog.py, test_stale_input.py).
EPISODE_INPUT_TIMEOUT_S = 1.0


def test_slip_stop_episode_through_node_processes(rclpy_context, ros_env, tmp_path):
    result, traj = _slip_stop_episode(rclpy_context, ros_env, tmp_path)
    _check_slip_stop(result, traj)


def _slip_stop_episode(rclpy_context, ros_env, tmp_path, checkpoint=None, slip_log=None,
                       **extra):
    from std_msgs.msg import String

    from benchmarks.demo_episode import StopSettings
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import LATCHED_QOS, RELIABLE_QOS
    from aslip_ros.nodes.slip_stop import RESULT_TOPIC
    from aslip_ros.scene.layouts import get_object

    s = StopSettings()
    obj = "chips_can"
    length = get_object(obj).length_m
    tmp_path.mkdir(parents=True, exist_ok=True)
    bus = Bus(rclpy_context, name=f"aslip_test_bus_{tmp_path.name}")
    bus.listen(String, RESULT_TOPIC, LATCHED_QOS)
    if slip_log is not None:
        from aslip_ros.msg import SlipVector
        bus.listen(SlipVector, c.SLIP_TOPIC, RELIABLE_QOS)
    traj = tmp_path / "wall_push.npz"
    ctl_params = {"approach_speed_m_s": s.approach_speed_m_s,
                  "retract_distance_m": s.retract_distance_m,
                  "retract_speed_m_s": s.retract_speed_m_s, "settle_s": s.settle_s,
                  "max_approach_distance_m": s.retract_distance_m + length
                  + s.overshoot_limit_m, "debounce_count": s.debounce_count,
                  "settle_result_s": s.settle_result_s,
                  "slip_timeout_s": EPISODE_INPUT_TIMEOUT_S,
                  "pose_timeout_s": EPISODE_INPUT_TIMEOUT_S, **extra}

    def final():
        return [json.loads(m.data) for m in bus.messages(RESULT_TOPIC)
                if json.loads(m.data).get("final")]

    with NodeProcess("slip_inference", ros_env,
                     {"checkpoint": checkpoint or _checkpoint()}) as inf, \
            NodeProcess("slip_stop", ros_env, ctl_params) as ctl:
        inf.wait_ready()
        ctl.wait_ready()
        with NodeProcess("scene_sim", ros_env,
                         {"scenario": "wall_push", "seed": 1201, "object": obj,
                          "wall_distance_m": 0.0, "trajectory_out": str(traj)}) as sim:
            sim.wait_ready()
            assert bus.wait(lambda: bool(final()), timeout=40.0), \
                ctl.output[-3000:] + inf.output[-2000:]
            sim.stop()
    if slip_log is not None:
        slip_log.extend(bus.messages(c.SLIP_TOPIC))
    bus.close()
    return final()[0], traj


def _check_slip_stop(result, traj):
    from benchmarks import demo_metrics as dm
    from aslip_ros.scene.layouts import get_object
    length = get_object("chips_can").length_m
    assert result["reason"] == "slip", result
    d = np.load(traj)
    meta = json.loads(str(d["metadata"]))
    n = np.asarray(meta["task"]["push_direction"])
    onsets = dm.contacts_from_trajectory(d["t"], d["object"], n, meta["task"]["wall_point"],
                                         meta["task"]["object_length_m"])
    contacts = [(t, d["tcp"][k]) for t, k in onsets]
    o = dm.stop_outcome(d["t"], d["tcp"], n, contacts, length, initial_contact=d["tcp"][0])
    assert o.touched and o.at_rest and o.success, o
    assert 0.0 < o.stopping_error_m <= STOP_ERROR_BOUND_M, o
    # The controller's own reading (newest TCP pose against its start pose) agrees.
    assert result["stopping_distance_m"] == pytest.approx(o.stopping_error_m, abs=2e-3)


def test_slip_stop_episode_with_the_streaming_model(rclpy_context, ros_env, tmp_path):
    """The streaming checkpoint in slip_inference closes the slip-stop loop: the controller
    acts on its per-hop estimates and stops the arm on slip, within the CNN's bound. Its
    rotation estimate is left out of the stop (stop_on_rotation false; rotation stops:
    test_nodes_control): beside two busy loops it once reached the rotation threshold
    first on this planar push, and which of the two fires first is not what this tests."""
    assert STREAM.is_file(), STREAM
    slips: list = []
    result, traj = _slip_stop_episode(rclpy_context, ros_env, tmp_path, str(STREAM), slips,
                                      stop_on_rotation=False)
    assert result["reason"] == "slip", result
    assert len(slips) > 50 and {m.source for m in slips} == {"aslip_stream"}
    assert all(abs(m.window_length - 0.032) < 1e-6 for m in slips)     # float32 field
    assert any(m.slipping for m in slips)
    _check_slip_stop(result, traj)             # stopped after touching, within the bound


def _track_episode(checkpoint: str) -> dict:
    """One 4 s slip-track episode (cracker box, seed 2401) through the composed demo path,
    repeated as the demo repeats it after a stale-input stop or skipped scene blocks."""
    from benchmarks.demo_episode import Episode, TrackSettings

    return _run_as_the_demo_does(Episode("slip_track", "aslip", checkpoint, "cracker_box", 0,
                                         2401, track=TrackSettings(duration_s=4.0)))


def _run_as_the_demo_does(ep) -> dict:
    """``ep`` run, repeated as the demo repeats it after a stale-input stop or skipped scene
    blocks."""
    from benchmarks.demo import MAX_RERUNS
    from benchmarks.demo_episode import run_episode
    for _ in range(1 + MAX_RERUNS):
        r = run_episode(ep)
        if not str(r.get("controller_reason", "")).startswith("stale") and \
                r["skipped_blocks"] == 0:
            break
    else:
        _skip_if_far_beyond_real_time(f"{r.get('controller_reason')}, "
                                      f"{r['skipped_blocks']} scene blocks skipped")
    return r


@pytest.fixture(scope="module")
def composed_track():
    """One slip-track episode of the shipped CNN through the composed demo path."""
    return _track_episode(_checkpoint())


def test_slip_track_episode_composed_in_one_process(composed_track):
    r = composed_track
    assert r["ended"] == "duration", r
    tr = r["trace"]
    assert r["n_slip_msgs"] > 200, r           # the model ran at its 100 Hz hop throughout
    # The agent really dragged the object (otherwise a small RMSE would mean nothing) ...
    moved = np.linalg.norm(np.diff(tr["object"], axis=0), axis=1).sum()
    assert moved > 0.03, moved
    # ... and the arm moved (closed the loop); how well it followed is the next test.
    assert np.linalg.norm(np.diff(tr["tcp"], axis=0), axis=1).sum() > 0.01
    assert r["calibration"] is not None          # the shipped CNN calibrates live


def test_slip_track_episode_composed_follows_the_object(composed_track):
    """Until the calibration converged at the grasp (a held grasp, 60 frames), this grasp
    got 27 of its 200 background frames in the drag and the CNN tracked it at 38-44 mm
    (an arm standing still: 24 mm): a strict xfail before #26."""
    r = composed_track
    assert r["calibration"]["converged_after_s"] <= 2.0, r["calibration"]
    assert r["pose_rmse_m"] <= TRACK_RMSE_BOUND_M, {k: v for k, v in r.items() if k != "trace"}


def test_slip_track_episode_with_the_package_estimator():
    """The composed demo path runs the package's estimator (the hybrid of the streaming
    model and the window CNN): estimates at its 100 Hz hop all episode long, the per-grasp
    calibration converged within 2 s of the grasp (while the agent holds the object still),
    the agent drags the object and the arm follows."""
    r = _track_episode(str(DEFAULT))
    assert r["ended"] == "duration", r
    assert r["n_slip_msgs"] > 200, r
    cal = r["calibration"]
    assert cal["converged"] and cal["converged_after_s"] <= 2.0, cal
    moved = np.linalg.norm(np.diff(r["trace"]["object"], axis=0), axis=1).sum()
    assert moved > 0.03, moved
    assert r["pose_rmse_m"] <= TRACK_RMSE_BOUND_M, {k: v for k, v in r.items()
                                                    if k != "trace"}


def test_a_demo_worker_logs_to_its_file_not_to_the_progress_bar(tmp_path):
    """What a worker writes (Python or C stdio, where rcutils logs) lands in its log file."""
    import subprocess
    import sys
    code = ("import ctypes, os, sys\n"
            f"sys.path.append({str(ROOT)!r})\n"     # benchmarks/ is not installed
            "from benchmarks import demo\n"
            f"demo.redirect_output(demo.worker_log({str(tmp_path)!r}))\n"
            "print('python line'); print('stderr line', file=sys.stderr)\n"
            "libc = ctypes.CDLL(None); libc.dprintf(2, b'C line\\n')\n")
    out = subprocess.run([sys.executable, "-P", "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "" and out.stderr == ""
    logs = list(tmp_path.glob("worker-*.log"))
    assert len(logs) == 1
    assert set(logs[0].read_text().splitlines()) == {"python line", "stderr line", "C line"}


def test_pivot_stop_episode_composed_in_one_process():
    """The pivot-stop task through the composed demo path, the rotation-aware arm with the
    package's estimator: the arm lowers the object onto the surface, the object turns, the
    slip-stop controller stops the arm and the episode scores the angle turned before the
    arm came to rest from the scene's truth. With a checkpoint that estimates rotation the
    stop is on the estimate (its rotation, or its slip probability, which a turn raises too),
    within a few degrees (a planar-only checkpoint may run on to the travel limit, about 25
    degrees). That the controller acts on a rotation estimate alone is
    test_control_rotation's and test_demo_pivot's."""
    import math

    from benchmarks.demo_episode import Episode
    from aslip_ros.learn.checkpoint import estimates_rotation, load_checkpoint

    assert DEFAULT.is_file(), DEFAULT
    assert estimates_rotation(load_checkpoint(DEFAULT).meta), "the shipped model is planar"
    r = _run_as_the_demo_does(Episode("pivot_stop", "aslip", str(DEFAULT), "cracker_box", 0,
                                      3201))
    brief = {k: v for k, v in r.items() if k != "trace"}
    assert r["ended"] == "controller_result" and r["arm"] == "rotation_aware", brief
    assert r["turned"] and r["at_rest"], brief
    tr = r["trace"]
    # The score is the scene's angle at the end, the arm at rest, in degrees.
    assert r["angle_deg"] == pytest.approx(math.degrees(abs(tr["angle"][-1])), abs=0.2)
    assert 0.0 < r["angle_deg"] < 30.0, brief
    assert r["controller_reason"] in ("rotation", "slip", "max_travel"), brief
    assert tr["pred_w"].shape == tr["pred_t"].shape and tr["w_rel"].shape == tr["t"].shape
    assert r["controller_reason"] in ("rotation", "slip") and r["success"], brief
    assert r["angle_deg"] < 10.0, brief
