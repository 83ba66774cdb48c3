"""Messages <-> numpy: the only module that knows both (docs/design.md, layer rules).

Everything here validates and raises :class:`ValueError` (or its subclass
:class:`AudioFrameError`, which carries a short machine-readable ``reason``) instead of
letting a malformed message turn into NaN further down. No function keeps state.
"""

from __future__ import annotations

import array
import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TwistStamped
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from aslip_ros import frames, poses
# The decoding itself is ROS-free (the exporter uses it too); its names are part of this API.
from aslip_ros.audio_frame import (FULL_SCALE, NS_PER_S, AudioData,  # noqa: F401
                                   AudioFrameError, decode_audio_frame, stamp_to_ns)
from aslip_ros.msg import AudioFrame, SlipVector
# mocap4r2's RigidBodies -> the finger and object poses: ROS-free too (export, check).
from aslip_ros.rigid_bodies import BodyPoses, select_bodies  # noqa: F401
from aslip_ros.slip import ROTATION_EPSILON_RAD_S

#: Default frame of slip vectors (docs/design.md, "Units and frames").
GRASP_FRAME = frames.GRASP_PLANE
#: Default frame of audio blocks.
SENSOR_FRAME = frames.GRIPPER


# --------------------------------------------------------------------------------- time

def ns_to_stamp(ns: int) -> Time:
    """Integer nanoseconds -> ROS time (negative times are refused)."""
    ns = int(ns)
    if ns < 0:
        raise ValueError(f"a ROS stamp cannot be negative, got {ns} ns")
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


# --------------------------------------------------------------------------------- audio

def audio_to_msg(first_sample_index: int, stamp_ns: int, sample_rate: float,
                 channel_names: Sequence[str], block: np.ndarray, layout: str = "",
                 frame_id: str = SENSOR_FRAME) -> AudioFrame:
    """Build an AudioFrame from a ``(frames, channels)`` block (frame-major interleaving)."""
    names = [str(n) for n in channel_names]
    b = np.asarray(block)
    if b.ndim != 2 or b.shape[1] != len(names) or len(names) == 0:
        raise ValueError(f"block must be (frames, {len(names)}) for channels {names}, "
                         f"got {b.shape}")
    if not (math.isfinite(sample_rate) and sample_rate > 0):
        raise ValueError(f"sample_rate must be positive, got {sample_rate}")
    if int(first_sample_index) < 0:
        raise ValueError("first_sample_index must be >= 0")
    msg = AudioFrame()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    msg.sample_rate = float(sample_rate)
    msg.channel_names = names
    msg.layout = str(layout or "")
    msg.first_sample_index = int(first_sample_index)
    data = array.array("f")
    # frombytes on a C-contiguous float32 copy: the generated setter accepts an
    # array.array('f') as is, which is ~100x faster than a list of Python floats.
    data.frombytes(np.ascontiguousarray(b, dtype=np.float32).tobytes())
    msg.data = data
    return msg


def audio_from_msg(msg: AudioFrame, require_finite: bool = True) -> AudioData:
    """Decode and validate an AudioFrame: :func:`aslip_ros.audio_frame.decode_audio_frame`
    (the exporter's check of a recorded block too).

    :raises AudioFrameError: ``no_channels``, ``bad_rate``, ``empty``, ``ragged``,
        ``non_finite`` or ``out_of_range``.
    """
    return decode_audio_frame(msg, require_finite)


# --------------------------------------------------------------------------------- slip

