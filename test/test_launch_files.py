"""Every launch file, evaluated by the real launch stack, against what each node declares.

Each launch description is walked the way ``ros2 launch`` would: launch arguments resolved
(given or default; a required one missing is an error), conditions evaluated, opaque
functions run, substitutions performed and every ``Node``'s parameters evaluated by
launch_ros (YAML files and dicts alike). Then every parameter must be one the node declares
(:mod:`aslip_ros.nodes.introspect`), of the declared type (rclpy refuses an int for a
double), and pass the node's own validator. Without ``launch``/``launch_ros`` these tests
skip with the reason; ``ros2 launch`` itself runs in the process tests at the end.
"""

from __future__ import annotations

import json
import os
import runpy
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from conftest import HELPERS, ROOT

try:
    import launch  # noqa: F401
    import launch_ros  # noqa: F401
except ImportError as exc:
    LAUNCH_MISSING = (f"{exc.name} is not importable (source a ROS 2 Jazzy install or "
                      "build/ros2-launch/env.sh)")
else:
    LAUNCH_MISSING = None

pytestmark = pytest.mark.ros   # needs the colcon install (ament index, share/aslip_ros)
needs_launch = pytest.mark.skipif(LAUNCH_MISSING is not None, reason=str(LAUNCH_MISSING))


class Evaluated:
    """What a launch description starts, with every substitution performed."""

    def __init__(self) -> None:
        self.nodes: list = []        # (executable, node name, {param: value}, action)
        self.processes: list = []    # (cmd list, action)
        self.logs: list = []         # LogInfo texts
        self.shutdowns: list = []    # Shutdown reasons
        self.exit_targets: list = []  # actions with their own on_exit
        self.handlers: list = []      # registered event handlers
        self.arguments: dict = {}


def _yaml_params(path: str, node_name: str) -> dict:
    doc = yaml.safe_load(Path(path).read_text()) or {}
    section = doc.get(node_name, doc.get("/**", {})).get("ros__parameters", {})
    flat: dict = {}

    def walk(prefix, d):
        for k, v in d.items():
            if isinstance(v, dict):
                walk(f"{prefix}{k}.", v)
            else:
                flat[prefix + k] = v
    walk("", section)
    return flat


def _node_params(node, context, name: str) -> dict:
    from launch_ros.utilities import evaluate_parameters
    params: dict = {}
    for entry in evaluate_parameters(context, node._Node__parameters or []):
        if isinstance(entry, dict):
            params.update(entry)
        else:                               # a parameter file
            assert Path(entry).is_file(), f"missing parameter file {entry}"
            params.update(_yaml_params(str(entry), name))
    return params


def evaluate(launch_file: str, args: dict) -> Evaluated:
    """Walk ``launch/<launch_file>`` with ``args`` as ``ros2 launch`` would (no processes)."""
    from launch import LaunchContext
    from launch.actions import (DeclareLaunchArgument, ExecuteProcess, GroupAction, LogInfo,
                                OpaqueFunction, RegisterEventHandler, Shutdown)
    from launch.utilities import perform_substitutions
    from launch_ros.actions import Node

    from aslip_ros.launch_support.common import LaunchFailed
    ns = runpy.run_path(str(ROOT / "launch" / launch_file))
    desc = ns["generate_launch_description"]()
    context = LaunchContext()
    out = Evaluated()

    def sub(value):
        return perform_substitutions(context, value) if isinstance(value, list) else value

    def visit(entity) -> None:
        condition = getattr(entity, "condition", None)
        if condition is not None and not condition.evaluate(context):
            return
        if isinstance(entity, DeclareLaunchArgument):
            if entity.name in args:
                value = str(args[entity.name])
            elif entity.default_value is not None:
                value = perform_substitutions(context, entity.default_value)
            else:
                raise AssertionError(f"{launch_file}: required argument {entity.name!r} "
                                     "not given")
            context.launch_configurations[entity.name] = value
            out.arguments[entity.name] = value
        elif isinstance(entity, Node):
            exe = sub(entity._Node__node_executable)
            name = sub(entity._Node__node_name) if entity._Node__node_name else exe
            out.nodes.append((exe, name, _node_params(entity, context, name), entity))
            if getattr(entity, "_ExecuteLocal__on_exit", None) is not None:
                out.exit_targets.append(entity)
        elif isinstance(entity, ExecuteProcess):
            out.processes.append(([sub(c) for c in entity.cmd], entity))
        elif isinstance(entity, LogInfo):
            out.logs.append(sub(entity.msg))
        elif isinstance(entity, Shutdown):
            out.shutdowns.append(entity)
        elif isinstance(entity, RegisterEventHandler):
            out.handlers.append(entity.event_handler)
        elif isinstance(entity, OpaqueFunction):
            try:
                entities = entity.execute(context) or []
            except LaunchFailed as exc:          # fail(): the launch ends, exit code 1
                out.shutdowns.append(exc)
                return
            for e in entities:
                visit(e)
        elif isinstance(entity, GroupAction):
            for e in entity.get_sub_entities():
                visit(e)
        else:
            for e in entity.describe_sub_entities():
                visit(e)

    for e in desc.entities:
        visit(e)
    return out


