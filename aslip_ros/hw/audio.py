"""Live multi-channel audio capture through sounddevice/PortAudio.

Like every audio source (the WAV replay is :mod:`aslip_ros.hw.wav`), the capture yields
:class:`~aslip_ros.hw.audio_block.AudioBlock` objects through the same pull API (``read`` /
iteration), so the capture node does not care where the audio comes from. The block, the
source counters and :class:`AudioError` are defined in :mod:`aslip_ros.hw.audio_block` and
importable from here too.

Live capture follows the one rule of real-time audio: the PortAudio callback runs on the
audio thread and must never block, so it only copies the block, its ADC timestamp and the
running sample counter into a bounded queue. Nothing is lost silently:

- ``status.input_overflow`` (PortAudio lost samples before we saw them) is counted and
  flagged on the block it arrived with, and the lost frames are counted into the sample
  index, so the consumer sees a gap there and never splices audio across the hole. Their
  number comes from the ADC clock (``inputBufferAdcTime`` against the previous block's);
  a driver without usable ADC times costs one block length (the loss is real, its size
  unknown). Unflagged jumps of the ADC times are not losses: drivers whose ADC times follow
  the callback's wall clock jump whenever the host is busy or the device unpaced;
- a block that finds the queue full is dropped and counted, and the consumer sees the gap
  in ``first_sample_index`` (reported as :attr:`AudioBlock.frames_lost_before`);
- the time of the last delivery is kept (``seconds_since_data``), so a device that stops
  delivering can be told from a quiet one, and callback errors are counted in the stats.

``sounddevice`` is imported lazily, so this module works on machines without
``libportaudio2``.
"""

from __future__ import annotations

import atexit
import math
import queue
import threading
import time
from typing import Any, Iterator, List, Optional, Sequence, Union

import numpy as np

from aslip_ros.hw.audio_block import (DEFAULT_BLOCK_FRAMES, AudioBlock, AudioError, BlockReader,
                                      SourceStats, check_channel_names, check_positive_int)

__all__ = ['DEFAULT_BLOCK_FRAMES', 'AudioBlock', 'AudioError', 'SourceStats',
           'SoundDeviceCapture', 'check_latency']


def check_latency(latency: Any) -> Union[str, float]:
    """PortAudio suggested latency: ``'low'``, ``'high'`` or seconds in (0, 10]."""
    if isinstance(latency, str):
        text = latency.strip().lower()
        if text in ('low', 'high'):
            return text
        try:
            latency = float(text)
        except ValueError:
            raise ValueError(f"latency must be 'low', 'high' or seconds, got {latency!r}") \
                from None
    if isinstance(latency, bool) or not isinstance(latency, (int, float)) or \
            not (math.isfinite(latency) and 0.0 < latency <= 10.0):
        raise ValueError(f"latency must be 'low', 'high' or seconds in (0, 10], "
                         f"got {latency!r}")
    return float(latency)


