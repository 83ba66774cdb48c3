"""Slip-track: the arm follows the object while it slips in the grasp.

Closed loop through topics: audio -> slip_inference -> slip_track -> arm -> (scene).
Simulation (default; the scene's arm through scene_sim):
    ros2 launch aslip_ros slip_track.launch.py                  # the shipped demo model
    ros2 launch aslip_ros slip_track.launch.py checkpoint:=models/svm.pt rviz:=true
Hardware (xArm, audio interface, motion capture; docs/hardware-quickstart.md):
    ros2 launch aslip_ros slip_track.launch.py sim:=false cell:=my_cell.yaml \
        checkpoint:=my_model.pt
"""

from aslip_ros.launch_support.closed_loop import closed_loop_description


def generate_launch_description():
    return closed_loop_description("slip_track", scenario="drag", task_arg="gain",
                                   task_help="slip-track gain (default: the cell's, else "
                                             "the node's)")
