"""Slip-stop (wall push): stop the arm when the pushed object slips.

Closed loop through topics: audio -> slip_inference -> slip_stop -> arm -> (scene).
Simulation (default; the scene's arm through scene_sim):
    ros2 launch aslip_ros slip_stop.launch.py checkpoint:=models/aslip_cnn.pt object:=chips_can
Hardware (xArm, audio interface, motion capture for the ground truth):
    ros2 launch aslip_ros slip_stop.launch.py sim:=false checkpoint:=models/aslip_cnn.pt \
        xarm_ip:=192.168.1.222 audio_device:=UMC404HD \
        finger_topic:=/mocap/finger/pose object_topic:=/mocap/object/pose
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration as LC
from launch.substitutions import PythonExpression
from launch_ros.actions import Node


def generate_launch_description():
    cfg = os.path.join(get_package_share_directory("aslip_ros"), "config")
    sim = IfCondition(LC("sim"))
    args = [
        DeclareLaunchArgument("sim", default_value="true", description="simulated scene"),
        DeclareLaunchArgument("checkpoint", description="model checkpoint (CNN or SVM)"),
        DeclareLaunchArgument("object", default_value="chips_can"),
        DeclareLaunchArgument("seed", default_value="0"),
        DeclareLaunchArgument("xarm_ip", default_value="192.168.1.222"),
        DeclareLaunchArgument("audio_device", default_value=""),
        DeclareLaunchArgument("finger_topic", default_value="/aslip/mocap/finger"),
        DeclareLaunchArgument("object_topic", default_value="/aslip/mocap/object"),
        DeclareLaunchArgument("rviz", default_value="false"),
        DeclareLaunchArgument("direction", default_value="[0.0, 0.0, 0.0]",
                              description="hw: approach direction in link_base"),
    ]
    arm = PythonExpression(["'sim' if '", LC("sim"), "' == 'true' else 'xarm'"])
    nodes = [
        Node(package="aslip_ros", executable="scene_sim", name="scene_sim", condition=sim,
             output="screen",
             parameters=[os.path.join(cfg, "scene_sim.yaml"),
                         {"scenario": "wall_push", "object": LC("object"), "seed": LC("seed")}]),
        Node(package="aslip_ros", executable="audio_capture", name="audio_capture",
             condition=UnlessCondition(LC("sim")), output="screen",
             parameters=[os.path.join(cfg, "audio_capture.yaml"),
                         {"source": "device", "device": LC("audio_device")}]),
        Node(package="aslip_ros", executable="slip_inference", name="slip_inference",
             output="screen",
             parameters=[os.path.join(cfg, "slip_inference.yaml"),
                         {"checkpoint": LC("checkpoint")}]),
        Node(package="aslip_ros", executable="mocap_bridge", name="mocap_bridge",
             output="screen",
             parameters=[os.path.join(cfg, "mocap_bridge.yaml"),
                         {"finger_topic": LC("finger_topic"),
                          "object_topic": LC("object_topic")}]),
        Node(package="aslip_ros", executable="slip_stop", name="slip_stop", output="screen",
             parameters=[os.path.join(cfg, "slip_stop.yaml"),
                         {"arm": arm, "xarm_ip": LC("xarm_ip"), "direction": LC("direction")}]),
        Node(package="rviz2", executable="rviz2", name="rviz2",
             condition=IfCondition(LC("rviz")),
             arguments=["-d", os.path.join(cfg, "aslip.rviz")]),
    ]
    return LaunchDescription(args + nodes)
