"""AudioFrame decoding without ROS: the one check of an audio block, live and offline.

The live nodes decode rclpy messages (:func:`aslip_ros.nodes.convert.audio_from_msg` is this
function) and the exporter decodes the messages rosbags reads from a bag; both have the
fields of msg/AudioFrame.msg (``header.stamp``, ``sample_rate``, ``channel_names``,
``layout``, ``first_sample_index``, ``data``), so one function checks both, and a block
that a node would refuse is refused offline too.

The same goes for another driver's raw audio: audio_common's ``AudioDataStamped`` (bytes,
no sample counter) with its ``AudioInfo`` (channels, rate, GStreamer sample format, coding).
:class:`PcmFormat` (from an AudioInfo), its ``decode`` (bytes -> ``(frames, channels)``
float32, full scale +-1) and :class:`PcmStream` (the sample counter the driver does not
send) are the one definition that ``audio_capture`` (``input_type:=audio_common``) and
``aslip export`` (a bag of ``audio_stamped`` + ``audio_info``) both use.
"""

from __future__ import annotations

import array
import math
import posixpath
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
    _check_samples(flat, "AudioFrame", require_finite)
    block = flat.reshape(-1, len(names))
    return AudioData(int(msg.first_sample_index), stamp_to_ns(msg.header.stamp), rate, names,
                     str(msg.layout), str(msg.header.frame_id), block)


def _check_samples(flat: np.ndarray, what: str, require_finite: bool = True) -> None:
    """``non_finite`` / ``out_of_range`` samples (see :func:`decode_audio_frame`)."""
    # One min and one max pass settle the common case: NaN propagates into both and fails
    # the range test, as an infinity does. Only a block that fails them is looked at again,
    # to name its defect (and, without ``require_finite``, to let in-range NaN/Inf pass).
    if flat.size and -FULL_SCALE <= float(flat.min()) and float(flat.max()) <= FULL_SCALE:
        return
    finite = np.isfinite(flat)
    if require_finite and not finite.all():
        raise AudioFrameError("non_finite", f"{what} contains NaN or Inf samples")
    peak = float(np.max(np.abs(flat), where=finite, initial=0.0))
    if peak > FULL_SCALE:
        raise AudioFrameError("out_of_range", f"{what} holds a sample of magnitude "
                                              f"{peak:.3g}, beyond full scale {FULL_SCALE:g}")


# ----------------------------------------------------------------- audio_common's raw audio

#: audio_common_msgs types (ROS 2 names), as a bag records them.
AUDIO_COMMON_STAMPED_TYPE = "audio_common_msgs/msg/AudioDataStamped"
AUDIO_COMMON_INFO_TYPE = "audio_common_msgs/msg/AudioInfo"
#: The driver publishes its AudioInfo beside its audio, in the same namespace.
AUDIO_COMMON_INFO_NAME = "audio_info"
#: ``coding_format`` values that mean uncompressed interleaved PCM (compared without case;
#: audio_capture_node sends its ``format`` parameter: ``wave`` or ``mp3``).
PCM_CODINGS = ("wave", "wav", "pcm", "raw")
#: What to tell a lab whose driver sends compressed audio.
PCM_HOW = ("start audio_capture_node with format:=wave (e.g. `ros2 launch audio_capture "
           "capture_wave.launch.py`, or `-p format:=wave`)")

#: GStreamer's raw sample formats (GstAudioFormat names): bytes per sample, numpy dtype of
#: the stored word, the value of full scale, and the offset of unsigned formats. S24LE/BE
#: are packed 3-byte samples, S24_32 24-bit samples in the low bytes of 32-bit words.
PCM_FORMATS = {
    "S8": (1, "i1", 2.0 ** 7, 0), "U8": (1, "u1", 2.0 ** 7, 2 ** 7),
    "S16LE": (2, "<i2", 2.0 ** 15, 0), "S16BE": (2, ">i2", 2.0 ** 15, 0),
    "U16LE": (2, "<u2", 2.0 ** 15, 2 ** 15), "U16BE": (2, ">u2", 2.0 ** 15, 2 ** 15),
    "S24LE": (3, "<", 2.0 ** 23, 0), "S24BE": (3, ">", 2.0 ** 23, 0),
    "S24_32LE": (4, "<i4", 2.0 ** 23, 0), "S24_32BE": (4, ">i4", 2.0 ** 23, 0),
    "S32LE": (4, "<i4", 2.0 ** 31, 0), "S32BE": (4, ">i4", 2.0 ** 31, 0),
    "F32LE": (4, "<f4", 1.0, 0), "F32BE": (4, ">f4", 1.0, 0),
    "F64LE": (8, "<f8", 1.0, 0), "F64BE": (8, ">f8", 1.0, 0),
}


