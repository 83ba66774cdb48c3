"""The scene's simulated arm as an :class:`aslip_ros.arm.Arm`: commands on a topic.

``scene_sim`` executes ``/aslip/arm/cmd_vel`` (TwistStamped, ``link_base``) on the scene's
arm and publishes the TCP on ``/aslip/robot/tcp_pose``, which the controller hands back
here with :meth:`TopicArm.set_pose`.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from geometry_msgs.msg import TwistStamped
from rclpy.duration import Duration

from aslip_ros import frames
from aslip_ros.arm import ArmError
from aslip_ros.nodes import common as c
from aslip_ros.runtime.qos import RELIABLE_QOS
from aslip_ros.nodes import convert


#: How long :meth:`TopicArm.close` waits for the readers to acknowledge the final stop [s]:
#: 1 s was too short beside two busy loops (the warning below, 1 launch in 2); the wait
#: stays well inside the process's forced-exit grace (runtime/process.py EXIT_GRACE_S).
ACK_TIMEOUT_S = 2.0


class TopicArm:
    """An :class:`aslip_ros.arm.Arm` whose commands go out as TwistStamped.

    The receiver (``scene_sim``) holds each command for its ``command_timeout_s``, which
    plays the role of ``duration_s``; a zero twist is a stop.
    """

    #: Publishing never waits for the receiver: no need for an arm thread.
    blocking = False

    def __init__(self, node, topic: str = c.CMD_VEL_TOPIC, frame_id: str = frames.BASE):
        self._node = node
        self._pub = node.create_publisher(TwistStamped, topic, RELIABLE_QOS)
        self._frame = frame_id
        self._pose: Optional[np.ndarray] = None
        self._enabled = False
        self.commands = 0
        #: Messages published, velocities and stops (a lockstep driver waits for the
        #: receiver to have them all).
        self.published = 0

    def connect(self) -> None:
        """Nothing to open: the topic exists once the publisher does."""

    def enable_velocity_mode(self) -> None:
        """Accept velocity commands from now on."""
        self._enabled = True

    def send_velocity(self, v_xyz_m_s, duration_s: float) -> None:
        """Publish a velocity command [m/s, ``link_base``]."""
        if not self._enabled:
            raise ArmError("velocity mode is not enabled")
        now = self._node.get_clock().now().nanoseconds
        self._pub.publish(convert.twist_to_msg(v_xyz_m_s, now, self._frame))
        self.commands += 1
        self.published += 1

    def stop(self) -> None:
        """Publish a zero twist (a stop)."""
        now = self._node.get_clock().now().nanoseconds
        self._pub.publish(convert.twist_to_msg([0.0, 0.0, 0.0], now, self._frame))
        self.published += 1

    def set_pose(self, pose: np.ndarray) -> None:
        """Newest TCP pose from the TCP topic."""
        self._pose = pose

    def tcp_pose(self) -> np.ndarray:
        """Newest TCP pose received."""
        if self._pose is None:
            raise ArmError("no TCP pose received yet")
        return self._pose.copy()

    def close(self) -> None:
        """Stop, and wait (at most ``ACK_TIMEOUT_S``) until the readers have the stop.

        The publisher goes with the node, and the node is destroyed right after this at
        process exit: a reliable sample that no reader has acknowledged by then is lost.
        Without this wait, the launch's receivers last saw a moving command in 1 of 2 runs
        of a loaded machine."""
        self._enabled = False
        self.stop()
        if not self._pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S)):
            self._node.get_logger().warning(
                f"the final stop was not acknowledged by every reader within {ACK_TIMEOUT_S} s")
