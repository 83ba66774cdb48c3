"""The closed-loop graph shared by ``slip_stop.launch.py`` and ``slip_track.launch.py``.

Imported only by launch files (it needs ``launch`` and ``launch_ros``, which a full ROS 2
install provides): the scene or the audio interface, slip_inference, mocap_bridge, the
task's controller and, optionally, rviz. Also the pieces every launch file of the package
shares: :func:`share_dir`, :func:`rviz_actions`, and the lab's cell file (``cell:=``,
:mod:`aslip_ros.cell`) with the hardware launch arguments that override it
(:func:`cell_arguments`, :func:`capture_params`, :func:`mocap_topics`,
:func:`rigid_bodies_source`, :func:`arm_params`).
Precedence, for every node parameter: the node's config/*.yaml, then the cell file, then a
launch argument that is given (an empty argument leaves the value to the cell).
"""

import json
import os
import shutil

from ament_index_python.packages import PackageNotFoundError, get_package_prefix
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, LogInfo, OpaqueFunction, Shutdown
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration as LC
from launch_ros.actions import Node

import yaml

from aslip_ros import topics
from aslip_ros.cell import NODE_SECTIONS, Cell, CellError, load_cell
from aslip_ros.nodes import common as c
from aslip_ros.nodes.introspect import declared_by_name

#: The checkpoint each closed-loop launch uses when none is given (shipped in
#: share/aslip_ros/models), the one that did the task best in ``make demo`` (docs/demo.md):
#: slip-stop the streaming estimator (``aslip``: 50/50, slip onset to stop 37 ms median
#: against the window CNN's 49/50 and 47 ms), slip-track the 200 ms window CNN
#: (``aslip_window``: 7.3 mm pose RMSE against the streaming model's 15.8 mm).
DEFAULT_MODELS = {"slip_stop": "aslip_stream.pt", "slip_track": "aslip_cnn.pt"}


def share_dir() -> str:
    """The installed ``share/aslip_ros`` (config, launch files, models)."""
    return get_package_share_directory("aslip_ros")


def default_checkpoint(controller: str) -> str:
    """Path of the controller's shipped demo checkpoint in the install's share directory."""
    return os.path.join(share_dir(), "models", DEFAULT_MODELS[controller])


def rviz_found() -> bool:
    """Whether rviz2 is installed (as a ROS package or on PATH)."""
    try:
        get_package_prefix("rviz2")
        return True
    except PackageNotFoundError:
        return shutil.which("rviz2") is not None


def rviz_actions(condition=None) -> list:
    """rviz with the package's view of this graph, or a log line when rviz2 is missing.

    The view is config/aslip.rviz with the graph's pose topics (the cell's, a launch
    argument's), written by :func:`aslip_ros.nodes.rviz_view.write_view` (also without
    rviz2, for an rviz started elsewhere). A missing rviz2 must not take down a graph that
    is already commanding an arm: launch_ros would fail the whole launch on an unknown
    package, so rviz is only added when found. rviz exiting (its window closed) leaves the
    rest running.
    """
    return [OpaqueFunction(function=_rviz, condition=condition)]


def _rviz(context) -> list:
    from aslip_ros.nodes.rviz_view import write_view
    try:
        cell = load_checked_cell(arg(context, "cell"))
    except (CellError, ValueError) as exc:
        return fail(str(exc))
    finger, obj = mocap_topics(context, cell)
    if cell.get("mocap_bridge", "pose_source", "") == "rigid_bodies":
        finger = obj = None             # no PoseStamped for rviz's Pose displays (mocap4r2)
    placed = flag(context, "sim") or bool(cell.get("mocap_bridge", "publish_base_tf", False))
    cfg, notes = write_view(os.path.join(share_dir(), "config", "aslip.rviz"), finger, obj,
                            placed)
    out = [LogInfo(msg=f"rviz view: {cfg}")] + [LogInfo(msg=f"rviz: {n}") for n in notes]
    if rviz_found():
        return out + [Node(package="rviz2", executable="rviz2", name="rviz2",
                           arguments=["-d", str(cfg)], output="screen")]
    return out + [LogInfo(msg="rviz2 is not installed: running without rviz (install "
                              "ros-jazzy-rviz2 to see the slip arrows)")]


class LaunchFailed(RuntimeError):
    """Raised inside the launch to end it with exit code 1 (a Shutdown exits 0)."""


def fail(why: str) -> list:
    """Log ``why`` as an error and end the launch with exit code 1: ``ros2 launch`` exits 0
    after a Shutdown action, so a script recording trial after trial (`set -e`, a loop)
    would go on after a failed one. The launch service turns an exception raised by an
    action into a shutdown with that reason and exit code 1."""
    def raise_(context):
        raise LaunchFailed(why)
    return [LogInfo(msg=f"ERROR: {why}"), OpaqueFunction(function=raise_)]