def _type_error(spec, value):
    """Why rclpy would refuse ``value`` for a parameter declared with ``spec.default``."""
    want = spec.default

    def same(a, b):
        if isinstance(a, bool) or isinstance(b, bool):
            return isinstance(a, bool) and isinstance(b, bool)
        return type(a) is type(b)
    if isinstance(want, (list, tuple)):
        if not isinstance(value, (list, tuple)):
            return f"is {type(value).__name__}, declared a list"
        if want and value and not all(same(v, want[0]) for v in value):
            return f"has items {[type(v).__name__ for v in value]}, declared " \
                   f"{type(want[0]).__name__}"
        return None
    if not same(value, want):
        return f"is {type(value).__name__} {value!r}, declared {type(want).__name__}"
    return None


def check_parameters(ev: Evaluated) -> None:
    """Every node parameter is declared, of the declared type and valid."""
    from aslip_ros.node_table import nodes
    from aslip_ros.nodes.introspect import declared_by_name
    problems = []
    for exe, name, params, _ in ev.nodes:
        exe = exe if exe in nodes() else name          # a registered node: the interpreter
        if exe not in nodes():
            continue                                   # rviz2: not ours
        declared = declared_by_name(exe)
        for key, value in params.items():
            spec = declared.get(key)
            if spec is None:
                problems.append(f"{name}: {key} is not a parameter of {exe}")
                continue
            err = _type_error(spec, value)
            if err is None and spec.check is not None:
                err = spec.check(list(value) if isinstance(value, tuple) else value)
            if err:
                problems.append(f"{name}: {key} {err}")
    assert not problems, "\n".join(problems)


def handles_exit(ev: Evaluated, action) -> bool:
    """Whether ``action``'s exit triggers something (its on_exit or a registered handler)."""
    from launch.events.process import ProcessExited
    if any(action is t for t in ev.exit_targets):
        return True
    event = ProcessExited(action=action, name="x", cmd=[], cwd=None, env=None, pid=0,
                          returncode=0)
    return any(h.matches(event) for h in ev.handlers)


def _by_exe(ev: Evaluated) -> dict:
    return {exe: params for exe, _, params, _ in ev.nodes}


LAUNCHES = [
    ("slip_stop.launch.py", {}),
    ("slip_stop.launch.py", {"rviz": "true", "direction": "[1.0, 0.0, 0.0]"}),
    ("slip_stop.launch.py", {"scenario": "pivot"}),
    ("slip_stop.launch.py", {"sim": "false", "audio_device": "0", "autostart": "false",
                             "checkpoint": "my_model.pt"}),
    ("slip_track.launch.py", {}),
    ("slip_track.launch.py", {"sim": "false", "audio_device": "UMC404HD", "gain": "1",
                              "checkpoint": "my_model.pt", "channel_names": "[a,b]"}),
    ("slip_track.launch.py", {"input_timeout_s": "0.1"}),
    ("data_collection.launch.py", {}),
    ("data_collection.launch.py", {"sim": "false", "record": "false", "audio_device": "0"}),
    ("data_collection.launch.py", {"recorder": "aslip", "duration_s": "0"}),
    ("export.launch.py", {"bag": "b", "out": "o"}),
    ("rviz.launch.py", {}),
]


@needs_launch
@pytest.mark.parametrize("launch_file,args", LAUNCHES,
                         ids=[f"{f}-{'-'.join(a) or 'defaults'}" for f, a in LAUNCHES])
def test_every_node_parameter_is_declared_typed_and_valid(launch_file, args):
    check_parameters(evaluate(launch_file, args))


@needs_launch
def test_parameter_check_catches_a_wrong_type():
    """The check itself fails on what rclpy refuses (an int for a double, an unknown name)."""
    ev = evaluate("slip_track.launch.py", {})
    exe, name, params, node = next(n for n in ev.nodes if n[0] == "slip_track")
    ev.nodes = [(exe, name, dict(params, gain=1), node)]
    with pytest.raises(AssertionError, match="gain is int"):
        check_parameters(ev)
    ev.nodes = [(exe, name, {"gian": 1.0}, node)]
    with pytest.raises(AssertionError, match="not a parameter"):
        check_parameters(ev)


