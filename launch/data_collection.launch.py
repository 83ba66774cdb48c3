"""Data collection: audio + motion capture + ground-truth slip, recorded with `ros2 bag`.

Simulation (default):
    ros2 launch aslip_ros data_collection.launch.py scenario:=external_induced object:=chips_can
Hardware:
    ros2 launch aslip_ros data_collection.launch.py sim:=false audio_device:=UMC404HD \
        finger_topic:=/mocap/finger/pose object_topic:=/mocap/object/pose object:=chips_can
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration as LC
from launch.substitutions import PythonExpression
from launch_ros.actions import Node

TOPICS = ["/aslip/audio", "/aslip/mocap/finger", "/aslip/mocap/object",
          "/aslip/robot/tcp_pose", "/aslip/metadata", "/aslip/slip_truth"]


def generate_launch_description():
    share = get_package_share_directory("aslip_ros")
    cfg = os.path.join(share, "config")
    sim = IfCondition(LC("sim"))
    real = UnlessCondition(LC("sim"))
    args = [
        DeclareLaunchArgument("sim", default_value="true", description="simulated scene"),
        DeclareLaunchArgument("scenario", default_value="external_induced",
                              description="sim: external_induced | robot_induced"),
        DeclareLaunchArgument("object", default_value="chips_can"),
        DeclareLaunchArgument("seed", default_value="0"),
        DeclareLaunchArgument("duration_s", default_value="30.0",
                              description="sim: scene time to record [s]"),
        DeclareLaunchArgument("audio_device", default_value="",
                              description="hw: PortAudio device name or index"),
        DeclareLaunchArgument("channels", default_value="4"),
        DeclareLaunchArgument("sample_rate", default_value="48000.0"),
        DeclareLaunchArgument("finger_topic", default_value="/aslip/mocap/finger"),
        DeclareLaunchArgument("object_topic", default_value="/aslip/mocap/object"),
        DeclareLaunchArgument("bag", default_value="aslip_bag", description="output bag"),
        DeclareLaunchArgument("record", default_value="true"),
    ]
    scene = Node(package="aslip_ros", executable="scene_sim", name="scene_sim",
                 condition=sim, output="screen",
                 parameters=[os.path.join(cfg, "scene_sim.yaml"),
                             {"scenario": LC("scenario"), "object": LC("object"),
                              "seed": LC("seed"), "duration_s": LC("duration_s"),
                              "condition": PythonExpression([
                                  "'robot_moving' if '", LC("scenario"),
                                  "' == 'robot_induced' else 'robot_stationary'"])}])
    capture = Node(package="aslip_ros", executable="audio_capture", name="audio_capture",
                   condition=real, output="screen",
                   parameters=[os.path.join(cfg, "audio_capture.yaml"),
                               {"source": "device", "device": LC("audio_device"),
                                "channels": LC("channels"), "sample_rate": LC("sample_rate"),
                                "metadata_json": PythonExpression([
                                    "'{\"object\": \"", LC("object"), "\"}'"])}])
    bridge = Node(package="aslip_ros", executable="mocap_bridge", name="mocap_bridge",
                  output="screen",
                  parameters=[os.path.join(cfg, "mocap_bridge.yaml"),
                              {"finger_topic": LC("finger_topic"),
                               "object_topic": LC("object_topic"),
                               "calibration": PythonExpression([
                                   "'metadata' if '", LC("sim"), "' == 'true' else 'param'"])}])
    record = ExecuteProcess(
        cmd=["ros2", "bag", "record", "-s", "mcap", "-o", LC("bag")] + TOPICS,
        condition=IfCondition(LC("record")), output="screen")
    return LaunchDescription(args + [scene, capture, bridge, record])
