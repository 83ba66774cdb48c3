"""AudioFrame decoding without ROS: the one check of an audio block, live and offline.

The live nodes decode rclpy messages (:func:`aslip_ros.nodes.convert.audio_from_msg` is this
function) and the exporter decodes the messages rosbags reads from a bag; both have the
fields of msg/AudioFrame.msg (``header.stamp``, ``sample_rate``, ``channel_names``,
``layout``, ``first_sample_index``, ``data``), so one function checks both, and a block
that a node would refuse is refused offline too.
"""

from __future__ import annotations

import array
import math
from dataclasses import dataclass

import numpy as np

NS_PER_S = 1_000_000_000
#: Audio samples are float in full-scale units: a converter cannot deliver more than this.
FULL_SCALE = 1.0


class AudioFrameError(ValueError):
    """An AudioFrame that cannot be turned into a block; ``reason`` names the defect."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class AudioData:
    """A decoded AudioFrame: ``block`` is ``(frames, channels)`` float32."""

    first_sample_index: int
    stamp_ns: int
    sample_rate: float
    channel_names: list
    layout: str
    frame_id: str
    block: np.ndarray

    @property
    def frames(self) -> int:
        """Frames in the block."""
        return int(self.block.shape[0])

    @property
    def end_stamp_ns(self) -> int:
        """Stamp of the instant just after the block's last sample."""
        return self.stamp_ns + int(round(self.frames * NS_PER_S / self.sample_rate))


def stamp_to_ns(stamp) -> int:
    """A ``builtin_interfaces/Time`` (``sec``, ``nanosec``) -> integer nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def decode_audio_frame(msg, require_finite: bool = True) -> AudioData:
    """Decode and validate an AudioFrame (an rclpy or a rosbags message).

    :raises AudioFrameError: ``no_channels``, ``bad_rate``, ``empty``, ``ragged`` (length not
        a multiple of the channel count), ``non_finite`` (NaN/Inf samples) or
        ``out_of_range`` (a sample beyond :data:`FULL_SCALE`: no converter produces it, so
        the block is corrupt or mis-scaled, e.g. integer counts sent as float).
    """
    names = [str(n) for n in msg.channel_names]
    if not names:
        raise AudioFrameError("no_channels", "AudioFrame has no channel names")
    rate = float(msg.sample_rate)
    if not (math.isfinite(rate) and rate > 0.0):
        raise AudioFrameError("bad_rate", f"AudioFrame sample_rate {rate} is not positive")
    flat = np.frombuffer(msg.data, dtype=np.float32) if isinstance(msg.data, array.array) \
        else np.asarray(msg.data, dtype=np.float32)
    if flat.size == 0:
        raise AudioFrameError("empty", "AudioFrame carries no samples")
    if flat.size % len(names):
        raise AudioFrameError("ragged", f"AudioFrame has {flat.size} samples, not a multiple "
                                        f"of its {len(names)} channels")
    finite = np.isfinite(flat)
    if require_finite and not finite.all():
        raise AudioFrameError("non_finite", "AudioFrame contains NaN or Inf samples")
    peak = float(np.max(np.abs(flat), where=finite, initial=0.0))
    if peak > FULL_SCALE:
        raise AudioFrameError("out_of_range", f"AudioFrame holds a sample of magnitude "
                                              f"{peak:.3g}, beyond full scale {FULL_SCALE:g}")
    block = flat.reshape(-1, len(names))
    return AudioData(int(msg.first_sample_index), stamp_to_ns(msg.header.stamp), rate, names,
                     str(msg.layout), str(msg.header.frame_id), block)