@needs_launch
@pytest.mark.parametrize("launch_file", ["slip_stop.launch.py", "slip_track.launch.py"])
def test_closed_loop_defaults_use_the_shipped_model(launch_file):
    from ament_index_python.packages import get_package_share_directory
    ev = evaluate(launch_file, {})
    nodes = _by_exe(ev)
    # A node of the loop that exits ends the launch rather than leaving a half graph.
    assert all(handles_exit(ev, n[3]) for n in ev.nodes)
    ckpt = nodes["slip_inference"]["checkpoint"]
    share = get_package_share_directory("aslip_ros")
    # Both tasks run the package's one default estimator, the one make demo runs as aslip.
    from aslip_ros.node_table import DEFAULT_MODEL
    from benchmarks import demo_models
    assert ckpt == os.path.join(share, "models", DEFAULT_MODEL)
    assert demo_models.DEFAULT == "aslip" and demo_models.DEFAULT_NAME == DEFAULT_MODEL
    assert Path(ckpt).is_file(), f"{ckpt} is not installed"
    assert {"scene_sim", "slip_inference", "mocap_bridge", launch_file.split(".")[0]} == \
        set(nodes)


@needs_launch
def test_slip_stop_runs_the_pivot_scene_on_request():
    assert _by_exe(evaluate("slip_stop.launch.py", {}))["scene_sim"]["scenario"] == "wall_push"
    assert _by_exe(evaluate("slip_stop.launch.py",
                            {"scenario": "pivot"}))["scene_sim"]["scenario"] == "pivot"


@needs_launch
@pytest.mark.parametrize("launch_file", ["slip_stop.launch.py", "slip_track.launch.py"])
def test_the_watchdog_timeout_is_a_launch_argument(launch_file):
    from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S
    task = launch_file.split(".")[0]
    default = _by_exe(evaluate(launch_file, {}))[task]
    assert (default["slip_timeout_s"], default["pose_timeout_s"]) == (DEFAULT_TIMEOUT_S,) * 2
    given = _by_exe(evaluate(launch_file, {"input_timeout_s": "0.25"}))[task]
    assert (given["slip_timeout_s"], given["pose_timeout_s"]) == (0.25, 0.25)


@needs_launch
@pytest.mark.parametrize("launch_file,args", [
    ("slip_stop.launch.py", {"sim": "false", "audio_device": "0", "checkpoint": "m.pt"}),
    ("data_collection.launch.py", {"sim": "false", "record": "false", "audio_device": "0"})])
def test_a_numeric_audio_device_stays_a_string(launch_file, args):
    capture = _by_exe(evaluate(launch_file, args))["audio_capture"]
    assert capture["device"] == "0"


@needs_launch
def test_data_collection_metadata_is_json_text():
    nodes = _by_exe(evaluate("data_collection.launch.py",
                             {"sim": "false", "record": "false", "object": "pla_rod"}))
    meta = json.loads(nodes["audio_capture"]["metadata_json"])
    assert meta["object"] == "pla_rod" and meta["induced"] == "external"


@needs_launch
def test_data_collection_records_every_topic_and_ends_with_the_scene():
    from aslip_ros.nodes import common as c
    ev = evaluate("data_collection.launch.py", {"recorder": "aslip"})
    nodes = _by_exe(ev)
    topics = set(nodes["bag_recorder"]["topics"])
    assert {c.AUDIO_TOPIC, c.FINGER_TOPIC, c.OBJECT_TOPIC, c.TCP_TOPIC, c.METADATA_TOPIC,
            c.SLIP_TRUTH_TOPIC, "/tf", "/tf_static"} <= topics
    assert nodes["scene_sim"]["duration_s"] == 30.0
    assert nodes["scene_sim"]["exit_when_done"] is True
    # Their exits end the launch (the scene's run is over / nothing is recorded any more).
    watched = {n[1] for n in ev.nodes if handles_exit(ev, n[3])}
    assert {"scene_sim", "bag_recorder", "mocap_bridge"} <= watched, watched
    endless = _by_exe(evaluate("data_collection.launch.py", {"duration_s": "0"}))
    assert endless["scene_sim"]["exit_when_done"] is False


# -- a lab's cell (issue: the documented hardware path) --------------------------------

