"""Training export: turn a recorded bag into a windowed dataset with `aslip export`.

    ros2 launch aslip_ros export.launch.py bag:=aslip_bag out:=data/datasets/mine window:=0.2

``jobs:=N`` reads a folder of bags in N processes (``aslip export --jobs``; the same dataset).

The launch ends when the export does; a failed export shuts it down with the reason.
"""

import sys

from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, ExecuteProcess, LogInfo,
                            RegisterEventHandler, Shutdown)
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration as LC


def _finished(event, ctx):
    if event.returncode == 0:
        return None
    why = f"aslip export failed with exit code {event.returncode} (see its message above)"
    return [LogInfo(msg=f"ERROR: {why}"), Shutdown(reason=why)]


def generate_launch_description():
    # The interpreter running the launch imports aslip_ros (the launch files need it), so
    # it runs the CLI too, whether or not the `aslip` script is on PATH.
    export = ExecuteProcess(cmd=[sys.executable, "-m", "aslip_ros.cli", "export", LC("bag"),
                                 "-o", LC("out"),
                                 "--window", LC("window"), "--hop", LC("hop"),
                                 "--jobs", LC("jobs"), "--no-progress"],
                            name="aslip_export", output="screen")
    return LaunchDescription([
        DeclareLaunchArgument("bag", description="bag directory (or a folder of bags)"),
        DeclareLaunchArgument("out", description="dataset directory to create"),
        DeclareLaunchArgument("window", default_value="0.2", description="window [s]"),
        DeclareLaunchArgument("hop", default_value="0.1", description="hop [s]"),
        DeclareLaunchArgument("jobs", default_value="1",
                              description="processes reading the bags (--jobs of aslip export)"),
        export,
        RegisterEventHandler(OnProcessExit(target_action=export, on_exit=_finished)),
    ])
