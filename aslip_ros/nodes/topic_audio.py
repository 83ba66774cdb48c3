"""Another driver's AudioFrames as an :class:`~aslip_ros.hw.audio_source.AudioSource`.

``audio_capture`` with ``source:=topic`` subscribes to ``input_topic`` and republishes the
stream on ``/aslip/audio`` with its own metadata, layout and frame, so a microphone driven
by another node joins the pipeline. The stream must carry the configured ``sample_rate``
and ``channel_names`` (the contract the rest of the graph is told about at configure);
a frame that does not, or that fails :func:`aslip_ros.nodes.convert.audio_from_msg`, is
dropped and counted, and the next accepted block reports the frames missed before it.

With ``input_type:=audio_common`` the topic carries audio_common's ``AudioDataStamped``
(``audio_capture_node``'s ``audio_stamped``) and the format comes from its latched
``AudioInfo`` (``info_topic``, by default ``audio_info`` beside ``input_topic``):
:class:`AudioCommonTopic`. Channels and rate are the AudioInfo's, never assumed; until it
has come no audio is published and the diagnostics say so; compressed audio (the driver's
default MP3) is refused with what to set (``format:=wave``). The stream's format is fixed
by the first usable AudioInfo: a different one later is refused (its blocks are dropped and
the diagnostics turn to ERROR) until the first returns or audio_capture is restarted,
because the rest of the graph was told the first format. Decoding and the sample counter
the driver does not send are :class:`aslip_ros.audio_frame.PcmFormat` and
:class:`~aslip_ros.audio_frame.PcmStream`, which ``aslip export`` uses too.
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Any, Mapping, Optional


from aslip_ros.audio_frame import (AudioFrameError, AudioInfoError, PcmFormat, PcmStream,
                                   audio_info_topic, stamp_to_ns)
from aslip_ros.hw.audio_block import AudioBlock, SourceStats
from aslip_ros.hw.audio_block import BlockReader as _BlockReader
from aslip_ros.hw.audio_source import METADATA_BASE, OpenedSource
from aslip_ros.msg import AudioFrame
from aslip_ros.runtime.qos import AUDIO_COMMON_QOS, LATCHED_QOS, SENSOR_QOS
from aslip_ros.nodes import convert

#: Blocks waiting for the capture thread; more are dropped (and counted) rather than kept.
QUEUE_BLOCKS = AUDIO_COMMON_QOS.depth


class _QueuedTopic:
    """Blocks received on a topic by the node's executor, handed out by :meth:`read` in
    arrival order to the capture thread; what does not fit the queue is dropped, counted."""

    def __init__(self, node, topic: str) -> None:
        self._node = node
        self._topic = topic
        self._queue: queue.Queue = queue.Queue(maxsize=QUEUE_BLOCKS)
        self._reader = _BlockReader()
        self._subs: list = []
        self._lock = threading.Lock()
        self.received = 0
        self.rejected = 0
        self.dropped = 0

    def _subscriptions(self) -> list:
        """The subscriptions that feed the queue (created by :meth:`start`)."""
        raise NotImplementedError

    def _not_delivered(self) -> int:
        """Blocks received but not handed out, besides those the full queue dropped."""
        return self.rejected

    def start(self) -> None:
        """Subscribe (a restart subscribes again; the published index never goes back)."""
        with self._lock:
            if not self._subs:
                self._subs = self._subscriptions()

    def stop(self) -> None:
        """Unsubscribe; blocks still queued are discarded."""
        with self._lock:
            subs, self._subs = self._subs, []
        for sub in subs:
            self._node.destroy_subscription(sub)
        while not self._queue.empty():
            self._queue.get_nowait()

    def read(self, timeout_s: Optional[float] = None) -> Optional[AudioBlock]:
        """The next received block, or ``None`` if none came within ``timeout_s``."""
        try:
            block = self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None
        return self._reader.mark(block)

    def stats(self) -> SourceStats:
        """Counters for the diagnostics (blocks not handed out count as dropped)."""
        return SourceStats(blocks_produced=self.received, frames_produced=0,
                           blocks_read=self._reader.blocks_read,
                           blocks_dropped=self._not_delivered() + self.dropped,
                           frames_dropped=0, input_overflows=0,
                           queue_depth=self._queue.qsize())


class TopicAudio(_QueuedTopic):
    """AudioFrames received on a topic, handed out by :meth:`read` in arrival order."""

    def __init__(self, node, topic: str, sample_rate: float, channel_names) -> None:
        super().__init__(node, topic)
        self.sample_rate = float(sample_rate)
        self.channel_names = [str(n) for n in channel_names]
        self.last_error = ""

    def _subscriptions(self) -> list:
        return [self._node.create_subscription(AudioFrame, self._topic, self._on_frame,
                                               SENSOR_QOS)]

    def _on_frame(self, msg: AudioFrame) -> None:
        self.received += 1
        try:
            data = convert.audio_from_msg(msg)
            if data.channel_names != self.channel_names or \
                    abs(data.sample_rate - self.sample_rate) > 1e-6 * self.sample_rate:
                raise ValueError(f"stream is {data.sample_rate:g} Hz {data.channel_names}, "
                                 f"expected {self.sample_rate:g} Hz {self.channel_names}")
        except ValueError as exc:
            self.rejected += 1
            self.last_error = str(exc)
            self._node.get_logger().warning(f"AudioFrame on {self._topic} dropped: {exc}",
                                            throttle_duration_sec=1.0)
            return
        t = data.stamp_ns * 1e-9
        try:
            self._queue.put_nowait(AudioBlock(data.first_sample_index, t, t, data.block))
        except queue.Full:
            self.dropped += 1


#: What ``input_type`` selects: the package's AudioFrame, or audio_common's pair.
INPUT_TYPES = ("aslip", "audio_common")


class AudioCommonTopic(_QueuedTopic):
    """audio_common's ``AudioDataStamped`` + latched ``AudioInfo`` as an audio source.

    ``sample_rate`` is 0 and ``channel_names`` empty until the first usable AudioInfo;
    ``waiting_for`` names what the source waits for ('' once it streams) and ``refusal``
    says why it publishes nothing ('' when it does).
    """

    def __init__(self, node, topic: str, info_topic: str, channel_names) -> None:
        super().__init__(node, topic)
        self._info_topic = info_topic
        self._names = [str(n) for n in channel_names]
        self.sample_rate = 0.0
        self.channel_names: list = []
        self.fmt: Optional[PcmFormat] = None
        self._stream: Optional[PcmStream] = None
        self._current_ok = False              # the latest AudioInfo is the stream's format
        self.waiting_for = f"audio_info on {info_topic}"
        self.refusal = ""
        self.held = 0                         # audio before a usable AudioInfo, or refused

    def _subscriptions(self) -> list:
        """The AudioInfo (latched) and the audio."""
        from audio_common_msgs.msg import AudioDataStamped, AudioInfo
        return [self._node.create_subscription(AudioInfo, self._info_topic, self._on_info,
                                               LATCHED_QOS),
                self._node.create_subscription(AudioDataStamped, self._topic,
                                               self._on_audio, AUDIO_COMMON_QOS)]

    def _not_delivered(self) -> int:
        """Audio held back before a usable AudioInfo, or refused, counts as dropped."""
        return self.held + self.rejected

    def _refuse(self, why: str) -> None:
        if why != self.refusal:
            self._node.get_logger().error(f"audio from {self._topic} refused: {why}")
        self.refusal = why

    def _on_info(self, msg) -> None:
        try:
            fmt = PcmFormat.from_info(msg)
        except AudioInfoError as exc:
            self._current_ok = False
            self._refuse(str(exc))
            return
        if self.fmt is None:
            if len(self._names) != fmt.channels:
                self._current_ok = False
                self._refuse(f"{self._info_topic} says {fmt.channels} channel(s) ({fmt}); "
                             f"channel_names has {len(self._names)}: {self._names}. Set "
                             f"channel_names to {fmt.channels} name(s)")
                return
            self.fmt, self._stream = fmt, PcmStream(fmt)
            self.sample_rate, self.channel_names = fmt.sample_rate, list(self._names)
            self._node.get_logger().info(f"{self._info_topic}: {fmt}; streaming "
                                         f"{self._topic}")
        elif fmt != self.fmt:
            self._current_ok = False
            self._refuse(f"{self._info_topic} changed mid-stream from {self.fmt} to {fmt}; "
                         f"audio is refused until it returns: restart audio_capture to take "
                         f"the new format")
            return
        self._current_ok = True
        self.waiting_for = ""
        if self.refusal:
            self._node.get_logger().info(f"{self._info_topic} is usable again ({fmt})")
        self.refusal = ""

    def _on_audio(self, msg) -> None:
        self.received += 1
        fmt, stream = self.fmt, self._stream
        if not self._current_ok or fmt is None:
            self.held += 1
            return
        stamp_ns = stamp_to_ns(msg.header.stamp)
        data = msg.audio.data
        try:
            n = fmt.frames(data)
            index, _ = stream.place(n, stamp_ns)
            block = fmt.decode(data)
        except AudioFrameError as exc:
            self.rejected += 1
            self._node.get_logger().warning(f"audio on {self._topic} dropped: {exc}",
                                            throttle_duration_sec=1.0)
            return
        # The driver's capture time; a driver that stamps nothing: the block's end is now.
        t = stamp_ns * 1e-9 if stamp_ns else time.time() - n / fmt.sample_rate
        try:
            self._queue.put_nowait(AudioBlock(index, t, t, block))
        except queue.Full:
            self.dropped += 1


def open_topic(p: Mapping[str, Any], node: Any) -> OpenedSource:
    """The ``topic`` source: ``input_topic``, ``input_type``, ``info_topic``,
    ``sample_rate`` (AudioFrame only), ``channel_names``, ``layout``."""
    if p["input_type"] == "audio_common":
        try:
            import audio_common_msgs.msg  # noqa: F401 - only this input needs them
        except ImportError as exc:
            raise RuntimeError(f"input_type audio_common needs the audio_common_msgs "
                               f"package (ros-jazzy-audio-common-msgs): {exc}") from None
        info = p["info_topic"] or audio_info_topic(p["input_topic"])
        src = AudioCommonTopic(node, p["input_topic"], info, p["channel_names"])
        # The rate and the channels come with the AudioInfo (audio_capture adds them).
        meta = dict(METADATA_BASE, layout=p["layout"], source_topic=p["input_topic"],
                    source_info_topic=info)
        return OpenedSource(src, meta, p["layout"])
    src = TopicAudio(node, p["input_topic"], p["sample_rate"], p["channel_names"])
    meta = dict(METADATA_BASE, sample_rate=src.sample_rate, channel_names=src.channel_names,
                layout=p["layout"], source_topic=p["input_topic"])
    return OpenedSource(src, meta, p["layout"])


def driver_topics(p: Mapping[str, Any]) -> list:
    """The driver's own topics a recording keeps beside ``/aslip/audio`` for audio_capture
    parameters ``p`` (a cell's): audio_common's audio and its latched AudioInfo with
    ``input_type:=audio_common`` (``aslip export`` reads the pair alone too), else none."""
    if p.get("source") != "topic" or p.get("input_type") != "audio_common" or \
            not p.get("input_topic"):
        return []
    return [p["input_topic"], p.get("info_topic") or audio_info_topic(p["input_topic"])]
