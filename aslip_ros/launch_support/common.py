"""What every launch file of the package shares.

Imported only by launch files and :mod:`aslip_ros.launch_support.closed_loop` (it needs
``launch`` and ``launch_ros``, which a full ROS 2 install provides): :func:`share_dir`,
:func:`rviz_actions`, ending a launch with exit code 1 (:func:`fail`, :func:`required`), and
the lab's cell file (``cell:=``, :mod:`aslip_ros.cell`) with the hardware launch arguments
that override it (:func:`cell_arguments`, :func:`capture_params`, :func:`mocap_topics`,
:func:`rigid_bodies_source`, :func:`arm_params`).
Precedence, for every node parameter: the node's config/*.yaml, then the cell file, then a
launch argument that is given (an empty argument leaves the value to the cell).
"""

import json
import os
import shutil

from ament_index_python.packages import PackageNotFoundError, get_package_prefix
from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, LogInfo, OpaqueFunction, Shutdown
from launch.substitutions import LaunchConfiguration as LC
from launch_ros.actions import Node

import yaml

from aslip_ros import topics
from aslip_ros import node_table
from aslip_ros.cell import Cell, CellError, load_cell
from aslip_ros.nodes import common as c
from aslip_ros.nodes.introspect import declared_by_name


def share_dir() -> str:
    """The installed ``share/aslip_ros`` (config, launch files, models)."""
    return get_package_share_directory("aslip_ros")


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
    argument's), written by :func:`aslip_ros.launch_support.rviz_view.write_view` (also without
    rviz2, for an rviz started elsewhere). A missing rviz2 must not take down a graph that
    is already commanding an arm: launch_ros would fail the whole launch on an unknown
    package, so rviz is only added when found. rviz exiting (its window closed) leaves the
    rest running.
    """
    return [OpaqueFunction(function=_rviz, condition=condition)]


def _rviz(context) -> list:
    from aslip_ros.launch_support.rviz_view import write_view
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
        if name not in node_table.cell_sections():
            sections[name] = body
            continue
        declared, checked = declared_by_name(name), {}
        for key, value in body.items():
            spec = declared.get(key)
            if spec is None:
                problems.append(f"{name}: {key!r} is not a parameter of {name}")
                continue
            value = as_type(spec.default, value)
            err = c.check_value(spec, value)
            if err:
                problems.append(f"{name}: {key}: {err}")
            checked[key] = value
        sections[name] = checked
    for key, value in cell.section("arm").items():
        spec = declared_by_name("slip_stop")[key]
        value = as_type(spec.default, value)
        err = c.check_value(spec, value)
        if err:
            problems.append(f"arm: {key}: {err}")
        sections["arm"][key] = value
    if problems:
        raise CellError(f"cell file {cell.path}: " + "; ".join(problems))
    return Cell(cell.path, sections)


def as_type(default, value):
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


def node_param(cell: Cell, node: str, key: str):
    """The value ``node`` runs with for ``key`` by the precedence above, without a launch
    argument: the cell file's, else the node's config/*.yaml, else the declared default."""
    given = cell.params(node)
    if key in given:
        return given[key]
    with open(os.path.join(share_dir(), "config", f"{node}.yaml")) as f:
        config = (yaml.safe_load(f) or {}).get(node, {}).get("ros__parameters", {})
    return config[key] if key in config else declared_by_name(node)[key].default


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