CELL = """\
audio_capture:
  device: "rig_pcm"
  channel_names: [pad_a, pad_b]
mocap_bridge:
  finger_topic: /natnet/finger/pose
  object_topic: /natnet/object/pose
  grasp_plane_in_finger: [0.01, 0.0, 0.05, 0, 0, 0, 1]
arm:
  xarm_ip: 10.0.0.7
  arm_max_speed_m_s: 0.05
  arm_workspace_min_m: [0.2, -0.3, 0.05]
  arm_workspace_max_m: [0.6, 0.3, 0.5]
  grasp_plane_in_tcp: [0, 0, 0.17, 0, 0, 0, 1]
slip_stop:
  approach_speed_m_s: 0.005
"""

HW = {"sim": "false", "checkpoint": "my_model.pt"}


@pytest.fixture
def cell(tmp_path):
    path = tmp_path / "lab_cell.yaml"
    path.write_text(CELL)
    return str(path)


@needs_launch
def test_the_data_collection_records_the_pose_topics_the_graph_uses(cell):
    """A driver publishing on its own names: those are recorded (with /tf_static and the
    metadata), not the contract's defaults nobody publishes."""
    for args in ({"cell": cell}, {"finger_topic": "/natnet/finger/pose",
                                  "object_topic": "/natnet/object/pose"}):
        ev = evaluate("data_collection.launch.py", dict(args, sim="false", recorder="aslip"))
        nodes = _by_exe(ev)
        rec = nodes["bag_recorder"]
        assert {"/natnet/finger/pose", "/natnet/object/pose", "/tf_static",
                "/aslip/metadata", "/aslip/audio"} <= set(rec["topics"]), rec["topics"]
        assert "/aslip/mocap/finger" not in rec["topics"]
        assert set(rec["pose_topics"]) == {"/natnet/finger/pose", "/natnet/object/pose"}
        assert rec["duration_s"] == 30.0        # the trial's length counts recorded audio
        bridge = nodes["mocap_bridge"]
        assert (bridge["finger_topic"], bridge["object_topic"]) == \
            ("/natnet/finger/pose", "/natnet/object/pose")
        check_parameters(ev)


@needs_launch
def test_a_hardware_recording_waits_for_the_latched_topics_the_cells_nodes_publish(
        cell, tmp_path):
    """audio_capture latches the metadata and mocap_bridge the calibration on /tf_static:
    the timed recording does not end without them (a CI run's 3 s trial lost /tf_static).
    A cell whose bridge publishes no TF owes none; the scene's recording is not timed."""
    rec = _by_exe(evaluate("data_collection.launch.py",
                           {"sim": "false", "cell": cell, "recorder": "aslip"}))["bag_recorder"]
    assert set(rec["latched_due"]) == {"/aslip/metadata", "/tf_static"}
    quiet = tmp_path / "no_tf_cell.yaml"
    quiet.write_text(CELL.replace("mocap_bridge:\n", "mocap_bridge:\n  publish_tf: false\n"))
    ev = evaluate("data_collection.launch.py",
                  {"sim": "false", "cell": str(quiet), "recorder": "aslip"})
    assert list(_by_exe(ev)["bag_recorder"]["latched_due"]) == ["/aslip/metadata"]
    check_parameters(ev)
    sim = _by_exe(evaluate("data_collection.launch.py", {"recorder": "aslip"}))
    assert list(sim["bag_recorder"]["latched_due"]) == [""]


@needs_launch
def test_the_metadata_of_a_hardware_recording_carries_the_cells_calibration(cell):
    nodes = _by_exe(evaluate("data_collection.launch.py",
                             {"sim": "false", "record": "false", "cell": cell}))
    meta = json.loads(nodes["audio_capture"]["metadata_json"])
    assert meta["grasp_plane_in_finger"] == [0.01, 0.0, 0.05, 0.0, 0.0, 0.0, 1.0]
    assert meta["grasp_plane_in_tcp"] == [0.0, 0.0, 0.17, 0.0, 0.0, 0.0, 1.0]
    assert meta["topics"]["finger"] == "/natnet/finger/pose"
    assert nodes["mocap_bridge"]["calibration"] == "param"
    assert list(nodes["mocap_bridge"]["grasp_plane_in_finger"]) == meta["grasp_plane_in_finger"]


