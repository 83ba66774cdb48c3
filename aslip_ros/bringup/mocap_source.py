"""Where a bring-up check takes the finger's and the object's poses: one PoseStamped topic
per body, or the bodies of a mocap4r2 ``RigidBodies`` topic picked by name or numeric ID
(:mod:`aslip_ros.rigid_bodies`).

One resolution for ``aslip check mocap``, ``grasp-plane`` and ``grasp-axes``, with the same
options (``--finger-topic``/``--object-topic``, ``--finger-body``/``--object-body``,
``--rigid-bodies-topic``): the options where given, else the cell file's ``mocap_bridge``
section (the bridge's own keys: ``pose_source``, ``finger_topic``, ``object_topic``,
``finger_body``, ``object_body``, ``rigid_bodies_topic``), else the bridge's defaults. A
cell that says ``pose_source: rigid_bodies`` thus needs no option. ROS-free.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import Dict, Sequence

from aslip_ros import topics
from aslip_ros.rigid_bodies import POSE_SOURCES, POSE_STAMPED, RIGID_BODIES, ROLES

#: The bridge's default PoseStamped topic of each body.
DEFAULT_TOPICS = {"finger": topics.FINGER, "object": topics.OBJECT}


@dataclass(frozen=True)
class MocapSource:
    """The chosen poses: ``topics`` (role -> PoseStamped topic), or with ``bodies`` (role ->
    rigid body name or ID) the RigidBodies on ``rigid_bodies_topic``."""

    topics: Dict[str, str] = field(default_factory=dict)
    rigid_bodies_topic: str = ""
    bodies: Dict[str, str] = field(default_factory=dict)

    @property
    def rigid(self) -> bool:
        """The poses come from a RigidBodies topic."""
        return bool(self.bodies)

    def text(self) -> str:
        """``/rigid_bodies bodies '3' (finger) and '5' (object)``, or the topics."""
        if self.rigid:
            named = " and ".join(f"{b!r} ({r})" for r, b in self.bodies.items())
            return f"{self.rigid_bodies_topic} bod{'ies' if len(self.bodies) > 1 else 'y'} " \
                f"{named}"
        return ", ".join(self.topics.values())


def add_arguments(p: argparse.ArgumentParser, roles: Sequence[str] = ROLES) -> None:
    """The options choosing the poses of ``roles`` (every default is resolved later, by
    :func:`resolve`, so that a cell file can give it)."""
    for role in roles:
        p.add_argument(f"--{role}-topic", help=f"{role} PoseStamped topic (default: the "
                       f"--setup cell's mocap_bridge.{role}_topic, else {DEFAULT_TOPICS[role]})")
    for role in roles:
        p.add_argument(f"--{role}-body", metavar="NAME_OR_ID", help=(
            f"mocap4r2: the {role}'s rigid body in the RigidBodies (its name, or its numeric "
            "ID as OptiTrack names them) instead of a PoseStamped topic (default: the "
            f"--setup cell's mocap_bridge.{role}_body where its pose_source is "
            "rigid_bodies)"))
    p.add_argument("--rigid-bodies-topic", help="mocap4r2: the RigidBodies topic (default: "
                   "the --setup cell's mocap_bridge.rigid_bodies_topic, else "
                   f"{topics.RIGID_BODIES})")


def _flags(roles: Sequence[str]) -> str:
    return " and ".join(f"--{r}-body" for r in roles)


def resolve(args: argparse.Namespace, cell=None, roles: Sequence[str] = ROLES) -> MocapSource:
    """The poses of ``roles`` from the options in ``args`` (:func:`add_arguments`) and the
    cell (:class:`aslip_ros.cell.Cell`, or None).

    :raises ValueError: bodies named for some roles only, bodies and topics both given, or a
        cell whose ``pose_source`` is unknown or lacks a body.
    """
    given = {r: getattr(args, f"{r}_body", None) for r in roles}
    named_topics = [r for r in roles if getattr(args, f"{r}_topic", None)]
    mocap = cell.section("mocap_bridge") if cell is not None else {}
    where = f"cell file {cell.path}: mocap_bridge" if cell is not None else ""
    rb_topic = str(getattr(args, "rigid_bodies_topic", None) or mocap.get("rigid_bodies_topic")
                   or topics.RIGID_BODIES)
    if any(v not in (None, "") for v in given.values()):
        if not all(str(v or "").strip() for v in given.values()):
            raise ValueError(f"{_flags(roles)} go together (the rigid bodies of the "
                             "RigidBodies)")
        if named_topics:
            raise ValueError(f"{_flags(roles)} and "
                             f"{' and '.join(f'--{r}-topic' for r in named_topics)} exclude "
                             "each other (a RigidBodies topic, or PoseStamped topics)")
        return MocapSource(rigid_bodies_topic=rb_topic,
                           bodies={r: str(v).strip() for r, v in given.items()})
    source = str(mocap.get("pose_source", POSE_STAMPED))
    if source not in POSE_SOURCES:
        raise ValueError(f"{where}.pose_source is {source!r}: one of "
                         f"{', '.join(POSE_SOURCES)}")
    if source == RIGID_BODIES and not named_topics:
        bodies = {r: str(mocap.get(f"{r}_body", "")).strip() for r in roles}
        lacking = [f"{r}_body" for r, b in bodies.items() if not b]
        if lacking:
            raise ValueError(f"{where}.pose_source rigid_bodies needs "
                             f"{' and '.join(lacking)} (the rigid body's name or numeric ID)")
        return MocapSource(rigid_bodies_topic=rb_topic, bodies=bodies)
    return MocapSource(topics={r: str(getattr(args, f"{r}_topic", None)
                                      or mocap.get(f"{r}_topic") or DEFAULT_TOPICS[r])
                               for r in roles})