def required(event, context):
    """``on_exit`` of a node the graph cannot work without: its exit ends the launch.

    A closed loop without one of its nodes stops the arm through the watchdogs but would
    otherwise sit there looking alive; the launch says which node ended and why it stops.
    """
    if context.is_shutdown:
        return None
    if event.returncode == 0:        # a task that ended (exit_when_done), not a failure
        why = f"{event.action.name} finished; shutting down the graph"
        return [LogInfo(msg=why), Shutdown(reason=why)]
    return fail(f"{event.action.name} exited with code {event.returncode}; shutting down "
                "the graph")


def load_checked_cell(path: str) -> Cell:
    """:func:`aslip_ros.cell.load_cell`, and every key and value checked against what its
    node declares (name, type, range): a typo or an out-of-range limit is refused at launch,
    before anything starts, instead of being ignored by the node. Integers given for
    floating-point parameters become floats (YAML writes ``1`` for ``1.0``)."""
    cell = load_cell(path)
    problems, sections = [], {}
    for name, body in cell.sections.items():
        if name not in NODE_SECTIONS:
            sections[name] = body
            continue
        declared, checked = declared_by_name(name), {}
        for key, value in body.items():
            spec = declared.get(key)
            if spec is None:
                problems.append(f"{name}: {key!r} is not a parameter of {name}")
                continue
            value = _as_type(spec.default, value)
            err = c.check_value(spec, value)
            if err:
                problems.append(f"{name}: {key}: {err}")
            checked[key] = value
        sections[name] = checked
    for key, value in cell.section("arm").items():
        spec = declared_by_name("slip_stop")[key]
        value = _as_type(spec.default, value)
        err = c.check_value(spec, value)
        if err:
            problems.append(f"arm: {key}: {err}")
        sections["arm"][key] = value
    if problems:
        raise CellError(f"cell file {cell.path}: " + "; ".join(problems))
    return Cell(cell.path, sections)


def _as_type(default, value):
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, str) and isinstance(value, int) and not isinstance(value, bool):
        return str(value)           # a name that is a number, e.g. a mocap body's ID
    if isinstance(default, list) and default and isinstance(default[0], float) and \
            isinstance(value, list):
        return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v
                for v in value]
    return value


def cell_arguments() -> list:
    """The launch arguments every launch file takes for a real cell (empty: the cell
    file's value, else the node's default)."""
    return [
        DeclareLaunchArgument("cell", default_value="",
                              description="the lab's cell file (config/cell_example.yaml, "
                                          "docs/hardware-quickstart.md); '' = defaults"),
        DeclareLaunchArgument("audio_device", default_value="",
                              description="hw: PortAudio device name or index (overrides "
                                          "the cell's audio_capture.device)"),
        DeclareLaunchArgument("channel_names", default_value="",
                              description="hw: microphone names in channel order, e.g. "
                                          "[left,right] (1, 2, 4, ... microphones; overrides "
                                          "the cell)"),
        DeclareLaunchArgument("channels", default_value="",
                              description="hw: channel count when no names are given "
                                          "(named ch0, ch1, ...)"),
        DeclareLaunchArgument("finger_topic", default_value="",
                              description=f"finger PoseStamped topic (default: the cell's, "
                                          f"else {topics.FINGER})"),
        DeclareLaunchArgument("object_topic", default_value="",
                              description=f"object PoseStamped topic (default: the cell's, "
                                          f"else {topics.OBJECT})"),
        DeclareLaunchArgument("xarm_ip", default_value="",
                              description="hw: xArm controller IP (overrides the cell)"),
        DeclareLaunchArgument("arm", default_value="",
                              description="hw: xarm (default) or module.path:factory, an arm "
                                          "of your own (docs/design.md, Extending)"),
    ]


def arg(context, name: str) -> str:
    """A launch argument's value, stripped ('' when not given and empty by default)."""
    return LC(name).perform(context).strip()


def flag(context, name: str) -> bool:
    """A true/false launch argument."""
    return arg(context, name).lower() in ("true", "1", "yes")


def _name_list(text: str) -> list:
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = None
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",") if v.strip()]
    if not isinstance(value, list) or not value or \
            not all(isinstance(v, str) and v for v in value):
        raise CellError(f"channel_names:={text} is not a list of names such as [left,right]")
    return value