def slip_to_msg(vx: float, vz: float, probability: float, slipping: bool, threshold: float,
                stamp_ns: int, window_length: float, source: str,
                frame_id: str = GRASP_FRAME, direction_sigma: float = -1.0,
                angular_velocity: float = 0.0, angular_sigma: float = -1.0,
                out: Optional[SlipVector] = None) -> SlipVector:
    """Build a SlipVector; refuses non-finite or out-of-range values instead of sending them.

    When ``slipping`` is false the velocity, speed and direction are zero (the paper's zero
    vector), whatever ``vx``/``vz`` say. ``angular_velocity`` [rad/s, about grasp-plane +y]
    and its sigma (negative: none) are not gated by ``slipping``, which is planar: a pure
    rotation is published with ``slipping`` false.

    ``out``: a message to fill instead of a new one (a publisher sending 100 a second reuses
    one; rclpy serialises it in ``publish``). Every field is written, so nothing of the
    message it held before is left; on a refusal it is left untouched.
    """
    # A sum of finite values is finite: one test for the common case, names on failure.
    if not math.isfinite(float(vx) + float(vz) + float(probability) + float(threshold)
                         + float(window_length) + float(direction_sigma)
                         + float(angular_velocity) + float(angular_sigma)):
        values = {"vx": vx, "vz": vz, "probability": probability, "threshold": threshold,
                  "window_length": window_length, "direction_sigma": direction_sigma,
                  "angular_velocity": angular_velocity, "angular_sigma": angular_sigma}
        bad = [k for k, v in values.items() if not math.isfinite(float(v))]
        raise ValueError(f"slip estimate has non-finite {', '.join(bad) or 'sum'}: {values}")
    if not 0.0 <= probability <= 1.0 or not 0.0 <= threshold <= 1.0:
        raise ValueError(f"probability {probability} / threshold {threshold} outside [0, 1]")
    if window_length < 0.0:
        raise ValueError(f"window_length must be >= 0, got {window_length}")
    stamp = ns_to_stamp(stamp_ns)
    msg = SlipVector() if out is None else out
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.probability = float(probability)
    msg.slipping = bool(slipping)
    msg.threshold = float(threshold)
    if slipping:
        msg.velocity.x, msg.velocity.z = float(vx), float(vz)
        msg.speed = float(math.hypot(vx, vz))
        msg.direction = float(math.atan2(vz, vx)) if msg.speed > 0.0 else 0.0
        msg.direction_sigma = float(direction_sigma)
    else:
        msg.velocity.x = msg.velocity.z = msg.speed = msg.direction = 0.0
        msg.direction_sigma = -1.0
    msg.velocity.y = 0.0
    msg.angular_velocity = float(angular_velocity)
    msg.angular_velocity_sigma = float(angular_sigma) if angular_sigma >= 0.0 else -1.0
    msg.window_length = float(window_length)
    msg.source = str(source)
    return msg


def prediction_to_slip(pred, stamp_ns: int, source: str,
                       frame_id: str = GRASP_FRAME) -> SlipVector:
    """A :class:`aslip_ros.learn.inference.predictor.Prediction` as a SlipVector (validated).

    The message's ``threshold`` is the one the prediction's ``slipping`` was decided at
    (``pred.threshold``), never a second value that could disagree with the decision; its
    ``direction_sigma`` is the prediction's, and so are ``angular_velocity`` and its sigma
    (0 and -1, "not estimated", for a prediction without them).
    """
    return slip_to_msg(pred.vx, pred.vz, pred.probability, pred.slipping, pred.threshold,
                       stamp_ns, pred.window_length, source, frame_id,
                       direction_sigma=pred.direction_sigma,
                       angular_velocity=getattr(pred, "angular_velocity", 0.0),
                       angular_sigma=getattr(pred, "angular_sigma", -1.0))


@dataclass(frozen=True)
class SlipData:
    """A validated SlipVector: grasp-plane ``(vx, vz)`` [m/s], the decision, and the
    rotational slip about grasp-plane +y [rad/s] with its sigma (negative: none)."""

    stamp_ns: int
    vx: float
    vz: float
    slipping: bool
    probability: float
    angular_velocity: float = 0.0
    angular_sigma: float = -1.0


def slip_from_msg(msg: SlipVector) -> SlipData:
    """Decode a SlipVector; :class:`ValueError` on NaN/Inf or a probability outside [0, 1]."""
    vx, vz, p = float(msg.velocity.x), float(msg.velocity.z), float(msg.probability)
    w, w_sigma = float(msg.angular_velocity), float(msg.angular_velocity_sigma)
    if not all(math.isfinite(x) for x in (vx, vz, p, w, w_sigma)):
        raise ValueError("SlipVector holds a non-finite value")
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"SlipVector probability {p} outside [0, 1]")
    return SlipData(stamp_to_ns(msg.header.stamp), vx, vz, bool(msg.slipping), p, w,
                    w_sigma if w_sigma >= 0.0 else -1.0)


