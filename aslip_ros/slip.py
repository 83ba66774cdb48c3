"""The slip quantity: the one definition every layer shares (docs/design.md, "Slip").

ROS-free (floor 0). A slip estimate is a probability that the held object slips against
the pads, a slip velocity of the object relative to the gripper, in the pad plane of
``aslip_grasp_plane`` (REP 103 axes: x along the jaw, z up; y is the pad normal), in m/s,
and a rotational slip rate about the pad normal, in rad/s. Labels, the dataset's window
columns, the losses, every model's outputs, the metrics and the message conversion take the
components, the thresholds and the kind of a slip from here.
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

#: Rotational slip: the angular velocity of the object relative to the finger about +y of
#: ``aslip_grasp_plane`` (the pad normal; REP 103, right-handed), in rad/s. The dataset's
#: column, the labels, every model's rotational output and ``SlipVector.angular_velocity``
#: carry this one component. It is separate from the planar slip above: ``slipping``, the
#: probability and the dataset's ``slip`` column stay planar, and a consumer acts on
#: ``|wy|`` itself. The planar velocity is that of the object's material point at the
#: grasp-plane origin (the pad centre), ``v_c = dr/dt - w x r``; the local slip velocity at
#: an in-plane pad point ``(x, z)`` is then ``(vx + wy * z, vz - wy * x)``.
ANGULAR_COMPONENT = "wy"
#: Its axis in a grasp-plane (x, y, z) vector.
ANGULAR_AXIS = "xyz".index("y")
ANGULAR_UNIT = "rad/s"
#: Reference radius of the contact patch [m]: turns a rate into the rim speed
#: ``|wy| * ROTATION_RADIUS_M`` [m/s] (loss scaling, translation-vs-rotation decision).
ROTATION_RADIUS_M = 0.01
#: A window rotates when ``|wy|`` exceeds this [rad/s]: 5 mm/s at the 10 mm reference radius,
#: the planar label's 5 mm/s threshold (``data.labels.DEFAULT_EPSILON_M_S``).
ROTATION_EPSILON_RAD_S = 0.5
#: The two kinds of a slipping window, :func:`slip_kind`.
SLIP_KINDS = ("translation", "rotation")


def rim_speed(wy):
    """The speed ``|wy| * ROTATION_RADIUS_M`` [m/s] that a rotation ``wy`` [rad/s] gives the
    rim of the reference contact patch (a number or a numpy array)."""
    return abs(wy) * ROTATION_RADIUS_M


def is_rotation(speed, wy):
    """Whether a slip is of the kind "rotation": the rim speed of ``wy`` [rad/s] exceeds the
    planar ``speed`` [m/s] (numbers or numpy arrays, elementwise)."""
    return rim_speed(wy) > speed


def slip_kind(speed: float, wy: float) -> str:
    """The kind of one slip, ``"rotation"`` or ``"translation"`` (:func:`is_rotation`)."""
    return SLIP_KINDS[1] if is_rotation(speed, wy) else SLIP_KINDS[0]