@needs_launch
@pytest.mark.parametrize("names", [["solo"], ["pad_a", "pad_b"], ["a", "b", "c", "d"]])
def test_channel_names_are_a_launch_argument_for_1_2_and_4_microphones(names):
    for launch_file, extra in (("data_collection.launch.py", {"record": "false"}),
                               ("slip_stop.launch.py", {"checkpoint": "m.pt"})):
        ev = evaluate(launch_file, dict(extra, sim="false",
                                        channel_names="[" + ",".join(names) + "]"))
        capture = _by_exe(ev)["audio_capture"]
        assert list(capture["channel_names"]) == names and capture["channels"] == len(names)
        check_parameters(ev)
    two = _by_exe(evaluate("data_collection.launch.py",
                           {"sim": "false", "record": "false", "channels": "2"}))
    assert list(two["audio_capture"]["channel_names"]) == ["ch0", "ch1"]


@needs_launch
@pytest.mark.parametrize("launch_file", ["slip_stop.launch.py", "slip_track.launch.py"])
def test_every_closed_loop_takes_the_cells_limits_and_grasp_plane(cell, launch_file):
    task = launch_file.split(".")[0]
    ev = evaluate(launch_file, dict(HW, cell=cell))
    nodes = _by_exe(ev)
    ctrl = nodes[task]
    assert ctrl["arm"] == "xarm" and ctrl["xarm_ip"] == "10.0.0.7"
    assert ctrl["arm_max_speed_m_s"] == 0.05
    assert list(ctrl["arm_workspace_min_m"]) == [0.2, -0.3, 0.05]
    assert list(ctrl["grasp_plane_in_tcp"]) == [0.0, 0.0, 0.17, 0.0, 0.0, 0.0, 1.0]
    assert list(nodes["audio_capture"]["channel_names"]) == ["pad_a", "pad_b"]
    assert nodes["audio_capture"]["device"] == "rig_pcm"
    if task == "slip_stop":
        assert ctrl["approach_speed_m_s"] == 0.005
    check_parameters(ev)
    # A launch argument given overrides the cell.
    ip = _by_exe(evaluate(launch_file, dict(HW, cell=cell, xarm_ip="10.0.0.9")))[task]
    assert ip["xarm_ip"] == "10.0.0.9"


@needs_launch
@pytest.mark.parametrize("launch_file", ["slip_stop.launch.py", "slip_track.launch.py"])
def test_hardware_refuses_to_run_the_scenes_model(launch_file):
    ev = evaluate(launch_file, {"sim": "false"})
    assert ev.shutdowns and not ev.nodes
    assert any("checkpoint:=" in m and "simulated scene" in m for m in ev.logs), ev.logs


@needs_launch
@pytest.mark.parametrize("text,needle", [
    ("arm:\n  arm_max_speed: 0.05\n", "unknown key 'arm_max_speed'"),
    ("arm:\n  arm_max_speed_m_s: 5.0\n", "arm_max_speed_m_s"),
    ("slip_stop:\n  aproach_speed_m_s: 0.01\n", "'aproach_speed_m_s' is not a parameter"),
    ("slip_stop:\n  xarm_ip: 1.2.3.4\n", "belongs in the 'arm' section"),
    ("grippers: {}\n", "unknown section 'grippers'"),
    ("- not a mapping\n", "must be a mapping")])
def test_a_wrong_cell_file_stops_every_launch_before_anything_starts(tmp_path, text, needle):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    for launch_file, extra in (("slip_stop.launch.py", HW), ("slip_track.launch.py", HW),
                               ("data_collection.launch.py", {"sim": "false"})):
        ev = evaluate(launch_file, dict(extra, cell=str(path)))
        assert ev.shutdowns and not ev.nodes, launch_file
        assert any(needle in m and "bad.yaml" in m for m in ev.logs), (needle, ev.logs)


@needs_launch
def test_robot_induced_recording_on_hardware_sweeps_the_arm_within_the_cells_limits(cell):
    ev = evaluate("data_collection.launch.py", {"sim": "false", "cell": cell,
                                                "induced": "robot", "duration_s": "20",
                                                "recorder": "aslip"})
    nodes = _by_exe(ev)
    sweeps = nodes["robot_sweeps"]
    assert sweeps["arm"] == "xarm" and sweeps["arm_max_speed_m_s"] == 0.05
    assert sweeps["duration_s"] == 20.0 and sweeps["exit_when_done"] is True
    meta = json.loads(nodes["audio_capture"]["metadata_json"])
    assert meta["induced"] == "robot" and meta["condition"] == "robot_moving"
    assert "/aslip/robot/tcp_pose" in nodes["bag_recorder"]["topics"]
    assert any(handles_exit(ev, n[3]) for n in ev.nodes if n[0] == "robot_sweeps")
    check_parameters(ev)


