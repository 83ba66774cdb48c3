"""The closed-loop graph shared by ``slip_stop.launch.py`` and ``slip_track.launch.py``.

Imported only by launch files (it needs ``launch`` and ``launch_ros``, which a full ROS 2
install provides): the scene or the audio interface, slip_inference, mocap_bridge, the
task's controller and, optionally, rviz. Also the pieces every launch file of the package
shares (:func:`share_dir`, :func:`rviz_actions`).
"""

import os
import shutil

from ament_index_python.packages import PackageNotFoundError, get_package_prefix
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, LogInfo, Shutdown
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration as LC
from launch.substitutions import PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from aslip_ros import topics
from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S

#: The checkpoint a launch uses when none is given (shipped in share/aslip_ros/models).
DEFAULT_MODEL = "aslip_cnn.pt"


def share_dir() -> str:
    """The installed ``share/aslip_ros`` (config, launch files, models)."""
    return get_package_share_directory("aslip_ros")


def default_checkpoint() -> str:
    """Path of the shipped demo checkpoint in the install's share directory."""
    return os.path.join(share_dir(), "models", DEFAULT_MODEL)


def rviz_found() -> bool:
    """Whether rviz2 is installed (as a ROS package or on PATH)."""
    try:
        get_package_prefix("rviz2")
        return True
    except PackageNotFoundError:
        return shutil.which("rviz2") is not None


def rviz_actions(condition=None) -> list:
    """rviz with the package's view, or a log line when rviz2 is missing.

    A missing rviz2 must not take down a graph that is already commanding an arm: launch_ros
    would fail the whole launch on an unknown package, so rviz is only added when found.
    rviz exiting (its window closed) leaves the rest running.
    """
    cfg = os.path.join(share_dir(), "config", "aslip.rviz")
    if rviz_found():
        return [Node(package="rviz2", executable="rviz2", name="rviz2", condition=condition,
                     arguments=["-d", cfg], output="screen")]
    return [LogInfo(condition=condition,
                    msg="rviz2 is not installed: running without rviz (install "
                        "ros-jazzy-rviz2 to see the slip arrows)")]


def fail(why: str) -> list:
    """Log ``why`` as an error and shut the launch down with it as the reason."""
    return [LogInfo(msg=f"ERROR: {why}"), Shutdown(reason=why)]


def required(event, context):
    """``on_exit`` of a node the graph cannot work without: its exit ends the launch.

    A closed loop without one of its nodes stops the arm through the watchdogs but would
    otherwise sit there looking alive; the launch says which node ended and why it stops.
    """
    if context.is_shutdown:
        return None
    return fail(f"{event.action.name} exited with code {event.returncode}; shutting down "
                "the graph")


def closed_loop_description(controller: str, scenario: str, task_arg: str,
                            task_default: str, task_help: str,
                            task_type=str) -> LaunchDescription:
    """Launch ``controller`` (slip_stop or slip_track) in its closed loop.

    ``scenario`` is the scene's task when ``sim:=true``; ``task_arg`` is the one
    controller parameter exposed as a launch argument (default ``task_default``, parameter
    type ``task_type``).
    """
    cfg = os.path.join(share_dir(), "config")
    sim = IfCondition(LC("sim"))
    args = [
        DeclareLaunchArgument("sim", default_value="true", description="simulated scene"),
        DeclareLaunchArgument("checkpoint", default_value=default_checkpoint(),
                              description="model checkpoint (CNN or SVM); default: the "
                                          "shipped demo model, trained on the scene"),
        DeclareLaunchArgument("object", default_value="chips_can"),
        DeclareLaunchArgument("seed", default_value="0"),
        DeclareLaunchArgument("xarm_ip", default_value="192.168.1.222"),
        DeclareLaunchArgument("audio_device", default_value="",
                              description="hw: PortAudio device name or index"),
        DeclareLaunchArgument("finger_topic", default_value=topics.FINGER),
        DeclareLaunchArgument("object_topic", default_value=topics.OBJECT),
        DeclareLaunchArgument("rviz", default_value="false",
                              description="start rviz (skipped with a log line when missing)"),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="configure and activate the controller at start "
                                          "(false: it waits for `ros2 lifecycle set`)"),
        DeclareLaunchArgument(task_arg, default_value=task_default, description=task_help),
        DeclareLaunchArgument(
            "input_timeout_s", default_value=str(DEFAULT_TIMEOUT_S),
            description="stale-input watchdog of the controller: stop the arm when the newest "
                        "slip estimate or TCP pose is older than this [s] (raise it on a "
                        "machine too busy to deliver estimates every 10 ms)"),
    ]
    arm = PythonExpression(["'sim' if '", LC("sim"), "' == 'true' else 'xarm'"])
    task_value = LC(task_arg) if task_type is None else ParameterValue(LC(task_arg),
                                                                       value_type=task_type)
    nodes = [
        Node(package="aslip_ros", executable="scene_sim", name="scene_sim", condition=sim,
             output="screen", on_exit=required,
             parameters=[os.path.join(cfg, "scene_sim.yaml"),
                         {"scenario": scenario, "object": LC("object"),
                          "seed": ParameterValue(LC("seed"), value_type=int)}]),
        Node(package="aslip_ros", executable="audio_capture", name="audio_capture",
             condition=UnlessCondition(LC("sim")), output="screen", on_exit=required,
             parameters=[os.path.join(cfg, "audio_capture.yaml"),
                         {"source": "device",
                          # A device index ("0") is a name to audio_capture, not a number.
                          "device": ParameterValue(LC("audio_device"), value_type=str)}]),
        Node(package="aslip_ros", executable="slip_inference", name="slip_inference",
             output="screen", on_exit=required,
             parameters=[os.path.join(cfg, "slip_inference.yaml"),
                         {"checkpoint": ParameterValue(LC("checkpoint"), value_type=str)}]),
        Node(package="aslip_ros", executable="mocap_bridge", name="mocap_bridge",
             output="screen", on_exit=required,
             parameters=[os.path.join(cfg, "mocap_bridge.yaml"),
                         {"finger_topic": LC("finger_topic"),
                          "object_topic": LC("object_topic")}]),
        Node(package="aslip_ros", executable=controller, name=controller, output="screen",
             on_exit=required,
             parameters=[os.path.join(cfg, f"{controller}.yaml"),
                         {"arm": arm, "xarm_ip": ParameterValue(LC("xarm_ip"), value_type=str),
                          "autostart": ParameterValue(LC("autostart"), value_type=bool),
                          "slip_timeout_s": ParameterValue(LC("input_timeout_s"),
                                                           value_type=float),
                          "pose_timeout_s": ParameterValue(LC("input_timeout_s"),
                                                           value_type=float),
                          task_arg: task_value}]),
    ]
    return LaunchDescription(args + nodes + rviz_actions(IfCondition(LC("rviz"))))