class AudioInfoError(ValueError):
    """An AudioInfo whose audio cannot be decoded; ``reason``: ``not_pcm`` (compressed, e.g.
    MP3), ``sample_format`` (not one of :data:`PCM_FORMATS`), ``no_channels``, ``bad_rate``."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def audio_info_topic(audio_topic: str) -> str:
    """The AudioInfo topic beside ``audio_topic`` (``/audio/audio_stamped`` ->
    ``/audio/audio_info``), where audio_capture_node publishes it."""
    home = posixpath.dirname(audio_topic)
    return posixpath.join(home, AUDIO_COMMON_INFO_NAME) if home else AUDIO_COMMON_INFO_NAME


@dataclass(frozen=True)
class PcmFormat:
    """Interleaved PCM as an AudioInfo describes it: channel count, rate [Hz], GStreamer
    sample format (``S16LE``...)."""

    channels: int
    sample_rate: float
    sample_format: str

    @classmethod
    def from_info(cls, info) -> "PcmFormat":
        """The format of an ``audio_common_msgs/AudioInfo`` (rclpy or rosbags message).

        :raises AudioInfoError: compressed coding (MP3...), an unknown sample format, no
            channels or no rate.
        """
        coding = str(info.coding_format).strip()
        if coding.lower() not in PCM_CODINGS:
            raise AudioInfoError("not_pcm", f"audio_info says coding_format {coding!r}: only "
                                            f"uncompressed PCM (WAVE) can be read; {PCM_HOW}")
        name = str(info.sample_format).strip().upper()
        if name not in PCM_FORMATS:
            raise AudioInfoError("sample_format", f"audio_info sample_format "
                                                  f"{info.sample_format!r} is none of "
                                                  f"{', '.join(PCM_FORMATS)}")
        channels, rate = int(info.channels), float(info.sample_rate)
        if channels < 1:
            raise AudioInfoError("no_channels", f"audio_info says {channels} channels")
        if not (math.isfinite(rate) and rate > 0):
            raise AudioInfoError("bad_rate", f"audio_info sample_rate {rate:g} is not positive")
        return cls(channels, rate, name)

    def __str__(self) -> str:
        return f"{self.sample_rate:g} Hz, {self.channels} ch, {self.sample_format}"

    @property
    def frame_bytes(self) -> int:
        """Bytes of one frame (a sample of every channel)."""
        return PCM_FORMATS[self.sample_format][0] * self.channels

    def frames(self, data) -> int:
        """Frames in ``data`` (bytes); AudioFrameError ``empty`` or ``ragged`` (not whole
        frames)."""
        n = len(data)
        if n == 0:
            raise AudioFrameError("empty", "audio message carries no samples")
        if n % self.frame_bytes:
            raise AudioFrameError("ragged", f"audio message of {n} bytes is not whole frames "
                                            f"of {self.frame_bytes} bytes ({self})")
        return n // self.frame_bytes

    def decode(self, data, check: bool = True) -> np.ndarray:
        """``data`` (bytes, a uint8 array or list) -> ``(frames, channels)`` float32, +-1
        full scale; AudioFrameError as :meth:`frames`, and (with ``check``) ``non_finite``
        / ``out_of_range`` for float samples that no converter produces."""
        raw = _as_bytes(data)
        self.frames(raw)
        size, dtype, scale, offset = PCM_FORMATS[self.sample_format]
        if size == 3:
            b = np.frombuffer(raw, np.uint8).reshape(-1, 3).astype(np.int32)
            lo, hi = (b[:, 0], b[:, 2]) if dtype == "<" else (b[:, 2], b[:, 0])
            words = lo | (b[:, 1] << 8) | (hi << 16)
            ints = words - ((words & 0x800000) << 1)             # sign of 24 bits
            flat = ints.astype(np.float64) / scale
        else:
            words = np.frombuffer(raw, dtype)
            if self.sample_format.startswith("S24_32"):
                w = words.astype(np.int64) & 0xFFFFFF            # the high byte is padding
                words = w - ((w & 0x800000) << 1)
            flat = (words.astype(np.float64) - offset) / scale
        flat = flat.astype(np.float32)
        if check and self.sample_format.startswith("F"):
            _check_samples(flat, f"{self.sample_format} audio")
        return flat.reshape(-1, self.channels)


def _as_bytes(data) -> bytes:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return bytes(data)
    if isinstance(data, np.ndarray):
        return data.astype(np.uint8, copy=False).tobytes()
    if isinstance(data, array.array):
        return data.tobytes()
    return bytes(data)              # rclpy hands uint8[] over as a list of ints or bytes


class PcmStream:
    """The sample counter that audio_common does not send, the same live and offline.

    The first block is index 0 and the index counts the frames received. A message lost
    between the driver and the reader shows as a stamp (the driver's capture time) later
    than the previous block's stamp plus its duration: from half a block late on, the
    blocks that fit in the hole (of the previous one's length: the driver's buffers are of
    one size, and stamp jitter stays out of the count) are counted as lost frames (a gap,
    never a splice). Measured block
    to block, so a device clock that drifts from the nominal rate makes no phantom gaps. A
    stamp of zero (a driver that stamps nothing) or one that goes back counts as contiguous:
    the index never goes back.
    """

    def __init__(self, fmt: PcmFormat) -> None:
        self.fmt = fmt
        self.next_index = 0
        self._prev: tuple | None = None      # (stamp_ns, frames) of the last block
        self.frames_lost = 0

    def place(self, frames: int, stamp_ns: int) -> tuple:
        """``(first_sample_index, frames_lost_before)`` of a block of ``frames`` stamped
        ``stamp_ns``; the counter then stands after it."""
        lost = 0
        if self._prev is not None and stamp_ns > 0 and self._prev[0] > 0:
            prev_ns, prev_frames = self._prev
            late = (stamp_ns - prev_ns) * 1e-9 * self.fmt.sample_rate - prev_frames
            if late >= max(1.0, prev_frames / 2.0):
                lost = prev_frames * int(round(late / prev_frames))
        index = self.next_index + lost
        self.next_index = index + int(frames)
        self.frames_lost += lost
        self._prev = (int(stamp_ns), int(frames))
        return index, lost