def _started_once_ready(ev: Evaluated, exe: str) -> list:
    """What the launch starts once node ``exe`` prints its readiness line."""
    from launch import LaunchContext
    from launch.events.process import ProcessStderr
    from launch.event_handlers import OnProcessIO
    node = next(n[3] for n in ev.nodes if n[0] == exe)
    event = ProcessStderr(text=f"[INFO] [0.0] [{exe}]: ready: x\n".encode(),
                          action=node, name=exe, cmd=[], cwd=None, env=None, pid=0)
    return [a for h in ev.handlers if isinstance(h, OnProcessIO) and h.matches(event)
            for a in h.handle(event, LaunchContext()) or ()]


@needs_launch
@pytest.mark.parametrize("recorder", ["aslip", "ros2bag"])
def test_a_hardware_trial_is_watched_with_the_cells_thresholds(
        cell, tmp_path, monkeypatch, recorder):
    """stream_watch (#34: a failed recording fails) starts once audio_capture is ready,
    watches the audio and the cell's pose topics with the cell's thresholds, and ends a
    ros2 bag trial duration_s after every stream is in; a threshold out of its declared
    range stops the launch before anything starts. rosbag2 is no wheel: its stand-in
    (test/helpers/fake_ros2bag) makes the launch take the ros2 bag route."""
    from launch import LaunchContext
    from launch.actions import RegisterEventHandler
    from launch_ros.actions import Node
    fake = HELPERS / "fake_ros2bag"
    monkeypatch.setenv("PATH", f"{fake / 'bin'}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("AMENT_PREFIX_PATH",
                       f"{fake}{os.pathsep}{os.environ['AMENT_PREFIX_PATH']}")
    path = tmp_path / "watched.yaml"
    path.write_text(Path(cell).read_text() + "stream_watch:\n  stall_timeout_s: 2\n")
    ev = evaluate("data_collection.launch.py", {"sim": "false", "cell": str(path),
                                                "duration_s": "20", "recorder": recorder})
    assert not ev.shutdowns, ev.logs
    bagged = any(cmd[:3] == ["ros2", "bag", "record"] for cmd, _ in ev.processes)
    assert bagged == (recorder == "ros2bag"), ev.processes
    started = _started_once_ready(ev, "audio_capture")
    (watch,) = [a for a in started if isinstance(a, Node)]
    assert watch._Node__node_executable == "stream_watch"      # installed (ASLIP_NODES)
    params = _node_params(watch, LaunchContext(), "stream_watch")
    assert list(params["topics"]) == ["/aslip/audio", "/natnet/finger/pose",
                                      "/natnet/object/pose"]
    assert params["stall_timeout_s"] == 2.0
    assert params["duration_s"] == (20.0 if recorder == "ros2bag" else 0.0)
    # Ending a ros2 bag trial, it waits for the latched topics the cell's nodes publish.
    assert set(params["latched_due"]) == ({"/aslip/metadata", "/tf_static"}
                                          if recorder == "ros2bag" else {""})
    assert any(isinstance(a, RegisterEventHandler) for a in started)
    assert _by_exe(ev)["audio_capture"]["exit_on_error"] is True
    path.write_text(Path(cell).read_text() + "stream_watch:\n  stall_timeout_s: 100\n")
    bad = evaluate("data_collection.launch.py", {"sim": "false", "cell": str(path)})
    assert bad.shutdowns and not bad.nodes
    assert any("stall_timeout_s" in m for m in bad.logs), bad.logs


@needs_launch
def test_data_collection_refuses_a_missing_ros2bag_loudly():
    ev = evaluate("data_collection.launch.py", {"recorder": "ros2bag"})
    if not ev.shutdowns:
        pytest.skip("rosbag2 is installed here")
    assert any("rosbag2" in m and m.startswith("ERROR") for m in ev.logs), ev.logs
    assert "bag_recorder" not in _by_exe(ev)


@needs_launch
def test_rviz_is_started_only_where_installed():
    from aslip_ros.launch_support.common import rviz_found
    for launch_file, args in (("rviz.launch.py", {}), ("slip_track.launch.py", {"rviz": "true"})):
        ev = evaluate(launch_file, args)
        started = "rviz2" in _by_exe(ev)
        assert started == rviz_found()
        if not rviz_found():
            assert any("rviz2 is not installed" in m for m in ev.logs), ev.logs
    assert "rviz2" not in _by_exe(evaluate("slip_track.launch.py", {}))


