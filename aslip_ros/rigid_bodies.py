"""Motion capture as one message of every rigid body: the finger and the object picked out of
a ``mocap4r2_msgs/RigidBodies`` by name or numeric ID (the one definition of that decoding).

mocap4r2's drivers (OptiTrack, Vicon, Qualisys) publish no PoseStamped: one
``RigidBodies`` (``header``, ``frame_number``, ``RigidBody[] rigidbodies``, each with
``rigid_body_name``, ``markers`` and a ``geometry_msgs/Pose``) carries every tracked body.
OptiTrack's names them by the Motive body's numeric ID as text (``"3"``), Vicon's by the
subject's name. A body is selected by that name; a name that is a number matches the same
number however written (``3``, ``"3"``, ``"03"``).

Poses come out as sent: pose7 ``(x, y, z, qx, qy, qz, qw)`` float64 in the message's
``header.frame_id`` (OptiTrack: ``map``), stamped by the header; both bodies of a message
share its frame and stamp. Validation is the caller's, as for a PoseStamped: the nodes
refuse a bad pose with :func:`aslip_ros.poses.as_pose`, the exporter's
:class:`~aslip_ros.data.labels.PoseTrack` drops it as a lost frame. A body absent from a
message is named, with the bodies that are present (:attr:`BodyPoses.missing_text`,
:class:`BodyTally`).

ROS-free (floor 0): mocap_bridge, ``aslip check mocap`` and ``aslip export`` all decode
here, rclpy and rosbags messages alike (same field names).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Mapping, Tuple

import numpy as np

from aslip_ros.audio_frame import stamp_to_ns

#: The message type, as rosbag2 and rosbags name it.
RIGID_BODIES_TYPE = "mocap4r2_msgs/msg/RigidBodies"
#: mocap_bridge's ``pose_source``: two PoseStamped topics, or one RigidBodies topic.
POSE_STAMPED = "pose_stamped"
RIGID_BODIES = "rigid_bodies"
POSE_SOURCES = (POSE_STAMPED, RIGID_BODIES)
#: The bodies a recording needs, by role.
ROLES = ("finger", "object")


def body_key(name) -> str:
    """The form in which body names compare: a number as its decimal digits, any other
    name as written (without surrounding blanks)."""
    text = str(name).strip()
    return str(int(text)) if text.isdigit() else text


def _names(names) -> str:
    return ", ".join(repr(n) for n in names) if names else "none"


def missing_text(bodies: Mapping[str, str], missing, present, where: str = "") -> str:
    """``rigid body '7' (object) is not in <where>; bodies present: '3', '5'``."""
    if not missing:
        return ""
    which = " and ".join(f"{bodies[r]!r} ({r})" for r in missing)
    verb = "is" if len(missing) == 1 else "are"
    return (f"rigid body {which} {verb} not in {where or 'the RigidBodies message'}; "
            f"bodies present: {_names(present)}")


@dataclass(frozen=True)
class BodyPoses:
    """The chosen bodies of one RigidBodies message.

    ``poses``: role -> pose7 as sent, for each body found; ``missing``: the roles whose body
    is not in the message; ``present``: the names of every body in it, in order.
    """

    stamp_ns: int
    frame_id: str
    frame_number: int
    bodies: Mapping[str, str]
    poses: Dict[str, np.ndarray]
    missing: Tuple[str, ...] = ()
    present: Tuple[str, ...] = ()

    @property
    def missing_text(self) -> str:
        """What is missing, naming the bodies present ('' when none is)."""
        return missing_text(self.bodies, self.missing, self.present)


def select_bodies(msg, bodies: Mapping[str, str]) -> BodyPoses:
    """Pick ``bodies`` (role -> body name or ID, e.g. ``{"finger": "3", "object": "5"}``)
    out of a ``RigidBodies`` message (rclpy or rosbags); the first body of a name counts.

    :raises ValueError: an empty body name.
    """
    wanted = {}
    for role, name in bodies.items():
        key = body_key(name)
        if not key:
            raise ValueError(f"no rigid body named for the {role}")
        wanted[role] = key
    found: Dict[str, np.ndarray] = {}
    present = []
    for body in msg.rigidbodies:
        name = str(body.rigid_body_name)
        present.append(name)
        key = body_key(name)
        for role, want in wanted.items():
            if want == key and role not in found:
                p, q = body.pose.position, body.pose.orientation
                found[role] = np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=np.float64)
    missing = tuple(r for r in wanted if r not in found)
    return BodyPoses(stamp_to_ns(msg.header.stamp), str(msg.header.frame_id),
                     int(msg.frame_number), dict(bodies), found, missing, tuple(present))


@dataclass
class BodyTally:
    """Counts over a stream of :class:`BodyPoses`: messages, and per role how many lacked
    its body, with every body name seen (for the diagnostics of a node, a check, an
    export)."""

    bodies: Mapping[str, str]
    messages: int = 0
    missing: Dict[str, int] = field(default_factory=dict)
    seen: Dict[str, None] = field(default_factory=dict)     # names, first-seen order

    def add(self, sel: BodyPoses) -> None:
        """Count one message."""
        self.messages += 1
        for r in sel.missing:
            self.missing[r] = self.missing.get(r, 0) + 1
        for name in sel.present:
            self.seen.setdefault(name, None)

    def text(self, where: str = "RigidBodies messages") -> str:
        """'' when every message held every body; else which bodies were missing from how
        many messages, naming the bodies seen."""
        if not any(self.missing.values()):
            return ""
        parts = []
        for role, n in self.missing.items():
            if n == self.messages:
                parts.append(f"rigid body {self.bodies[role]!r} ({role}) is in none of the "
                             f"{n} {where}")
            elif n:
                parts.append(f"rigid body {self.bodies[role]!r} ({role}) is missing from "
                             f"{n} of the {self.messages} {where}")
        return "; ".join(parts) + f"; bodies present: {_names(list(self.seen))}"
