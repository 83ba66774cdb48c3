"""Coordinate frame names and the TF tree the nodes publish (docs/design.md, "Units and frames").

The one definition of the frame names: nodes, message conversion and the tests take them
from here. ROS-free (floor 0), so the core can name frames too.

Tree (child -> parent) and who publishes each edge:

- ``link_base`` -> ``world``: static; the scene (they coincide there). On a real cell the
  motion-capture-to-robot calibration: mocap_bridge's ``base_in_world``, or
  ``static_transform_publisher``.
- ``aslip_tcp`` -> ``link_base``: the arm's TCP; the scene (on a real cell, the arm driver).
- ``aslip_finger``, ``aslip_object`` -> ``world``: the motion-capture rigid bodies; the
  scene; on a real cell mocap_bridge from the poses (``publish_pose_tf``), or the
  motion-capture driver's TF with its frame named in mocap_bridge's ``finger_frame``.
- ``aslip_grasp_plane`` -> ``aslip_finger``: static, ``grasp_plane_in_finger``; mocap_bridge,
  from the calibration it uses for the ground truth.
- ``aslip_gripper`` -> ``aslip_grasp_plane``: static identity; mocap_bridge. The audio
  frame: microphone positions are given in grasp-plane coordinates (scene/layouts.py).
"""

from __future__ import annotations

from typing import Mapping

WORLD = "world"
BASE = "link_base"
TCP = "aslip_tcp"
FINGER = "aslip_finger"
OBJECT = "aslip_object"
GRASP_PLANE = "aslip_grasp_plane"
GRIPPER = "aslip_gripper"

#: child -> parent of every edge the nodes publish.
TF_TREE: Mapping[str, str] = {BASE: WORLD, TCP: BASE, FINGER: WORLD, OBJECT: WORLD,
                              GRASP_PLANE: FINGER, GRIPPER: GRASP_PLANE}


def chain(frame: str, tree: Mapping[str, str] = TF_TREE) -> list:
    """``frame`` and its ancestors up to the root of ``tree`` (child -> parent edges).

    :raises ValueError: the edges loop.
    """
    out = [frame]
    while out[-1] in tree:
        out.append(tree[out[-1]])
        if out[-1] in out[:-1]:
            raise ValueError(f"the TF edges loop: {' -> '.join(out)}")
    return out


def connected(a: str, b: str, tree: Mapping[str, str] = TF_TREE) -> bool:
    """True when ``tree`` joins frames ``a`` and ``b`` (a transform between them exists)."""
    return chain(a, tree)[-1] == chain(b, tree)[-1]
