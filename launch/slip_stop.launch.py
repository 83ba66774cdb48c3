"""Slip-stop (wall push): stop the arm when the pushed object slips, or turns.

Closed loop through topics: audio -> slip_inference -> slip_stop -> arm -> (scene).
Simulation (default; the scene's arm through scene_sim):
    ros2 launch aslip_ros slip_stop.launch.py                  # the shipped demo model
    ros2 launch aslip_ros slip_stop.launch.py checkpoint:=models/svm.pt rviz:=true
    ros2 launch aslip_ros slip_stop.launch.py scenario:=pivot  # lowered onto a surface met
                                                               # off axis, the object turns
Hardware (xArm, audio interface, motion capture; docs/hardware-quickstart.md): the cell file
holds the device, channel names, mocap topics, arm limits and grasp planes; the checkpoint
is a model trained on your own recordings:
    ros2 launch aslip_ros slip_stop.launch.py sim:=false cell:=my_cell.yaml \
        checkpoint:=my_model.pt direction:="[1.0, 0.0, 0.0]"
"""

from aslip_ros.launch_support.closed_loop import closed_loop_description


def generate_launch_description():
    return closed_loop_description("slip_stop", scenario="wall_push", task_arg="direction",
                                   task_help="approach direction in link_base, e.g. "
                                             "[1.0, 0.0, 0.0] (sim: from the scene)",
                                   scenarios=("pivot",))
