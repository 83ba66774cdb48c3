"""Data collection: audio + motion capture + ground-truth slip + TF, recorded to a bag.

Simulation (default; the launch ends when `duration_s` of scene time is recorded):
    ros2 launch aslip_ros data_collection.launch.py scenario:=external_induced object:=chips_can
Hardware (records until Ctrl-C):
    ros2 launch aslip_ros data_collection.launch.py sim:=false audio_device:=UMC404HD \
        finger_topic:=/mocap/finger/pose object_topic:=/mocap/object/pose object:=chips_can

`recorder:=ros2bag` records with `ros2 bag record` (mcap), `recorder:=aslip` with the
package's own `bag_recorder` node (no rosbag2 needed), `auto` (default) picks ros2bag when it
is installed. A recorder that stops while the launch runs shuts the whole launch down with
the reason: a collection that records nothing must not look like one that works.
"""

import os
import shutil

from ament_index_python.packages import PackageNotFoundError, get_package_prefix
from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, ExecuteProcess, LogInfo, OpaqueFunction,
                            RegisterEventHandler, Shutdown, TimerAction)
from launch.conditions import IfCondition, UnlessCondition
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration as LC
from launch.substitutions import PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from aslip_ros.nodes.bag_recorder import DEFAULT_TOPICS
from aslip_ros.nodes.closed_loop_launch import fail, required, share_dir

RECORDERS = ("auto", "ros2bag", "aslip")
#: Seconds between the end of a finite scene run and the end of the launch.
END_GRACE_S = 1.0


def ros2bag_found() -> bool:
    """Whether `ros2 bag` (rosbag2) is installed."""
    try:
        get_package_prefix("ros2bag")
    except PackageNotFoundError:
        return False
    return shutil.which("ros2") is not None


def _recorder(context) -> list:
    choice = LC("recorder").perform(context)
    bag = LC("bag").perform(context)
    if choice not in RECORDERS:
        return fail(f"recorder:={choice} is none of {', '.join(RECORDERS)}")
    if choice == "auto":
        choice = "ros2bag" if ros2bag_found() else "aslip"
    if choice == "ros2bag":
        if not ros2bag_found():
            return fail("recorder:=ros2bag but rosbag2 (`ros2 bag`) is not installed; "
                        "use recorder:=aslip")
        rec = ExecuteProcess(cmd=["ros2", "bag", "record", "-s", "mcap", "-o", bag]
                             + DEFAULT_TOPICS, name="ros2_bag_record", output="screen")
    else:
        rec = Node(package="aslip_ros", executable="bag_recorder", name="bag_recorder",
                   output="screen",
                   parameters=[{"output": ParameterValue(bag, value_type=str),
                                "topics": list(DEFAULT_TOPICS)}])

    def stopped(event, ctx):
        if ctx.is_shutdown:
            return None
        return fail(f"the recorder ({choice}) exited with code {event.returncode} while "
                    f"the launch was running: nothing more is recorded to {bag}")

    return [LogInfo(msg=f"recording with {choice} to {bag}"), rec,
            RegisterEventHandler(OnProcessExit(target_action=rec, on_exit=stopped))]


def _scene_ended(event, ctx):
    if ctx.is_shutdown:
        return None
    if event.returncode != 0:
        return fail(f"scene_sim exited with code {event.returncode}")
    why = "the scene ran its duration_s: collection finished"
    # The recorder still receives what was in flight when the scene ended; then the launch
    # ends. (A launch test can also finish its checks before the launch is gone.)
    return [LogInfo(msg=why),
            TimerAction(period=END_GRACE_S, actions=[Shutdown(reason=why)])]


def generate_launch_description():
    cfg = os.path.join(share_dir(), "config")
    sim = IfCondition(LC("sim"))
    real = UnlessCondition(LC("sim"))
    args = [
        DeclareLaunchArgument("sim", default_value="true", description="simulated scene"),
        DeclareLaunchArgument("scenario", default_value="external_induced",
                              description="sim: external_induced | robot_induced"),
        DeclareLaunchArgument("object", default_value="chips_can"),
        DeclareLaunchArgument("seed", default_value="0"),
        DeclareLaunchArgument("duration_s", default_value="30.0",
                              description="sim: scene time to record [s], then the launch "
                                          "ends; 0 = until Ctrl-C"),
        DeclareLaunchArgument("audio_device", default_value="",
                              description="hw: PortAudio device name or index"),
        DeclareLaunchArgument("channels", default_value="4"),
        DeclareLaunchArgument("sample_rate", default_value="48000.0"),
        DeclareLaunchArgument("finger_topic", default_value="/aslip/mocap/finger"),
        DeclareLaunchArgument("object_topic", default_value="/aslip/mocap/object"),
        DeclareLaunchArgument("bag", default_value="aslip_bag", description="output bag"),
        DeclareLaunchArgument("record", default_value="true"),
        DeclareLaunchArgument("recorder", default_value="auto",
                              description="auto | ros2bag | aslip (no rosbag2 needed)"),
    ]
    scene = Node(package="aslip_ros", executable="scene_sim", name="scene_sim",
                 condition=sim, output="screen",
                 parameters=[os.path.join(cfg, "scene_sim.yaml"),
                             {"scenario": LC("scenario"), "object": LC("object"),
                              "seed": ParameterValue(LC("seed"), value_type=int),
                              "duration_s": ParameterValue(LC("duration_s"), value_type=float),
                              "exit_when_done": ParameterValue(PythonExpression(
                                  ["float('", LC("duration_s"), "') > 0"]), value_type=bool),
                              "condition": PythonExpression([
                                  "'robot_moving' if '", LC("scenario"),
                                  "' == 'robot_induced' else 'robot_stationary'"])}])
    # Strings stay strings: a device index ("0") and the JSON text would otherwise be
    # parsed as YAML into an integer and a dict.
    capture = Node(package="aslip_ros", executable="audio_capture", name="audio_capture",
                   condition=real, output="screen", on_exit=required,
                   parameters=[os.path.join(cfg, "audio_capture.yaml"),
                               {"source": "device",
                                "device": ParameterValue(LC("audio_device"), value_type=str),
                                "channels": ParameterValue(LC("channels"), value_type=int),
                                "sample_rate": ParameterValue(LC("sample_rate"),
                                                              value_type=float),
                                "metadata_json": ParameterValue(PythonExpression([
                                    "__import__('json').dumps({'object': '", LC("object"),
                                    "'})"]), value_type=str)}])
    bridge = Node(package="aslip_ros", executable="mocap_bridge", name="mocap_bridge",
                  output="screen", on_exit=required,
                  parameters=[os.path.join(cfg, "mocap_bridge.yaml"),
                              {"finger_topic": LC("finger_topic"),
                               "object_topic": LC("object_topic"),
                               "calibration": PythonExpression([
                                   "'metadata' if '", LC("sim"), "' == 'true' else 'param'"])}])
    return LaunchDescription(args + [
        scene, capture, bridge,
        RegisterEventHandler(OnProcessExit(target_action=scene, on_exit=_scene_ended)),
        OpaqueFunction(function=_recorder, condition=IfCondition(LC("record"))),
    ])