@needs_launch
def test_export_runs_the_cli_of_the_launching_interpreter():
    ev = evaluate("export.launch.py", {"bag": "in", "out": "ds", "window": "0.1"})
    (cmd, _), = ev.processes
    assert cmd[:4] == [sys.executable, "-m", "aslip_ros.cli", "export"]
    assert cmd[4:] == ["in", "-o", "ds", "--window", "0.1", "--hop", "0.1", "--jobs", "1",
                       "--no-progress"]
    (cmd, _), = evaluate("export.launch.py", {"bag": "in", "out": "ds", "jobs": "2"}).processes
    assert cmd[cmd.index("--jobs") + 1] == "2"


@needs_launch
def test_export_requires_its_arguments():
    with pytest.raises(AssertionError, match="required argument 'bag'"):
        evaluate("export.launch.py", {})


# ------------------------------------------------------------------- process behaviour

def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:    # a zombie has exited; only its parent has not reaped it yet
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def _wait_gone(pids, timeout: float) -> list:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        left = [p for p in pids if _alive(p)]
        if not left:
            return []
        time.sleep(0.2)
    return [p for p in pids if _alive(p)]


def test_a_node_dies_with_its_parent(ros_env, tmp_path):
    """A node whose parent is killed outright (SIGKILL: no chance to stop it) exits."""
    from ament_index_python.packages import get_package_prefix
    exe = Path(get_package_prefix("aslip_ros")) / "lib" / "aslip_ros" / "scene_sim"
    log = tmp_path / "node.log"
    parent = subprocess.Popen(
        [sys.executable, "-c",
         "import subprocess, sys, time\n"
         f"p = subprocess.Popen([{str(exe)!r}], stdout=open({str(log)!r}, 'w'), "
         "stderr=subprocess.STDOUT)\n"
         "print(p.pid, flush=True)\n"
         "time.sleep(600)\n"],
        env=ros_env, stdout=subprocess.PIPE, text=True)
    child = None
    try:
        child = int(parent.stdout.readline())
        assert _wait_text(log, "ready", 120), log.read_text()
        parent.kill()
        parent.wait(timeout=10)
        assert _wait_gone([child], 30.0) == [], "the node outlived its parent"
    finally:
        parent.kill()
        if child is not None and _alive(child):
            os.kill(child, signal.SIGKILL)


