"""Topic names: the one definition (docs/design.md, "Topics").

ROS-free (floor 0): the nodes (through :mod:`aslip_ros.nodes.common`), the bag reader and
writer (:mod:`aslip_ros.data.bags`) and the launch files all take the names from here. The
QoS of each topic is the nodes' business (nodes/common.py).
"""

from __future__ import annotations

AUDIO = "/aslip/audio"
FINGER = "/aslip/mocap/finger"
OBJECT = "/aslip/mocap/object"
TCP = "/aslip/robot/tcp_pose"
METADATA = "/aslip/metadata"
SLIP = "/aslip/slip"
SLIP_TRUTH = "/aslip/slip_truth"
CALIBRATION = "/aslip/calibration"
MARKER = "/aslip/slip_marker"
CMD_VEL = "/aslip/arm/cmd_vel"
SLIP_STOP_RESULT = "/aslip/slip_stop/result"
DIAGNOSTICS = "/diagnostics"
DIAGNOSTICS_JSON = "/aslip/diagnostics"
TF = "/tf"
TF_STATIC = "/tf_static"
#: mocap4r2's drivers (OptiTrack, Vicon, Qualisys): every rigid body in one
#: mocap4r2_msgs/RigidBodies (aslip_ros/rigid_bodies.py); the drivers' name, not the package's.
RIGID_BODIES = "/rigid_bodies"
#: Simulated time (rosgraph_msgs/Clock): published by scene_sim in lockstep mode.
CLOCK = "/clock"
