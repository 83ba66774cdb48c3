"""rviz with the A-SLIP view: predicted and ground-truth slip arrows, finger/object/TCP poses.

    ros2 launch aslip_ros rviz.launch.py

Without rviz2 installed it logs that and starts nothing (include it in a larger launch, or
pass `rviz:=true` to the closed-loop launch files, without that graph failing).
"""

from launch import LaunchDescription

from aslip_ros.nodes.closed_loop_launch import rviz_actions


def generate_launch_description():
    return LaunchDescription(rviz_actions())
