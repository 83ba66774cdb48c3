"""The closed-loop graph shared by ``slip_stop.launch.py`` and ``slip_track.launch.py``.

Imported only by those launch files (it needs ``launch`` and ``launch_ros``, which a full
ROS 2 install provides): the scene or the audio interface, slip_inference, mocap_bridge,
the task's controller and, optionally, rviz.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration as LC
from launch.substitutions import PythonExpression
from launch_ros.actions import Node


def closed_loop_description(controller: str, scenario: str, task_arg: str,
                            task_default: str, task_help: str) -> LaunchDescription:
    """Launch ``controller`` (slip_stop or slip_track) in its closed loop.

    ``scenario`` is the scene's task when ``sim:=true``; ``task_arg`` is the one
    controller parameter exposed as a launch argument (default ``task_default``).
    """
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
        DeclareLaunchArgument(task_arg, default_value=task_default, description=task_help),
    ]
    arm = PythonExpression(["'sim' if '", LC("sim"), "' == 'true' else 'xarm'"])
    nodes = [
        Node(package="aslip_ros", executable="scene_sim", name="scene_sim", condition=sim,
             output="screen",
             parameters=[os.path.join(cfg, "scene_sim.yaml"),
                         {"scenario": scenario, "object": LC("object"), "seed": LC("seed")}]),
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
        Node(package="aslip_ros", executable=controller, name=controller, output="screen",
             parameters=[os.path.join(cfg, f"{controller}.yaml"),
                         {"arm": arm, "xarm_ip": LC("xarm_ip"), task_arg: LC(task_arg)}]),
        Node(package="rviz2", executable="rviz2", name="rviz2",
             condition=IfCondition(LC("rviz")),
             arguments=["-d", os.path.join(cfg, "aslip.rviz")]),
    ]
    return LaunchDescription(args + nodes)
