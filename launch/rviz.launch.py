"""rviz with the A-SLIP view: predicted and ground-truth slip arrows, finger/object/TCP poses.

    ros2 launch aslip_ros rviz.launch.py                          # beside the scene
    ros2 launch aslip_ros rviz.launch.py sim:=false cell:=my_cell.yaml

The view follows the graph's pose topics (the cell's, or finger_topic:=, object_topic:=);
it is written to $ROS_HOME/aslip_ros/rviz/ and its path logged. Without rviz2 installed it
logs that and starts nothing (include it in a larger launch, or pass `rviz:=true` to the
closed-loop launch files, without that graph failing).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument

from aslip_ros.launch_support.common import cell_arguments, rviz_actions


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument("sim", default_value="true",
                               description="the simulated scene publishes world -> link_base "
                                           "(false: the cell's mocap_bridge base_in_world)")]
        + cell_arguments() + rviz_actions())
