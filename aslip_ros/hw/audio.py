"""Multi-channel audio sources: live capture through sounddevice/PortAudio, WAV replay.

Both sources yield :class:`AudioBlock` objects through the same pull API (``read`` /
iteration), so the capture node does not care where the audio comes from.

Live capture follows the one rule of real-time audio: the PortAudio callback runs on the
audio thread and must never block, so it only copies the block, its ADC timestamp and the
running sample counter into a bounded queue. Nothing is lost silently:

- ``status.input_overflow`` (PortAudio lost samples before we saw them) is counted and
  flagged on the block it arrived with;
- a block that finds the queue full is dropped and counted, and the consumer sees the gap
  in ``first_sample_index`` (reported as :attr:`AudioBlock.frames_lost_before`).

``sounddevice`` is imported lazily, so this module (and WAV replay) works on machines
without ``libportaudio2``.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterator, List, Optional, Sequence, Union

import numpy as np

#: Default block length: 10 ms at 48 kHz.
DEFAULT_BLOCK_FRAMES = 480


class AudioError(RuntimeError):
    """A device could not be found or opened, or a file could not be read."""


@dataclass(frozen=True)
class AudioBlock:
    """One block of multi-channel audio.

    :ivar first_sample_index: index of the block's first frame in the stream (a running
        counter over every frame the source produced, including dropped blocks).
    :ivar adc_time: acquisition time of the first frame on the source's clock [s]: PortAudio's
        ``inputBufferAdcTime`` for capture, file time for replay.
    :ivar host_time: estimated ``time.time()`` [s] of the first frame's acquisition, for
        stamping messages (callback wall time minus the block's age in the driver).
    :ivar data: ``(frames, channels)`` float32 samples, full scale +-1.
    :ivar overflow: PortAudio reported an input overflow with this block.
    :ivar frames_lost_before: frames missing between the previous block read and this one
        (queue overflow); 0 when contiguous.
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


def _channel_names(names: Optional[Sequence[str]], channels: int) -> List[str]:
    if names is None:
        return [f'ch{i}' for i in range(channels)]
    names = [str(n) for n in names]
    if len(names) != channels:
        raise ValueError(f'{len(names)} channel names for {channels} channels')
    if len(set(names)) != len(names) or any(not n for n in names):
        raise ValueError(f'channel names must be unique and non-empty: {names}')
    return names


def _check_positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or int(value) != value or int(value) < 1:
        raise ValueError(f'{name} must be an integer >= 1, got {value!r}')
    return int(value)


class _BlockReader:
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


class SoundDeviceCapture:
    """Live multi-channel capture from a PortAudio input device.

    :param device: device name (or a unique substring of it) or index; ``None`` = default.
    :param channels: number of input channels to open.
    :param sample_rate: sample rate [Hz]; the device must support it exactly.
    :param block_frames: frames per block (PortAudio ``blocksize``).
    :param channel_names: one unique name per channel (default ``ch0``...).
    :param queue_blocks: capacity of the queue between the audio thread and the consumer.
    :param latency: PortAudio suggested latency, ``'low'``, ``'high'`` or seconds.
    :param sd_module: the ``sounddevice`` module (tests may inject a fake); default: import.
    """

    def __init__(self, device: Union[str, int, None], channels: int, sample_rate: float,
                 block_frames: int = DEFAULT_BLOCK_FRAMES,
                 channel_names: Optional[Sequence[str]] = None,
                 queue_blocks: int = 256, latency: Union[str, float] = 'high',
                 sd_module: Any = None) -> None:
        """Validate the configuration and resolve the device (the stream opens in start)."""
        self._channels = _check_positive_int('channels', channels)
        self._block_frames = _check_positive_int('block_frames', block_frames)
        queue_blocks = _check_positive_int('queue_blocks', queue_blocks)
        sample_rate = float(sample_rate)
        if not math.isfinite(sample_rate) or sample_rate <= 0.0:
            raise ValueError(f'sample_rate must be finite and > 0, got {sample_rate}')
        self._sample_rate = sample_rate
        self._names = _channel_names(channel_names, self._channels)
        if isinstance(device, str) and not device.strip():
            device = None
        if isinstance(device, bool) or not (device is None or isinstance(device, (str, int))):
            raise ValueError(f'device must be a name, an index or None, got {device!r}')
        self._latency = latency
        self._sd = sd_module if sd_module is not None else self._import_sounddevice()
        self._device_index, self._device_name = self._resolve(device)
        self._queue: 'queue.Queue[AudioBlock]' = queue.Queue(maxsize=queue_blocks)
        self._stream: Any = None
        self._reader = _BlockReader()
        self._lock = threading.Lock()
        # Written only by the audio callback; read (racily but atomically) by the consumer.
        self._frames_produced = 0
        self._blocks_produced = 0
        self._blocks_dropped = 0
        self._frames_dropped = 0
        self._overflows = 0
        self._callback_errors = 0

    # -- configuration ----------------------------------------------------------------------

    @property
    def sample_rate(self) -> float:
        """Sample rate [Hz]."""
        return self._sample_rate

    @property
    def channel_names(self) -> List[str]:
        """One name per channel, in column order."""
        return list(self._names)

    @property
    def channels(self) -> int:
        """Number of channels."""
        return self._channels

    @property
    def block_frames(self) -> int:
        """Frames per block."""
        return self._block_frames

    @property
    def device_name(self) -> str:
        """The resolved PortAudio device name."""
        return self._device_name

    # -- lifecycle --------------------------------------------------------------------------

    def start(self) -> None:
        """Open and start the input stream. Raises :class:`AudioError` if it cannot."""
        with self._lock:
            if self._stream is not None:
                return
            try:
                stream = self._sd.InputStream(
                    device=self._device_index, channels=self._channels,
                    samplerate=self._sample_rate, blocksize=self._block_frames,
                    dtype='float32', latency=self._latency, callback=self._callback)
                stream.start()
            except Exception as exc:  # noqa: BLE001 - PortAudioError and friends
                raise AudioError(f'cannot open audio input {self._device_name!r} '
                                 f'({self._channels} ch, {self._sample_rate:g} Hz): {exc}') \
                    from exc
            self._stream = stream

    def stop(self) -> None:
        """Stop and close the stream (blocks still queued can be read)."""
        with self._lock:
            stream, self._stream = self._stream, None
        if stream is not None:
            try:
                stream.stop()
            finally:
                stream.close()

    close = stop

    @property
    def running(self) -> bool:
        """True while the stream is open and active."""
        stream = self._stream
        return stream is not None and bool(getattr(stream, 'active', True))

    def __enter__(self) -> 'SoundDeviceCapture':
        """Start on entering a ``with`` block."""
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        """Stop on leaving it."""
        self.stop()

    # -- consumer API -----------------------------------------------------------------------

    def read(self, timeout_s: Optional[float] = None) -> Optional[AudioBlock]:
        """Next block, waiting up to ``timeout_s`` (``None``: forever); ``None`` on timeout."""
        try:
            block = self._queue.get(timeout=timeout_s) if timeout_s != 0 else \
                self._queue.get_nowait()
        except queue.Empty:
            return None
        return self._reader.mark(block)

    def blocks(self, timeout_s: float = 0.5) -> Iterator[AudioBlock]:
        """Yield blocks until the stream stops and the queue is drained."""
        while True:
            block = self.read(timeout_s)
            if block is not None:
                yield block
            elif not self.running and self._queue.empty():
                return

    def stats(self) -> SourceStats:
        """Counters since construction."""
        return SourceStats(
            blocks_produced=self._blocks_produced, frames_produced=self._frames_produced,
            blocks_read=self._reader.blocks_read, blocks_dropped=self._blocks_dropped,
            frames_dropped=self._frames_dropped, input_overflows=self._overflows,
            queue_depth=self._queue.qsize())

    # -- internals --------------------------------------------------------------------------

    @staticmethod
    def _import_sounddevice() -> Any:
        try:
            import sounddevice
        except OSError as exc:  # PortAudio shared library missing
            raise AudioError(f'sounddevice cannot load PortAudio ({exc}); install '
                             'libportaudio2 (make setup does)') from exc
        return sounddevice

    def _resolve(self, device: Union[str, int, None]) -> tuple:
        try:
            info = self._sd.query_devices(device, 'input')
        except Exception as exc:  # noqa: BLE001 - ValueError / PortAudioError
            try:
                available = [f"{i}: {d['name']}" for i, d in
                             enumerate(self._sd.query_devices()) if d['max_input_channels']]
            except Exception:  # noqa: BLE001 - only for the message
                available = []
            raise AudioError(f'no audio input device {device!r} ({exc}); inputs: '
                             f'{available}') from exc
        if int(info['max_input_channels']) < self._channels:
            raise AudioError(f"device {info['name']!r} has {info['max_input_channels']} input "
                             f'channels, {self._channels} requested')
        index = info.get('index', device)
        return index, str(info['name'])

    def _callback(self, indata: np.ndarray, frames: int, time_info: Any, status: Any) -> None:
        # Runs on PortAudio's thread: copy, count, enqueue; never block, never raise.
        try:
            index = self._frames_produced
            self._frames_produced = index + frames
            self._blocks_produced += 1
            overflow = bool(getattr(status, 'input_overflow', False))
            if overflow:
                self._overflows += 1
            adc = float(getattr(time_info, 'inputBufferAdcTime', 0.0) or 0.0)
            current = float(getattr(time_info, 'currentTime', 0.0) or 0.0)
            now = time.time()
            # The block's first frame was acquired (current - adc) seconds ago when both
            # stamps are valid; some drivers report 0, then fall back to the block length.
            age = current - adc if adc > 0.0 and current >= adc else frames / self._sample_rate
            block = AudioBlock(index, adc, now - age, np.array(indata, dtype=np.float32),
                               overflow)
            try:
                self._queue.put_nowait(block)
            except queue.Full:
                self._blocks_dropped += 1
                self._frames_dropped += frames
        except Exception:  # noqa: BLE001 - an exception here would kill the stream
            self._callback_errors += 1


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

        self._block_frames = _check_positive_int('block_frames', block_frames)
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
        self._names = _channel_names(channel_names, data.shape[1])
        self._paced = bool(paced)
        self._loop = bool(loop)
        self._clock = clock
        self._sleep = sleep
        self._reader = _BlockReader()
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