def capture_params(context, cell: Cell, metadata: dict) -> dict:
    """audio_capture's parameters on a real cell: a PortAudio device, the cell's names (or
    the launch arguments'), and ``metadata`` as the recording's metadata. Raises CellError
    for an unreadable ``channel_names`` or ``channels``."""
    p = {"source": "device", "layout": ""}
    p.update(cell.params("audio_capture"))
    device = arg(context, "audio_device")
    if device:
        p["device"] = device
    names, count = arg(context, "channel_names"), arg(context, "channels")
    if names:
        p["channel_names"] = _name_list(names)
        p["channels"] = len(p["channel_names"])
    elif count:
        try:
            n = int(count)
        except ValueError:
            raise CellError(f"channels:={count} is not a channel count") from None
        p["channels"], p["channel_names"] = n, [f"ch{i}" for i in range(n)]
    p["device"] = str(p.get("device", ""))   # an index ("0") is a name, not a number
    p["metadata_json"] = json.dumps(metadata)
    return p


def rigid_bodies_source(context, cell: Cell):
    """The cell's mocap4r2 source, ``{"topic": ..., "bodies": {"finger": .., "object": ..}}``
    (mocap_bridge's ``pose_source: rigid_bodies``), or None for PoseStamped topics. Raises
    CellError for a ``finger_topic:=`` / ``object_topic:=`` given beside it."""
    from aslip_ros import rigid_bodies as rb
    p = cell.params("mocap_bridge")
    if p.get("pose_source", rb.POSE_STAMPED) != rb.RIGID_BODIES:
        return None
    given = [f"{k}_topic:=" for k in rb.ROLES if arg(context, f"{k}_topic")]
    if given:
        raise CellError(f"{' and '.join(given)} name PoseStamped topics, but the cell's "
                        "mocap_bridge takes the bodies of a RigidBodies (pose_source "
                        "rigid_bodies): set rigid_bodies_topic, finger_body and object_body "
                        "in the cell instead")
    return {"topic": p.get("rigid_bodies_topic", topics.RIGID_BODIES),
            "bodies": {r: str(p.get(f"{r}_body", "")) for r in rb.ROLES}}


def mocap_topics(context, cell: Cell) -> tuple:
    """(finger, object) pose topics: launch argument, else cell, else the contract; the
    RigidBodies topic for both where the cell takes them from one (mocap4r2)."""
    source = rigid_bodies_source(context, cell)
    if source is not None:
        return source["topic"], source["topic"]
    return tuple(arg(context, f"{k}_topic") or cell.get("mocap_bridge", f"{k}_topic", d)
                 for k, d in (("finger", topics.FINGER), ("object", topics.OBJECT)))


def bridge_params(context, cell: Cell, sim: bool) -> dict:
    """mocap_bridge's parameters: the scene's calibration from its metadata, the cell's
    ``grasp_plane_in_finger`` on hardware."""
    p = cell.params("mocap_bridge")
    if rigid_bodies_source(context, cell) is None:
        p["finger_topic"], p["object_topic"] = mocap_topics(context, cell)
    p["calibration"] = "metadata" if sim else p.get("calibration", "param")
    if sim:         # scene_sim publishes the bodies and world -> link_base itself
        p["publish_pose_tf"] = p["publish_base_tf"] = False
    return p


def arm_params(context, cell: Cell, node: str, sim: bool) -> dict:
    """A node that drives the arm: the cell's ``arm`` and ``node`` sections, the arm by
    ``sim``, ``xarm_ip`` when given."""
    p = cell.params(node)
    p["arm"] = "sim" if sim else (arg(context, "arm") or p.get("arm", "xarm"))
    ip = arg(context, "xarm_ip")
    if ip:
        p["xarm_ip"] = ip
    return p


def recording_metadata(context, cell: Cell, **extra) -> dict:
    """The metadata a hardware recording carries: the cell's calibrations, the pose topics
    (export reads them from here), and ``extra`` (object, induced, condition)."""
    finger, obj = mocap_topics(context, cell)
    meta = dict(cell.recording_metadata(), **extra)
    meta["topics"] = {"finger": finger, "object": obj, "tcp": topics.TCP}
    source = rigid_bodies_source(context, cell)
    if source is not None:          # which bodies of the RigidBodies are the finger, object
        meta["bodies"] = source["bodies"]
    return meta


