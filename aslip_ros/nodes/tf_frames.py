"""TF for the aslip frames: ``/tf`` and ``/tf_static`` with tf2's QoS and message type.

``tf2_msgs/msg/TFMessage`` comes from a ROS 2 install's tf2_msgs; in the pinned venv (no
wheel) from the identical definition in compat/tf2_msgs, which ``make setup`` builds there,
so rviz, tf2 and ``ros2 bag`` see the standard type either way. The publishers are the
few lines of tf2_ros's broadcasters (which the venv lacks) with the same QoS: a listener
cannot tell them apart.
"""

from __future__ import annotations

import threading
from typing import Iterable, Optional

from geometry_msgs.msg import TransformStamped

try:
    from tf2_msgs.msg import TFMessage
except ImportError as exc:   # a stale build; a clear refusal rather than a traceback
    from aslip_ros.runtime.process import ConfigError
    raise ConfigError(f"TF needs tf2_msgs (a ROS 2 install provides it; in the venv "
                      f"`make setup` builds compat/tf2_msgs): {exc}") from exc

from aslip_ros import topics
from aslip_ros.control.frames import as_pose
from aslip_ros.nodes import convert
from aslip_ros.runtime.qos import TF_QOS, TF_STATIC_QOS

TF_TOPIC = topics.TF
TF_STATIC_TOPIC = topics.TF_STATIC


def transform_msg(parent: str, child: str, pose, stamp_ns: int) -> TransformStamped:
    """``child``'s pose ``(x, y, z, qx, qy, qz, qw)`` in ``parent`` as a TransformStamped.

    :raises ValueError: a malformed pose (see :func:`aslip_ros.control.frames.as_pose`).
    """
    p = as_pose(pose, f"{child} in {parent}")
    msg = TransformStamped()
    msg.header.stamp = convert.ns_to_stamp(stamp_ns)
    msg.header.frame_id = parent
    msg.child_frame_id = child
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = (float(x) for x in p[:3])
    r.x, r.y, r.z, r.w = (float(x) for x in p[3:])
    return msg


def transform_pose(msg: TransformStamped) -> tuple:
    """``(stamp_ns, parent, child, pose)`` of a TransformStamped."""
    t, r = msg.transform.translation, msg.transform.rotation
    return (convert.stamp_to_ns(msg.header.stamp), msg.header.frame_id, msg.child_frame_id,
            [t.x, t.y, t.z, r.x, r.y, r.z, r.w])


class StaticFrames:
    """One node's static transforms on ``/tf_static``.

    The topic keeps one message per publisher (depth 1, transient local), so every change
    re-sends the node's whole set, as tf2_ros's StaticTransformBroadcaster does.
    """

    def __init__(self, node) -> None:
        self._node = node
        self._pub = node.create_publisher(TFMessage, TF_STATIC_TOPIC, TF_STATIC_QOS)
        self._by_child: dict = {}
        self._lock = threading.Lock()       # callbacks of several groups may add frames

    def set(self, parent: str, child: str, pose, stamp_ns: Optional[int] = None) -> None:
        """Add or replace ``child``'s transform and publish the set."""
        if stamp_ns is None:
            stamp_ns = self._node.get_clock().now().nanoseconds
        msg = transform_msg(parent, child, pose, stamp_ns)
        with self._lock:
            self._by_child[child] = msg
            self._pub.publish(TFMessage(transforms=list(self._by_child.values())))


class DynamicFrames:
    """Moving frames on ``/tf``; nothing is built or sent while nobody listens."""

    def __init__(self, node) -> None:
        self._pub = node.create_publisher(TFMessage, TF_TOPIC, TF_QOS)

    @property
    def wanted(self) -> bool:
        """Whether a subscriber (rviz, a tf2 listener, a bag recorder) is there."""
        return self._pub.get_subscription_count() > 0

    def publish(self, transforms: Iterable[TransformStamped]) -> None:
        """Send ``transforms`` in one message (none: nothing is sent)."""
        transforms = list(transforms)
        if transforms:
            self._pub.publish(TFMessage(transforms=transforms))
