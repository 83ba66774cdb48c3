"""What every audio source delivers: :class:`AudioBlock` objects and :class:`SourceStats`.

The live capture (:mod:`aslip_ros.hw.audio`), the WAV replay (:mod:`aslip_ros.hw.wav`), the
scene's and a bag's audio (:mod:`aslip_ros.hw.sources`) and the ROS topic source
(:mod:`aslip_ros.nodes.topic_audio`) all build on this module: the block, the counters,
:class:`AudioError`, the checks of a source's configuration and :class:`BlockReader`, the
consumer-side gap bookkeeping they share. The protocol a source satisfies and the sources by
name are :mod:`aslip_ros.hw.audio_source`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, List, Optional, Sequence

import numpy as np

#: Default block length: 10 ms at 48 kHz.
DEFAULT_BLOCK_FRAMES = 480


class AudioError(RuntimeError):
    """A device could not be found or opened, or a file could not be read."""


@dataclass(frozen=True)
class AudioBlock:
    """One block of multi-channel audio.

    :ivar first_sample_index: index of the block's first frame in the stream (a running
        counter over every frame the source produced, including dropped blocks and frames
        lost to input overflow).
    :ivar adc_time: acquisition time of the first frame on the source's clock [s]: PortAudio's
        ``inputBufferAdcTime`` for capture, file time for replay.
    :ivar host_time: estimated ``time.time()`` [s] of the first frame's acquisition, for
        stamping messages (callback wall time minus the block's age in the driver).
    :ivar data: ``(frames, channels)`` float32 samples, full scale +-1.
    :ivar overflow: PortAudio reported an input overflow with this block.
    :ivar frames_lost_before: frames missing between the previous block read and this one
        (queue or input overflow); 0 when contiguous.
    """

    first_sample_index: int
    adc_time: float
    host_time: float
    data: np.ndarray
    overflow: bool = False
    frames_lost_before: int = 0

    @property
    def frames(self) -> int:
        """Number of frames in the block."""
        return int(self.data.shape[0])


@dataclass(frozen=True)
class SourceStats:
    """Counters of a source, for diagnostics.

    ``blocks_produced`` counts every block the device/file produced; it equals
    ``blocks_read + blocks_dropped + queue_depth``.
    """

    blocks_produced: int
    frames_produced: int
    blocks_read: int
    blocks_dropped: int
    frames_dropped: int
    input_overflows: int
    queue_depth: int
    frames_overflowed: int = 0     # frames PortAudio lost before the callback saw them
    callback_errors: int = 0       # callbacks that failed (their block is lost)


def check_channel_names(names: Optional[Sequence[str]], channels: int) -> List[str]:
    """One unique, non-empty name per channel: ``names`` as strings, or ``ch0``... when None."""
    if names is None:
        return [f'ch{i}' for i in range(channels)]
    names = [str(n) for n in names]
    if len(names) != channels:
        raise ValueError(f'{len(names)} channel names for {channels} channels')
    if len(set(names)) != len(names) or any(not n for n in names):
        raise ValueError(f'channel names must be unique and non-empty: {names}')
    return names


def check_positive_int(name: str, value: Any) -> int:
    """``value`` as an int; ValueError naming ``name`` unless it is an integer >= 1."""
    if isinstance(value, bool) or int(value) != value or int(value) < 1:
        raise ValueError(f'{name} must be an integer >= 1, got {value!r}')
    return int(value)


class BlockReader:
    """Consumer-side bookkeeping shared by the sources: gap detection and read counting."""

    def __init__(self) -> None:
        self._next_index: Optional[int] = None
        self.blocks_read = 0

    def mark(self, block: AudioBlock) -> AudioBlock:
        """Count a block handed to the consumer and annotate any gap before it."""
        lost = 0
        if self._next_index is not None:
            lost = max(0, block.first_sample_index - self._next_index)
        self._next_index = block.first_sample_index + block.frames
        self.blocks_read += 1
        if lost:
            return AudioBlock(block.first_sample_index, block.adc_time, block.host_time,
                              block.data, block.overflow, lost)
        return block
