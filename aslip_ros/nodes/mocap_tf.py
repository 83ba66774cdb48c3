"""The motion-capture frames on TF, for a graph whose driver publishes none.

vrpn_mocap and mocap4r2 publish the rigid bodies as pose messages only, so on a real cell
nothing joins the finger and object frames to ``world``, and rviz can place neither the
slip arrows (``aslip_grasp_plane`` hangs below the finger) nor the bodies. mocap_bridge
feeds every pose it accepts to :class:`MocapFrames`, which publishes (aslip_ros/frames.py):

- ``world`` -> ``finger_frame`` and ``world`` -> ``object_frame`` on ``/tf``, each pose
  under the frame its message is stamped in, with the message's stamp;
- that frame -> ``world``, static identity, when the driver names the mocap world
  otherwise (``mocap``, ``map``): it is the frame this package calls ``world``;
- ``world`` -> ``link_base``, static ``base_in_world``, when ``publish_base_tf`` (the
  robot's base in the mocap world: the cell's, measured once), so the TCP shows too.

``publish_pose_tf: false`` where the driver (or the scene) already publishes the bodies.
"""

from __future__ import annotations

from typing import Optional

from aslip_ros import frames, poses
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import ConfigError

IDENTITY = [float(x) for x in poses.IDENTITY_POSE]


def mocap_tf_params() -> list:
    """The parameters :class:`MocapFrames` reads (declared by mocap_bridge)."""
    return [
        c.Param("publish_pose_tf", True,
                "publish the finger and object poses on /tf (false where the motion-capture "
                "driver or the scene already does)", read_only=True),
        c.Param("object_frame", frames.OBJECT, "TF frame of the object rigid body",
                c.non_empty, read_only=True),
        c.Param("publish_base_tf", False,
                "publish base_in_world as the static world -> link_base", read_only=True),
        c.Param("base_in_world", list(IDENTITY),
                "the arm's link_base in the motion-capture world (x y z qx qy qz qw) [m]",
                c.pose7, read_only=True),
    ]


class MocapFrames:
    """Publishes what a pose stream implies on TF; ``static`` is the node's StaticFrames
    (one latched set per node), created here when the node has none."""

    def __init__(self, node, p: dict, static=None) -> None:
        from aslip_ros.nodes import tf_frames
        self._node = node
        self._tf = tf_frames
        self._child = {"finger": p["finger_frame"], "object": p["object_frame"]}
        if self._child["finger"] == self._child["object"]:
            raise ConfigError(f"finger_frame and object_frame must differ (both "
                              f"{self._child['finger']!r})")
        self._poses = bool(p["publish_pose_tf"])
        self._static = static
        self._dynamic = tf_frames.DynamicFrames(node) if self._poses else None
        self._worlds: set = {frames.WORLD}
        if (self._poses or p["publish_base_tf"]) and self._static is None:
            self._static = tf_frames.StaticFrames(node)
        if p["publish_base_tf"]:
            self._static.set(frames.WORLD, frames.BASE, p["base_in_world"])

    def pose(self, which: str, stamp_ns: int, frame_id: str, pose) -> Optional[str]:
        """Publish body ``which`` (finger, object) at ``pose`` in ``frame_id``; returns why
        it was not published, or None."""
        if not self._poses:
            return None
        child = self._child[which]
        parent = frame_id or frames.WORLD
        if parent == child:
            return f"{which} pose is stamped in its own TF frame {child!r}"
        if parent not in self._worlds:
            self._worlds.add(parent)
            self._static.set(frames.WORLD, parent, IDENTITY)
            self._node.get_logger().info(
                f"the motion capture's frame {parent!r} is {frames.WORLD!r}: published as "
                "an identity transform")
        if self._dynamic.wanted:
            self._dynamic.publish([self._tf.transform_msg(parent, child, pose, stamp_ns)])
        return None
