"""Slip-track: the arm follows the object while it slips in the grasp.

Closed loop through topics: audio -> slip_inference -> slip_track -> arm -> (scene).
Simulation (default; the scene's arm through scene_sim):
    ros2 launch aslip_ros slip_track.launch.py                  # the shipped demo model
    ros2 launch aslip_ros slip_track.launch.py checkpoint:=models/svm.pt rviz:=true
Hardware (xArm, audio interface, motion capture for the ground truth):
    ros2 launch aslip_ros slip_track.launch.py sim:=false checkpoint:=models/aslip_cnn.pt \
        xarm_ip:=192.168.1.222 audio_device:=UMC404HD \
        finger_topic:=/mocap/finger/pose object_topic:=/mocap/object/pose
"""

from aslip_ros.nodes.closed_loop_launch import closed_loop_description


def generate_launch_description():
    return closed_loop_description("slip_track", scenario="drag", task_arg="gain",
                                   task_default="1.0",
                                   task_help="slip-track gain", task_type=float)
