"""rviz with the A-SLIP view: predicted and ground-truth slip arrows, finger/object/TCP poses.

    ros2 launch aslip_ros rviz.launch.py
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    rviz_cfg = os.path.join(get_package_share_directory("aslip_ros"), "config", "aslip.rviz")
    return LaunchDescription([
        Node(package="rviz2", executable="rviz2", name="rviz2", arguments=["-d", rviz_cfg],
             output="screen"),
    ])