# --------------------------------------------------------------------------------- poses

def pose_to_msg(pose7: Sequence[float], stamp_ns: int, frame_id: str) -> PoseStamped:
    """pose7 ``(x, y, z, qx, qy, qz, qw)`` -> PoseStamped."""
    p = _pose7(pose7)
    msg = PoseStamped()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    pos, q = msg.pose.position, msg.pose.orientation
    pos.x, pos.y, pos.z = float(p[0]), float(p[1]), float(p[2])
    q.x, q.y, q.z, q.w = float(p[3]), float(p[4]), float(p[5]), float(p[6])
    return msg


def pose_from_msg(msg: PoseStamped) -> tuple:
    """PoseStamped -> ``(stamp_ns, frame_id, pose7)`` with a unit quaternion.

    :raises ValueError: non-finite values or a zero quaternion.
    """
    pos, q = msg.pose.position, msg.pose.orientation
    p = _pose7([pos.x, pos.y, pos.z, q.x, q.y, q.z, q.w])
    return stamp_to_ns(msg.header.stamp), str(msg.header.frame_id), p


def _pose7(pose7: Sequence[float]) -> np.ndarray:
    return poses.as_pose(pose7, "pose")


def rigid_bodies_class():
    """``mocap4r2_msgs/RigidBodies``, imported only where it is used: the package runs
    without mocap4r2. ValueError saying what to install when it is missing."""
    try:
        from mocap4r2_msgs.msg import RigidBodies
    except ImportError as exc:
        raise ValueError(f"the mocap4r2_msgs package is not installed (sudo apt install "
                         f"ros-jazzy-mocap4r2-msgs, or build it in your workspace): "
                         f"{exc}") from None
    return RigidBodies


# --------------------------------------------------------------------------------- twist