def closed_loop_description(controller: str, scenario: str, task_arg: str,
                            task_help: str, scenarios: tuple[str, ...] = ()
                            ) -> LaunchDescription:
    """Launch ``controller`` (slip_stop or slip_track) in its closed loop.

    ``scenario`` is the scene's task when ``sim:=true`` (with ``scenarios``, the default of a
    ``scenario`` launch argument that may name any of them); ``task_arg`` is the one
    controller parameter exposed as a launch argument (empty: the cell's, else the node's).
    """
    choice = [DeclareLaunchArgument(
        "scenario", default_value=scenario, choices=[scenario, *scenarios],
        description="sim: the scene's task")] if scenarios else []
    args = choice + [
        DeclareLaunchArgument("sim", default_value="true", description="simulated scene"),
        DeclareLaunchArgument("checkpoint", default_value="",
                              description="model checkpoint (streaming, window CNN or "
                                          "SVM); sim: default the "
                                          "shipped demo model, trained on the scene; "
                                          "hardware: required, a model trained on your "
                                          "cell's recordings"),
        DeclareLaunchArgument("object", default_value="chips_can"),
        DeclareLaunchArgument("seed", default_value="0"),
        DeclareLaunchArgument("rviz", default_value="false",
                              description="start rviz (skipped with a log line when missing)"),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="configure and activate the controller at start "
                                          "(false: it waits for `ros2 lifecycle set`)"),
        DeclareLaunchArgument(task_arg, default_value="", description=task_help),
        DeclareLaunchArgument(
            "input_timeout_s", default_value="",
            description="stale-input watchdog of the controller: stop the arm when the newest "
                        "slip estimate or TCP pose is older than this [s] (default: the "
                        "cell's slip_timeout_s, else the node's; raise it on a machine too "
                        "busy to deliver estimates every 10 ms)"),
    ] + cell_arguments()
    graph = OpaqueFunction(function=_closed_loop, kwargs=dict(
        controller=controller, scenario=scenario, task_arg=task_arg))
    return LaunchDescription(args + [graph] + rviz_actions(IfCondition(LC("rviz"))))


def _closed_loop(context, controller, scenario, task_arg):
    try:
        return _closed_loop_nodes(context, controller, scenario, task_arg)
    except (CellError, ValueError) as exc:
        return fail(str(exc))


def _given(context, name: str, default):
    """Launch argument ``name`` parsed as YAML to the type of ``default``, or None."""
    text = arg(context, name)
    if not text:
        return None
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = text
    value = _as_type(default, value)
    if type(value) is not type(default):
        raise ValueError(f"{name}:={text} is not a {type(default).__name__}")
    return value


def _closed_loop_nodes(context, controller, scenario, task_arg):
    cfg = os.path.join(share_dir(), "config")
    sim = flag(context, "sim")
    declared = declared_by_name(controller)
    cell = load_checked_cell(arg(context, "cell"))
    checkpoint = arg(context, "checkpoint")
    if not checkpoint:
        if not sim:
            raise CellError(
                "sim:=false needs checkpoint:=YOUR_MODEL.pt: the shipped models are "
                "trained on the simulated scene's microphones and refuse a real stream; "
                "train one on your cell's recordings (docs/hardware-quickstart.md)")
        checkpoint = default_checkpoint(controller)
    capture = None if sim else capture_params(context, cell, {})
    ctrl = arm_params(context, cell, controller, sim)
    ctrl["autostart"] = _given(context, "autostart", True)
    timeout = _given(context, "input_timeout_s", 1.0)
    if timeout is not None:
        ctrl["slip_timeout_s"] = ctrl["pose_timeout_s"] = timeout
    value = _given(context, task_arg, declared[task_arg].default)
    if value is not None:
        ctrl[task_arg] = value
    inference = cell.params("slip_inference")
    inference["checkpoint"] = checkpoint
    nodes = [
        Node(package="aslip_ros", executable="slip_inference", name="slip_inference",
             output="screen", on_exit=required,
             parameters=[os.path.join(cfg, "slip_inference.yaml"), inference]),
        Node(package="aslip_ros", executable="mocap_bridge", name="mocap_bridge",
             output="screen", on_exit=required,
             parameters=[os.path.join(cfg, "mocap_bridge.yaml"),
                         bridge_params(context, cell, sim)]),
        Node(package="aslip_ros", executable=controller, name=controller, output="screen",
             on_exit=required,
             parameters=[os.path.join(cfg, f"{controller}.yaml"), ctrl]),
    ]
    if sim:
        nodes.insert(0, Node(package="aslip_ros", executable="scene_sim", name="scene_sim",
                             output="screen", on_exit=required,
                             parameters=[os.path.join(cfg, "scene_sim.yaml"),
                                         {"scenario": context.launch_configurations.get(
                                             "scenario", scenario),
                                          "object": arg(context, "object"),
                                          "seed": _given(context, "seed", 0)}]))
    else:
        nodes.insert(0, Node(package="aslip_ros", executable="audio_capture",
                             name="audio_capture", output="screen", on_exit=required,
                             parameters=[os.path.join(cfg, "audio_capture.yaml"), capture]))
    return nodes
