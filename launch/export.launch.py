"""Training export: turn a recorded bag into a windowed dataset with `aslip export`.

    ros2 launch aslip_ros export.launch.py bag:=aslip_bag out:=data/datasets/mine window:=0.2
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration as LC


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("bag", description="bag directory (or a folder of bags)"),
        DeclareLaunchArgument("out", description="dataset directory to create"),
        DeclareLaunchArgument("window", default_value="0.2", description="window [s]"),
        DeclareLaunchArgument("hop", default_value="0.1", description="hop [s]"),
        ExecuteProcess(cmd=["aslip", "export", LC("bag"), "-o", LC("out"),
                            "--window", LC("window"), "--hop", LC("hop"), "--no-progress"],
                       output="screen"),
    ])
