"""Multi-channel WAV replay as :class:`~aslip_ros.hw.audio_block.AudioBlock` objects (same pull
API as the live capture in :mod:`aslip_ros.hw.audio`)."""

from __future__ import annotations

import time
from typing import Any, Callable, Iterator, List, Optional, Sequence

import numpy as np

from aslip_ros.hw.audio_block import (DEFAULT_BLOCK_FRAMES, AudioBlock, AudioError, BlockReader,
                                      SourceStats, check_channel_names, check_positive_int)


class WavReplay:
    """Replay a multi-channel WAV file as :class:`AudioBlock` objects.

    Reads int16, int32 (also 24-bit, which scipy returns as int32), uint8 and float WAV
    files through :func:`scipy.io.wavfile.read` and scales them to float32 +-1.

    :param path: the WAV file.
    :param block_frames: frames per block; the last block may be shorter.
    :param paced: deliver blocks in real time (a block becomes available when its last
        frame would have been captured); ``False`` delivers as fast as read.
    :param loop: start over at the end (the sample index keeps counting).
    :param channel_names: one unique name per channel (default ``ch0``...).
    :param clock: monotonic clock for pacing; ``sleep``: used while pacing.
    """

    def __init__(self, path: str, block_frames: int = DEFAULT_BLOCK_FRAMES,
                 paced: bool = True, loop: bool = False,
                 channel_names: Optional[Sequence[str]] = None,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        """Read the file header and data (memory-mapped where scipy allows it)."""
        from scipy.io import wavfile

        self._block_frames = check_positive_int('block_frames', block_frames)
        try:
            try:
                rate, data = wavfile.read(path, mmap=True)
            except ValueError:
                # scipy cannot memory-map 24-bit files; read them into memory instead.
                rate, data = wavfile.read(path)
        except (OSError, ValueError) as exc:
            raise AudioError(f'cannot read WAV file {path!r}: {exc}') from exc
        if data.ndim == 1:
            data = data[:, np.newaxis]
        if data.shape[0] == 0:
            raise AudioError(f'WAV file {path!r} has no samples')
        self._raw = data
        self._scale, self._offset = self._scaling(data.dtype, path)
        self._sample_rate = float(rate)
        self._names = check_channel_names(channel_names, data.shape[1])
        self._paced = bool(paced)
        self._loop = bool(loop)
        self._clock = clock
        self._sleep = sleep
        self._reader = BlockReader()
        self._index = 0
        self._t0: Optional[float] = None
        self._wall0 = 0.0
        self._finished = False

    @staticmethod
    def _scaling(dtype: np.dtype, path: str) -> tuple:
        if dtype == np.int16:
            return 1.0 / 32768.0, 0.0
        if dtype == np.int32:
            return 1.0 / 2147483648.0, 0.0
        if dtype == np.uint8:
            return 1.0 / 128.0, -128.0
        if dtype.kind == 'f':
            return 1.0, 0.0
        raise AudioError(f'unsupported WAV sample type {dtype} in {path!r}')

    @property
    def sample_rate(self) -> float:
        """Sample rate from the file header [Hz]."""
        return self._sample_rate

    @property
    def channel_names(self) -> List[str]:
        """One name per channel."""
        return list(self._names)

    @property
    def channels(self) -> int:
        """Number of channels in the file."""
        return int(self._raw.shape[1])

    @property
    def block_frames(self) -> int:
        """Frames per block."""
        return self._block_frames

    @property
    def n_frames(self) -> int:
        """Frames in the file."""
        return int(self._raw.shape[0])

    @property
    def finished(self) -> bool:
        """True once the last block has been read (never, when looping)."""
        return self._finished

    def start(self) -> None:
        """Start the replay clock (also done by the first read)."""
        if self._t0 is None:
            self._t0 = self._clock()
            self._wall0 = time.time()

    def stop(self) -> None:
        """End the replay: further reads return ``None``."""
        self._finished = True

    close = stop

    def __enter__(self) -> 'WavReplay':
        """Start on entering a ``with`` block."""
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        """Stop on leaving it."""
        self.stop()

    def read(self, timeout_s: Optional[float] = None) -> Optional[AudioBlock]:
        """Next block; when paced, waits until it is due (``None`` if not due in time)."""
        if self._finished:
            return None
        self.start()
        n = self.n_frames
        pos = self._index % n if self._loop else self._index
        if pos >= n:
            self._finished = True
            return None
        frames = min(self._block_frames, n - pos)
        file_time = self._index / self._sample_rate
        if self._paced:
            due = self._t0 + (self._index + frames) / self._sample_rate
            wait = due - self._clock()
            if wait > 0.0:
                if timeout_s is not None and wait > timeout_s:
                    if timeout_s > 0.0:
                        self._sleep(timeout_s)
                    return None
                self._sleep(wait)
        raw = np.asarray(self._raw[pos:pos + frames])
        data = ((raw.astype(np.float32) + np.float32(self._offset)) *
                np.float32(self._scale)).astype(np.float32, copy=False)
        block = AudioBlock(self._index, file_time, self._wall0 + file_time, data)
        self._index += frames
        if not self._loop and self._index >= n:
            self._finished = True
        return self._reader.mark(block)

    def blocks(self, timeout_s: Optional[float] = None) -> Iterator[AudioBlock]:
        """Yield blocks until the end of the file (forever when looping)."""
        while not self._finished:
            block = self.read(timeout_s)
            if block is not None:
                yield block

    def stats(self) -> SourceStats:
        """Counters (replay never drops)."""
        return SourceStats(
            blocks_produced=self._reader.blocks_read, frames_produced=self._index,
            blocks_read=self._reader.blocks_read, blocks_dropped=0, frames_dropped=0,
            input_overflows=0, queue_depth=0)
