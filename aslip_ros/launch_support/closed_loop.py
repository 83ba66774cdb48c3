"""The closed-loop graph of a controller: ``slip_stop.launch.py``, ``slip_track.launch.py``.

The scene or the audio interface, slip_inference, mocap_bridge, the controller and,
optionally, rviz. Any controller of the node table (:mod:`aslip_ros.node_table`: a node that
drives the arm and has a default model) runs here; the model is its row's
``default_model`` when no ``checkpoint:=`` is given (in simulation).
Precedence, for every node parameter: the node's config/*.yaml, then the cell file, then a
launch argument that is given (an empty argument leaves the value to the cell).
"""

import os
import sys

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration as LC
from launch_ros.actions import Node

import yaml

from aslip_ros import node_table
from aslip_ros.cell import CellError
from aslip_ros.launch_support.common import (arg, arm_params, as_type, bridge_params,
                                             capture_params, cell_arguments, fail, flag,
                                             load_checked_cell, required, rviz_actions,
                                             share_dir)
from aslip_ros.nodes.introspect import declared_by_name


def default_checkpoint(controller: str) -> str:
    """Path of the controller's shipped demo checkpoint (its row's ``default_model``) in the
    install's share directory."""
    return os.path.join(share_dir(), "models", node_table.spec(controller).default_model)


def closed_loop_description(controller: str, scenario: str, task_arg: str,
                            task_help: str, scenarios: tuple[str, ...] = ()
                            ) -> LaunchDescription:
    """Launch ``controller`` (a controller of the node table: slip_stop, slip_track, or one
    registered with :func:`aslip_ros.node_table.register`) in its closed loop.

    ``scenario`` is the scene's task when ``sim:=true`` (with ``scenarios``, the default of a
    ``scenario`` launch argument that may name any of them); ``task_arg`` is the one
    controller parameter exposed as a launch argument (empty: the cell's, else the node's).
    """
    if controller not in node_table.controllers():
        raise ValueError(f"{controller!r} is not a controller of the node table (known: "
                         f"{', '.join(node_table.controllers())})")
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


def node_action(name: str, **kwargs) -> Node:
    """A launch_ros ``Node`` for node ``name`` of the node table: its installed executable,
    or, for a registered node (not installed), ``python -P -m aslip_ros.runtime.launcher
    <module>`` on the launch's own interpreter (which imports the package, so finds the
    module on the same path; ``-P``: not a checkout in the working directory instead of the
    installed package)."""
    row = node_table.spec(name)
    if row.installed:
        return Node(package="aslip_ros", executable=name, name=name, output="screen",
                    **kwargs)
    return Node(executable=sys.executable, name=name, output="screen",
                arguments=["-P", "-m", "aslip_ros.runtime.launcher", row.module], **kwargs)


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
    value = as_type(default, value)
    if type(value) is not type(default):
        raise ValueError(f"{name}:={text} is not a {type(default).__name__}")
    return value


def _closed_loop_nodes(context, controller, scenario, task_arg):
    cfg = os.path.join(share_dir(), "config")
    sim = flag(context, "sim")
    declared = declared_by_name(controller)
    row = node_table.spec(controller)
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
        node_action(controller, on_exit=required, parameters=[
            *([os.path.join(cfg, row.config)] if row.config else []), ctrl]),
    ]
    if sim:
        nodes.insert(0, Node(package="aslip_ros", executable="scene_sim", name="scene_sim",
                             output="screen", on_exit=required,
                             parameters=[os.path.join(cfg, "scene_sim.yaml"),
                                         {"scenario": context.launch_configurations.get(
                                             "scenario", scenario),
                                          "object": arg(context, "object"),
                                          "seed": _given(context, "seed", 0),
                                          # The scene starts once slip_inference reads the
                                          # audio: on a slow machine it came up 4 s after
                                          # the scene, the drag had begun, and the per-grasp
                                          # calibration learnt the slip as background.
                                          "start_with_subscriber": True}]))
    else:
        nodes.insert(0, Node(package="aslip_ros", executable="audio_capture",
                             name="audio_capture", output="screen", on_exit=required,
                             parameters=[os.path.join(cfg, "audio_capture.yaml"), capture]))
    return nodes
