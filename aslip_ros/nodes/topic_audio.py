"""Another driver's AudioFrames as an :class:`~aslip_ros.hw.audio_source.AudioSource`.

``audio_capture`` with ``source:=topic`` subscribes to ``input_topic`` and republishes the
stream on ``/aslip/audio`` with its own metadata, layout and frame, so a microphone driven
by another node joins the pipeline. The stream must carry the configured ``sample_rate``
and ``channel_names`` (the contract the rest of the graph is told about at configure);
a frame that does not, or that fails :func:`aslip_ros.nodes.convert.audio_from_msg`, is
dropped and counted, and the next accepted block reports the frames missed before it.
"""

from __future__ import annotations

import queue
import threading
from typing import Any, Mapping, Optional

from aslip_ros.hw.audio_block import AudioBlock, SourceStats
from aslip_ros.hw.audio_block import BlockReader as _BlockReader
from aslip_ros.hw.audio_source import METADATA_BASE, OpenedSource
from aslip_ros.msg import AudioFrame
from aslip_ros.nodes import common as c
from aslip_ros.nodes import convert

#: Blocks waiting for the capture thread; more are dropped (and counted) rather than kept.
QUEUE_BLOCKS = 100


class TopicAudio:
    """AudioFrames received on a topic, handed out by :meth:`read` in arrival order."""

    def __init__(self, node, topic: str, sample_rate: float, channel_names) -> None:
        self._node = node
        self._topic = topic
        self.sample_rate = float(sample_rate)
        self.channel_names = [str(n) for n in channel_names]
        self._queue: queue.Queue = queue.Queue(maxsize=QUEUE_BLOCKS)
        self._reader = _BlockReader()
        self._sub = None
        self._lock = threading.Lock()
        self.received = 0
        self.rejected = 0
        self.dropped = 0
        self.last_error = ""

    def start(self) -> None:
        """Subscribe (a restart subscribes again; the published index never goes back)."""
        with self._lock:
            if self._sub is None:
                self._sub = self._node.create_subscription(AudioFrame, self._topic,
                                                           self._on_frame, c.SENSOR_QOS)

    def stop(self) -> None:
        """Unsubscribe; blocks still queued are discarded."""
        with self._lock:
            sub, self._sub = self._sub, None
        if sub is not None:
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
        """Counters for the diagnostics (rejected frames count as dropped blocks)."""
        return SourceStats(blocks_produced=self.received, frames_produced=0,
                           blocks_read=self._reader.blocks_read,
                           blocks_dropped=self.rejected + self.dropped, frames_dropped=0,
                           input_overflows=0, queue_depth=self._queue.qsize())

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


def open_topic(p: Mapping[str, Any], node: Any) -> OpenedSource:
    """The ``topic`` source: ``input_topic``, ``sample_rate``, ``channel_names``, ``layout``."""
    src = TopicAudio(node, p["input_topic"], p["sample_rate"], p["channel_names"])
    meta = dict(METADATA_BASE, sample_rate=src.sample_rate, channel_names=src.channel_names,
                layout=p["layout"], source_topic=p["input_topic"])
    return OpenedSource(src, meta, p["layout"])