def twist_to_msg(v_xyz: Sequence[float], stamp_ns: int, frame_id: str = frames.BASE
                 ) -> TwistStamped:
    """A linear velocity [m/s] as TwistStamped (angular part zero)."""
    v = np.asarray(v_xyz, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ValueError(f"velocity must be 3 finite numbers, got {v_xyz!r}")
    msg = TwistStamped()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    msg.twist.linear.x, msg.twist.linear.y, msg.twist.linear.z = (float(x) for x in v)
    return msg


def twist_from_msg(msg: TwistStamped) -> np.ndarray:
    """TwistStamped -> linear velocity ``(3,)`` [m/s]; ValueError on NaN/Inf."""
    lin = msg.twist.linear
    v = np.array([lin.x, lin.y, lin.z], dtype=np.float64)
    if not np.isfinite(v).all():
        raise ValueError(f"twist holds a non-finite value: {v.tolist()}")
    return v


# --------------------------------------------------------------------------------- rviz

def probability_color(p: float, alpha: float = 1.0) -> ColorRGBA:
    """Green at p = 0 through yellow to red at p = 1."""
    p = min(1.0, max(0.0, float(p))) if math.isfinite(p) else 0.0
    return ColorRGBA(r=min(1.0, 2.0 * p), g=min(1.0, 2.0 * (1.0 - p)), b=0.0, a=float(alpha))


def slip_markers(msg: SlipVector, ns: str = "aslip_slip", scale_s: float = 2.0,
                 shaft_m: float = 0.004, lifetime_s: float = 0.5,
                 alpha: Optional[float] = None, arc_radius_m: float = 0.02) -> MarkerArray:
    """rviz markers for a SlipVector, in its own frame.

    An arrow from the grasp-plane origin along the slip velocity (``scale_s`` metres of arrow
    per m/s of slip: where the object goes in ``scale_s`` seconds; deleted while not
    slipping), a sphere at the origin and, for the rotational slip, an arc of radius
    ``arc_radius_m`` about the pad normal (+y) from the top of the pad (+z), turning the way
    the object turns, through the angle it turns in ``scale_s`` seconds
    (``angular_velocity * scale_s``, below one full turn) with an arrow head at its end
    (both deleted while ``|angular_velocity|`` is at most
    ``aslip_ros.slip.ROTATION_EPSILON_RAD_S``); all colored by the slip probability.
    """
    if not (math.isfinite(scale_s) and scale_s > 0):
        raise ValueError(f"scale_s must be positive, got {scale_s}")
    color = probability_color(msg.probability, 1.0 if alpha is None else alpha)
    life_ns = int(lifetime_s * NS_PER_S)
    arrow = Marker()
    arrow.header = msg.header
    arrow.ns, arrow.id, arrow.type = ns, 0, Marker.ARROW
    arrow.lifetime.sec, arrow.lifetime.nanosec = life_ns // NS_PER_S, life_ns % NS_PER_S
    if msg.slipping and msg.speed > 0.0:
        arrow.action = Marker.ADD
        arrow.pose.orientation.w = 1.0
        tip = arrow.points
        start, end = type(arrow.pose.position)(), type(arrow.pose.position)()
        end.x = float(msg.velocity.x) * scale_s
        end.z = float(msg.velocity.z) * scale_s
        tip.extend([start, end])
        arrow.scale.x, arrow.scale.y, arrow.scale.z = shaft_m, 2.0 * shaft_m, 3.0 * shaft_m
        arrow.color = color
    else:
        arrow.action = Marker.DELETE
    dot = Marker()
    dot.header = msg.header
    dot.ns, dot.id, dot.type, dot.action = ns, 1, Marker.SPHERE, Marker.ADD
    dot.lifetime = arrow.lifetime
    dot.pose.orientation.w = 1.0
    dot.scale.x = dot.scale.y = dot.scale.z = 3.0 * shaft_m
    dot.color = color
    arc, head = _rotation_markers(msg, ns, scale_s * float(msg.angular_velocity),
                                  arc_radius_m, shaft_m, color)
    arc.lifetime = head.lifetime = arrow.lifetime
    return MarkerArray(markers=[arrow, dot, arc, head])


def _rotation_markers(msg: SlipVector, ns: str, sweep_rad: float, radius_m: float,
                      shaft_m: float, color: ColorRGBA) -> tuple:
    """The rotation's arc (LINE_STRIP, id 2) and its arrow head (ARROW, id 3)."""
    arc, head = Marker(), Marker()
    for m, k, kind in ((arc, 2, Marker.LINE_STRIP), (head, 3, Marker.ARROW)):
        m.header = msg.header
        m.ns, m.id, m.type = ns, k, kind
    if not abs(float(msg.angular_velocity)) > ROTATION_EPSILON_RAD_S:
        arc.action = head.action = Marker.DELETE
        return arc, head
    sweep = max(-1.9 * math.pi, min(1.9 * math.pi, sweep_rad))
    Point = type(arc.pose.position)
    # A turn by s about +y carries the top of the pad (0, 0, r) to r (sin s, 0, cos s).
    n = max(2, int(math.ceil(abs(sweep) / (math.pi / 24)))) + 1
    for j in range(n):
        a = sweep * j / (n - 1)
        arc.points.append(Point(x=radius_m * math.sin(a), y=0.0, z=radius_m * math.cos(a)))
    end = arc.points[-1]
    # Tangent at the end, the way it turns, as long as the planar arrow's head.
    turn = 1.0 if sweep > 0 else -1.0
    tx, tz = turn * math.cos(sweep), -turn * math.sin(sweep)
    tail = Point(x=end.x - 3.0 * shaft_m * tx, y=0.0, z=end.z - 3.0 * shaft_m * tz)
    head.points.extend([tail, Point(x=end.x + 3.0 * shaft_m * tx, y=0.0,
                                    z=end.z + 3.0 * shaft_m * tz)])
    for m in (arc, head):
        m.action = Marker.ADD
        m.pose.orientation.w = 1.0
        m.color = color
    arc.scale.x = shaft_m
    head.scale.x, head.scale.y, head.scale.z = shaft_m, 2.0 * shaft_m, 3.0 * shaft_m
    return arc, head
