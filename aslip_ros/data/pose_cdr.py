"""A fast decoder of serialized ``geometry_msgs/PoseStamped`` (the exporter reads millions):
the fixed CDR layout unpacked with :mod:`struct` and numpy instead of a generic deserializer.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from aslip_ros.data.bag_errors import BagError


@dataclass(frozen=True)
class StampedPose:
    """A decoded ``geometry_msgs/PoseStamped``: header stamp (ns), frame id, pose7."""

    stamp_ns: int
    frame_id: str
    pose: np.ndarray


def decode_pose_stamped(raw: bytes | memoryview) -> StampedPose:
    """Decode CDR-serialized ``geometry_msgs/msg/PoseStamped`` bytes.

    Layout (XCDR1 plain, after the 4-byte encapsulation header whose second byte gives the
    byte order): int32 sec, uint32 nanosec, uint32 string length (with NUL), the string,
    padding to an 8-byte boundary, then seven float64: position xyz, orientation xyzw.
    """
    buf = bytes(raw)
    if len(buf) < 16 or buf[1] not in (0, 1):
        raise BagError(f"not a CDR PoseStamped ({len(buf)} bytes)")
    order = "<" if buf[1] == 1 else ">"
    sec, nsec, n = struct.unpack_from(order + "iII", buf, 4)
    end = 16 + n
    off = 4 + ((end - 4 + 7) & ~7)
    if off + 56 != len(buf) or n == 0:
        raise BagError(f"not a CDR PoseStamped ({len(buf)} bytes, frame id length {n})")
    frame = buf[16:end - 1].decode("utf-8", errors="replace")
    pose = np.frombuffer(buf, dtype=order + "f8", count=7, offset=off).astype(np.float64)
    return StampedPose(sec * 1_000_000_000 + nsec, frame, pose)
