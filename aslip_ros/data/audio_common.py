"""A bag of audio_common's own topics (``audio_stamped`` + latched ``audio_info``, as ``ros2
bag record`` takes them from ``audio_capture_node``) read as the AudioFrames that
``audio_capture input_type:=audio_common`` would have published from the same messages.

Decoding and the sample counter are :class:`aslip_ros.audio_frame.PcmFormat` and
:class:`~aslip_ros.audio_frame.PcmStream`, the live bridge's own, so both routes give one
dataset. The format is the bag's AudioInfo (all of them: the driver re-sends it every 5 s;
one that differs refuses the bag, as a change of an AudioFrame stream's format does), taken
for every audio message, the ones logged before the first AudioInfo too. The channel names
and layout are the recording metadata's (``channel_names`` of the right count), else
``ch0``, ``ch1``... (the driver names none).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from aslip_ros.audio_frame import (AUDIO_COMMON_INFO_TYPE, AUDIO_COMMON_STAMPED_TYPE,
                                   AudioFrameError, AudioInfoError, PcmFormat, PcmStream,
                                   audio_info_topic, stamp_to_ns)
from aslip_ros.data.bag_errors import BagError


def audio_topic_in(reader, topic: str, default: str) -> str:
    """``topic``, or (where ``topic`` is the ``default`` one and the bag lacks it) the bag's
    only topic of audio_common audio: a bag recorded from audio_capture_node directly."""
    have = reader.info.topics
    if topic in have or topic != default:
        return topic
    found = [t for t, kind in have.items() if kind == AUDIO_COMMON_STAMPED_TYPE]
    return found[0] if len(found) == 1 else topic


class AudioCommonFrames:
    """The AudioDataStamped messages of one bag topic, turned into AudioFrame-like records
    (``header``, ``sample_rate``, ``channel_names``, ``layout``, ``first_sample_index``,
    ``data`` float32) for the exporter's AudioFrame path."""

    msgtype = AUDIO_COMMON_STAMPED_TYPE

    def __init__(self, reader, topic: str, meta: dict) -> None:
        path = reader.path
        info_topic = audio_info_topic(topic)
        if reader.info.topics.get(info_topic) != AUDIO_COMMON_INFO_TYPE:
            raise BagError(f"bag {path}: {topic} holds audio_common audio but the bag has no "
                           f"{AUDIO_COMMON_INFO_TYPE} on {info_topic}, which gives its format: "
                           "record audio_info too (it is latched: the recorder needs a "
                           "transient-local subscription, which ros2 bag and bag_recorder "
                           "take)")
        formats = {}
        for m in reader.messages([info_topic]):
            try:
                fmt = PcmFormat.from_info(m.msg)
            except AudioInfoError as exc:
                raise BagError(f"bag {path}: {exc}") from None
            formats.setdefault(fmt, m.log_ns)
        if len(formats) > 1:
            raise BagError(f"bag {path}: the AudioInfo on {info_topic} changes within the "
                           f"bag ({'; '.join(map(str, formats))}); split the bag")
        self.fmt = next(iter(formats))
        self._stream = PcmStream(self.fmt)
        self._path, self._topic = path, topic
        names = meta.get("channel_names") if isinstance(meta, dict) else None
        if not (isinstance(names, list) and len(names) == self.fmt.channels):
            names = [f"ch{i}" for i in range(self.fmt.channels)]
        self.channel_names = [str(n) for n in names]
        self.layout = str(meta.get("layout") or "") if isinstance(meta, dict) else ""

    def frame(self, msg):
        """The AudioFrame of one AudioDataStamped; BagError where its bytes are not whole
        frames. Float samples are left unchecked: the AudioFrame check refuses them."""
        data = msg.audio.data
        try:
            n = self.fmt.frames(data)
        except AudioFrameError as exc:
            if exc.reason != "empty":
                raise BagError(f"bag {self._path}: {self._topic}: {exc}") from None
            n, block = 0, np.zeros((0, self.fmt.channels), np.float32)
        if n:
            block = self.fmt.decode(data, check=False)
        stamp_ns = stamp_to_ns(msg.header.stamp)
        index = self._stream.place(n, stamp_ns)[0] if n else self._stream.next_index
        return SimpleNamespace(header=msg.header, sample_rate=self.fmt.sample_rate,
                               channel_names=self.channel_names, layout=self.layout,
                               first_sample_index=index, data=block.reshape(-1))
