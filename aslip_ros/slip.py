"""The slip quantity: the one definition every layer shares (docs/design.md, "Slip").

ROS-free (floor 0). A slip estimate is a probability that the held object slips against
the pads and a slip velocity of the object relative to the gripper, in the pad plane of
``aslip_grasp_plane`` (REP 103 axes: x along the jaw, z up; y is the pad normal), in m/s.
Labels, the dataset's window columns, the losses, every model's velocity output, the
metrics and the message conversion take the components and the decision threshold from
here, so that a new component (rotational slip) is added in one place first.
"""

from __future__ import annotations

#: Components of the slip velocity, in order: the columns of every ``(..., 2)`` velocity
#: array (labels, dataset, model outputs) and the fields of ``SlipVector.velocity``.
VELOCITY_COMPONENTS = ("vx", "vz")
#: The message field of ``geometry_msgs/Vector3`` each component fills, and its index in
#: a grasp-plane (x, y, z) vector (mocap labels keep y for diagnostics: it is not slip).
VELOCITY_FIELDS = ("x", "z")
VELOCITY_AXES = tuple("xyz".index(f) for f in VELOCITY_FIELDS)
N_VELOCITY = len(VELOCITY_COMPONENTS)
VELOCITY_UNIT = "m/s"

#: The paper's decision threshold on p(slip): the default wherever a checkpoint, a node or
#: a metric names none.
DEFAULT_THRESHOLD = 0.5