def test_a_node_stuck_inside_a_c_call_still_exits_after_a_signal(ros_env):
    """The main thread blocked in C for good (a relocked mutex: no signal interrupts it): the
    node still starts its forced exit on SIGINT, because signals are taken on a thread of
    their own, and exits before the launch would escalate to SIGKILL."""
    code = (
        "import ctypes\n"
        "from rclpy.node import Node\n"
        "from aslip_ros.runtime.process import ready, run_node\n"
        "libc = ctypes.CDLL(None)\n"
        "mutex = ctypes.create_string_buffer(64)      # PTHREAD_MUTEX_INITIALIZER: zeros\n"
        "class Stuck(Node):\n"
        "    def __init__(self):\n"
        "        super().__init__('stuck_in_c')\n"
        "        self.create_timer(0.5, self.tick)\n"
        "        ready(self)\n"
        "    def tick(self):\n"
        "        print('stuck now', flush=True)\n"
        "        libc.pthread_mutex_lock(mutex)\n"
        "        libc.pthread_mutex_lock(mutex)        # a default mutex: never returns\n"
        "raise SystemExit(run_node(Stuck))\n")
    proc = subprocess.Popen([sys.executable, "-c", code], env=ros_env, cwd=str(HELPERS),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        end = time.monotonic() + 60
        seen = ""
        while "stuck now" not in seen and time.monotonic() < end and proc.poll() is None:
            seen += proc.stdout.readline()
        assert "stuck now" in seen, seen
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            raise AssertionError("the node ignored SIGINT for 30 s") from None
        took = time.monotonic() - t0
        assert "exiting now" in out
        assert took < 9.0, f"exit took {took:.1f} s"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def test_a_node_whose_cleanup_hangs_still_exits_after_a_signal(ros_env):
    """Launch escalates to SIGKILL 10 s after SIGINT; a node exits well before that."""
    code = (
        "import time\n"
        "from rclpy.node import Node\n"
        "from aslip_ros.runtime.process import ready, run_node\n"
        "class Stuck(Node):\n"
        "    def __init__(self):\n"
        "        super().__init__('stuck')\n"
        "        ready(self)\n"
        "    def before_shutdown(self):\n"
        "        time.sleep(60)\n"
        "raise SystemExit(run_node(Stuck))\n")
    proc = subprocess.Popen([sys.executable, "-c", code], env=ros_env, cwd=str(HELPERS),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        end = time.monotonic() + 60
        seen = ""
        while "ready" not in seen and time.monotonic() < end:
            seen += proc.stdout.readline()
        assert "ready" in seen, seen
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        took = time.monotonic() - t0
        assert "exiting now" in out
        assert took < 9.0, f"exit took {took:.1f} s"
    finally:
        proc.kill()


def _ros2_launch(args, env, out_path):
    from shutil import which
    ros2 = which("ros2", path=env.get("PATH"))
    if LAUNCH_MISSING is not None or ros2 is None:
        pytest.skip(LAUNCH_MISSING or "`ros2` is not on PATH")
    # start_new_session: the launch gets SIGINT like a terminal's Ctrl-C would send it,
    # not ignored as in a background job.
    return subprocess.Popen([ros2, "launch", "aslip_ros", *args], env=env,
                            stdout=open(out_path, "w"), stderr=subprocess.STDOUT,
                            start_new_session=True)


def _started_pids(log: Path) -> list:
    import re
    return [int(m) for m in re.findall(r"process started with pid \[(\d+)\]", log.read_text())]


def _wait_text(log: Path, text: str, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if text in log.read_text():
            return True
        time.sleep(0.25)
    return False


def test_a_suite_started_in_the_background_starts_interruptible_children():
    """A suite run as `make test &` inherits SIGINT ignored; ros2 launch, started from it,
    then ignored the SIGINT of the test above and ran until killed (60 s, every time, in a
    background run). conftest gives the suite's children a terminal's SIGINT."""
    child = ("import signal, subprocess, sys\n"
             f"sys.path.insert(0, {str(ROOT / 'test')!r})\n"
             "import conftest\n"
             "print(subprocess.run([sys.executable, '-c', 'import signal; "
             "print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN)'], "
             "capture_output=True, text=True).stdout.strip())\n")
    out = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True,
                         timeout=120,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "False", out.stdout


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_ros2_launch_leaves_no_node_behind(ros_env, tmp_path, sig):
    """slip_stop with rviz:=true (rviz2 missing or not): the graph runs until the launch is
    stopped, then no node of it is left, on SIGINT and on SIGTERM alike."""
    log = tmp_path / "launch.log"
    proc = _ros2_launch(["slip_stop.launch.py", "rviz:=true"], ros_env, log)
    pids = []
    try:
        assert _wait_text(log, "slip-stop trial started", 150), log.read_text()[-3000:]
        pids = _started_pids(log)
        assert len(pids) >= 4
        assert proc.poll() is None, "the launch ended by itself"
        proc.send_signal(sig)
        proc.wait(timeout=60)
        left = _wait_gone(pids, 30.0)
        assert left == [], f"nodes left running after {sig.name}: {left}\n" + \
            log.read_text()[-3000:]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        for p in pids:
            if _alive(p):
                os.kill(p, signal.SIGKILL)


@pytest.mark.slow
def test_a_failing_recorder_shuts_data_collection_down(ros_env, tmp_path):
    """The recorder refuses an existing bag: the launch must end by itself, saying why."""
    bag = tmp_path / "bag"
    bag.mkdir()
    log = tmp_path / "launch.log"
    proc = _ros2_launch(["data_collection.launch.py", "recorder:=aslip", "duration_s:=0",
                         f"bag:={bag}"], ros_env, log)
    try:
        proc.wait(timeout=150)
        text = log.read_text()
        assert "the recorder (aslip) exited with code 2" in text, text[-3000:]
        assert proc.returncode == 1, text[-3000:]      # a script sees the failure
        assert _wait_gone(_started_pids(log), 30.0) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.slow
def test_a_finite_data_collection_ends_by_itself_with_its_bag(ros_env, tmp_path):
    """duration_s:=3: the launch ends once the scene has run, leaving a complete bag."""
    from aslip_ros.data.bags import BagReader
    bag = tmp_path / "bag"
    log = tmp_path / "launch.log"
    proc = _ros2_launch(["data_collection.launch.py", "recorder:=aslip", "duration_s:=3",
                         f"bag:={bag}"], ros_env, log)
    try:
        proc.wait(timeout=150)
        text = log.read_text()
        assert "collection finished" in text, text[-3000:]
        assert _wait_gone(_started_pids(log), 30.0) == []
        with BagReader(bag) as reader:
            audio = dict(reader.info.counts).get("/aslip/audio", 0)
        assert audio >= 150, f"{audio} audio blocks for 3 s of scene\n" + text[-3000:]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