class SoundDeviceCapture:
    """Live multi-channel capture from a PortAudio input device.

    :param device: device name (or a unique substring of it) or index; ``None`` = default.
    :param channels: number of input channels to open.
    :param sample_rate: sample rate [Hz]; the device must support it exactly.
    :param block_frames: frames per block (PortAudio ``blocksize``).
    :param channel_names: one unique name per channel (default ``ch0``...).
    :param queue_blocks: capacity of the queue between the audio thread and the consumer.
    :param latency: PortAudio suggested latency, ``'low'`` (default: the device's low-latency
        setting, what a controller wants), ``'high'`` (robust to a busy host) or seconds.
    :param sd_module: the ``sounddevice`` module (tests may inject a fake); default: import.
    """

    def __init__(self, device: Union[str, int, None], channels: int, sample_rate: float,
                 block_frames: int = DEFAULT_BLOCK_FRAMES,
                 channel_names: Optional[Sequence[str]] = None,
                 queue_blocks: int = 256, latency: Union[str, float] = 'low',
                 sd_module: Any = None) -> None:
        """Validate the configuration and resolve the device (the stream opens in start)."""
        self._channels = check_positive_int('channels', channels)
        self._block_frames = check_positive_int('block_frames', block_frames)
        queue_blocks = check_positive_int('queue_blocks', queue_blocks)
        sample_rate = float(sample_rate)
        if not math.isfinite(sample_rate) or sample_rate <= 0.0:
            raise ValueError(f'sample_rate must be finite and > 0, got {sample_rate}')
        self._sample_rate = sample_rate
        self._names = check_channel_names(channel_names, self._channels)
        if isinstance(device, str) and not device.strip():
            device = None
        if isinstance(device, bool) or not (device is None or isinstance(device, (str, int))):
            raise ValueError(f'device must be a name, an index or None, got {device!r}')
        self._latency = check_latency(latency)
        self._sd = sd_module if sd_module is not None else self._import_sounddevice()
        self._device_index, self._device_name = self._resolve(device)
        self._queue: 'queue.Queue[AudioBlock]' = queue.Queue(maxsize=queue_blocks)
        self._stream: Any = None
        self._reader = BlockReader()
        self._lock = threading.Lock()
        # Written only by the audio callback; read (racily but atomically) by the consumer.
        self._frames_produced = 0
        self._blocks_produced = 0
        self._blocks_dropped = 0
        self._frames_dropped = 0
        self._overflows = 0
        self._frames_overflowed = 0
        self._callback_errors = 0
        self._next_index = 0               # index of the next frame, lost frames included
        self._prev_adc_end: Optional[float] = None   # ADC time just after the last block
        self._last_data = time.monotonic()

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
                self._prev_adc_end = None
                self._last_data = time.monotonic()
                stream.start()
            except Exception as exc:  # noqa: BLE001 - PortAudioError and friends
                raise AudioError(f'cannot open audio input {self._device_name!r} '
                                 f'({self._channels} ch, {self._sample_rate:g} Hz): {exc}') \
                    from exc
            self._stream = stream

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop and close the stream (blocks still queued can be read).

        A device that hangs (a driver blocked in its read) can hold ``stop`` forever; the
        stream is closed on a helper thread and abandoned after ``timeout_s`` with an
        :class:`AudioError`, so the caller's shutdown goes on.
        """
        with self._lock:
            stream, self._stream = self._stream, None
        if stream is None:
            return
        errors: list = []

        def close() -> None:
            try:
                try:
                    stream.abort()          # drop what is in flight: no wait on the device
                finally:
                    stream.close()
            except Exception as exc:  # noqa: BLE001 - handed to the caller below
                errors.append(exc)

        closer = threading.Thread(target=close, name='audio-close', daemon=True)
        closer.start()
        closer.join(timeout_s)
        if closer.is_alive():
            # sounddevice's exit handler would stop and close this stream again and hang
            # the process at exit: a hung stream is left to the OS.
            handler = getattr(self._sd, '_exit_handler', None)
            if handler is not None:
                atexit.unregister(handler)
            raise AudioError(f'audio input {self._device_name!r} did not stop within '
                             f'{timeout_s:g} s (device hung); stream abandoned')
        if errors:
            raise errors[0]

    close = stop

    @property
    def stream_latency(self) -> Optional[float]:
        """The input latency PortAudio chose for the open stream [s] (None when closed)."""
        stream = self._stream
        try:
            return float(stream.latency) if stream is not None else None
        except (AttributeError, TypeError, ValueError):
            return None

    def seconds_since_data(self) -> float:
        """Seconds since the last callback delivered a block (or since start)."""
        return time.monotonic() - self._last_data

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
            queue_depth=self._queue.qsize(), frames_overflowed=self._frames_overflowed,
            callback_errors=self._callback_errors)

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
            self._last_data = time.monotonic()
            data = np.array(indata, dtype=np.float32)
            if data.shape != (frames, self._channels):
                raise ValueError(f'callback block shaped {data.shape}')
            overflow = bool(getattr(status, 'input_overflow', False))
            adc = float(getattr(time_info, 'inputBufferAdcTime', 0.0) or 0.0)
            lost = self._frames_lost_before(adc, frames, overflow)
            index = self._next_index + lost
            self._next_index = index + frames
            self._frames_produced += frames
            self._blocks_produced += 1
            if overflow:
                self._overflows += 1
            self._frames_overflowed += lost
            current = float(getattr(time_info, 'currentTime', 0.0) or 0.0)
            now = time.time()
            # The block's first frame was acquired (current - adc) seconds ago when both
            # stamps are valid; some drivers report 0, then fall back to the block length.
            age = current - adc if adc > 0.0 and current >= adc else frames / self._sample_rate
            block = AudioBlock(index, adc, now - age, data, overflow)
            try:
                self._queue.put_nowait(block)
            except queue.Full:
                self._blocks_dropped += 1
                self._frames_dropped += frames
        except Exception:  # noqa: BLE001 - an exception here would kill the stream
            self._callback_errors += 1
            try:
                self._next_index += int(frames)     # the block is lost: leave its gap
            except Exception:  # noqa: BLE001 - frames itself may be the garbage
                pass

    def _frames_lost_before(self, adc: float, frames: int, overflow: bool) -> int:
        """Frames PortAudio lost between the previous block and this one (callback thread).

        Measured block to block (never against an accumulated expectation, which the ADC
        clock's drift against the sample rate would turn into phantom losses).
        """
        prev, self._prev_adc_end = self._prev_adc_end, \
            (adc + frames / self._sample_rate if adc > 0.0 else None)
        if not overflow:
            return 0
        hole = 0
        if prev is not None and adc > 0.0:
            hole = max(0, int(round((adc - prev) * self._sample_rate)))
        return hole if hole > 0 else frames
