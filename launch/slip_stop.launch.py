"""Slip-stop (wall push): stop the arm when the pushed object slips.

Closed loop through topics: audio -> slip_inference -> slip_stop -> arm -> (scene).
Simulation (default; the scene's arm through scene_sim):
    ros2 launch aslip_ros slip_stop.launch.py                  # the shipped demo model
    ros2 launch aslip_ros slip_stop.launch.py checkpoint:=models/svm.pt rviz:=true
Hardware (xArm, audio interface, motion capture for the ground truth):
    ros2 launch aslip_ros slip_stop.launch.py sim:=false checkpoint:=models/aslip_cnn.pt \
        xarm_ip:=192.168.1.222 audio_device:=UMC404HD \
        finger_topic:=/mocap/finger/pose object_topic:=/mocap/object/pose
"""

from aslip_ros.nodes.closed_loop_launch import closed_loop_description


def generate_launch_description():
    return closed_loop_description("slip_stop", scenario="wall_push", task_arg="direction",
                                   task_default="[0.0, 0.0, 0.0]",
                                   task_help="hw: approach direction in link_base",
                                   task_type=None)
