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
                frame_id: str = GRASP_FRAME, direction_sigma: float = -1.0) -> SlipVector:
    """Build a SlipVector; refuses non-finite or out-of-range values instead of sending them.

    When ``slipping`` is false the velocity, speed and direction are zero (the paper's zero
    vector), whatever ``vx``/``vz`` say.
    """
    values = {"vx": vx, "vz": vz, "probability": probability, "threshold": threshold,
              "window_length": window_length, "direction_sigma": direction_sigma}
    bad = [k for k, v in values.items() if not math.isfinite(float(v))]
    if bad:
        raise ValueError(f"slip estimate has non-finite {', '.join(bad)}: {values}")
    if not 0.0 <= probability <= 1.0 or not 0.0 <= threshold <= 1.0:
        raise ValueError(f"probability {probability} / threshold {threshold} outside [0, 1]")
    if window_length < 0.0:
        raise ValueError(f"window_length must be >= 0, got {window_length}")
    msg = SlipVector()
    msg.header.stamp = ns_to_stamp(stamp_ns)
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
        msg.direction_sigma = -1.0
    msg.velocity.y = 0.0
    msg.window_length = float(window_length)
    msg.source = str(source)
    return msg


def prediction_to_slip(pred, stamp_ns: int, source: str,
                       frame_id: str = GRASP_FRAME) -> SlipVector:
    """A :class:`aslip_ros.learn.inference.predictor.Prediction` as a SlipVector (validated).

    The message's ``threshold`` is the one the prediction's ``slipping`` was decided at
    (``pred.threshold``), never a second value that could disagree with the decision; its
    ``direction_sigma`` is the prediction's.
    """
    return slip_to_msg(pred.vx, pred.vz, pred.probability, pred.slipping, pred.threshold,
                       stamp_ns, pred.window_length, source, frame_id,
                       direction_sigma=pred.direction_sigma)


@dataclass(frozen=True)
class SlipData:
    """A validated SlipVector: grasp-plane ``(vx, vz)`` [m/s] and the decision."""

    stamp_ns: int
    vx: float
    vz: float
    slipping: bool
    probability: float


def slip_from_msg(msg: SlipVector) -> SlipData:
    """Decode a SlipVector; :class:`ValueError` on NaN/Inf or a probability outside [0, 1]."""
    vx, vz, p = float(msg.velocity.x), float(msg.velocity.z), float(msg.probability)
    if not (math.isfinite(vx) and math.isfinite(vz) and math.isfinite(p)):
        raise ValueError("SlipVector holds a non-finite value")
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"SlipVector probability {p} outside [0, 1]")
    return SlipData(stamp_to_ns(msg.header.stamp), vx, vz, bool(msg.slipping), p)


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
                 alpha: Optional[float] = None) -> MarkerArray:
    """rviz markers for a SlipVector, in its own frame.

    An arrow from the grasp-plane origin along the slip velocity (``scale_s`` metres of arrow
    per m/s of slip; deleted while not slipping) and a sphere at the origin, both colored by
    the slip probability.
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
    return MarkerArray(markers=[arrow, dot])
