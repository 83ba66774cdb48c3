"""``aslip check audio`` and ``aslip check taps``: the device side (PortAudio through
:class:`aslip_ros.hw.audio.SoundDeviceCapture`, or a WAV recording) around the pure
measurements of :mod:`.levels` and :mod:`.taps`.

Time is the stream's own (sample index / rate): a check records ``seconds`` of audio, not
of wall time, so an unpaced source (a file) gives the answer a live device would. The wall
clock only guards against a device that stops delivering (``stall_s``).
"""

from __future__ import annotations

import time
from typing import Any, Callable, List, Optional, Sequence, Union

from aslip_ros.bringup import levels as lv
from aslip_ros.bringup import taps as tp
from aslip_ros.bringup.verdict import Verdict
from aslip_ros.hw.audio_block import AudioBlock, AudioError

#: A device that delivers nothing for this long has stopped.
DEFAULT_STALL_S = 5.0


def device_arg(text: Optional[str]) -> Union[str, int, None]:
    """A ``--device`` value: an index when it is a number, else a name (substring)."""
    if text is None:
        return None
    text = str(text).strip()
    return int(text) if text.isdigit() else text


def _sounddevice() -> Any:
    try:
        import sounddevice
    except OSError as exc:
        raise AudioError(f'sounddevice cannot load PortAudio ({exc}); install '
                         'libportaudio2') from exc
    return sounddevice


def list_inputs(out, sd: Any = None) -> int:
    """Print PortAudio's input devices; FAIL when there is none."""
    sd = sd or _sounddevice()
    devices = [(i, d) for i, d in enumerate(sd.query_devices())
               if int(d.get('max_input_channels', 0)) > 0]
    print(f"{'index':>5s}  {'inputs':>6s}  {'default Hz':>10s}  name", file=out)
    for i, d in devices:
        print(f"{i:5d}  {int(d['max_input_channels']):6d}  "
              f"{float(d.get('default_samplerate', 0.0)):10.0f}  {d['name']}", file=out)
    verdict = Verdict()
    if not devices:
        verdict.fail('PortAudio sees no audio input: is the interface plugged in and '
                     'powered, and is this user in the audio group?')
    else:
        verdict.notes.append('check a device: aslip check audio --device INDEX_OR_NAME')
    return verdict.report(out)


def open_source(device: Optional[str], wav: Optional[str], channels: Optional[int],
                names: Optional[Sequence[str]], sample_rate: Optional[float],
                sd: Any = None) -> Any:
    """A started-on-demand source: the WAV replay (unpaced) or the PortAudio device.

    Unset channels and rate come from the device (all its inputs, its default rate).
    """
    if names is not None and channels is not None and len(names) != channels:
        raise ValueError(f'{len(names)} channel names for --channels {channels}')
    if wav is not None:
        from aslip_ros.hw.wav import WavReplay
        return WavReplay(wav, paced=False, channel_names=names)
    sd = sd or _sounddevice()
    dev = device_arg(device)
    if channels is None and names is None or sample_rate is None:
        try:
            info = sd.query_devices(dev, 'input')
        except Exception as exc:  # noqa: BLE001 - ValueError / PortAudioError
            raise AudioError(f'no audio input device {device!r} ({exc}); list them with '
                             '`aslip check audio`') from exc
        if channels is None and names is None:
            channels = int(info['max_input_channels'])
        if sample_rate is None:
            sample_rate = float(info['default_samplerate'])
    channels = len(names) if names is not None else channels
    from aslip_ros.hw.audio import SoundDeviceCapture
    return SoundDeviceCapture(dev, channels, sample_rate, channel_names=names,
                              latency='high', sd_module=sd)


def stream(source: Any, seconds: float, on_block: Callable[[AudioBlock], None],
           stall_s: float = DEFAULT_STALL_S) -> int:
    """Feed ``seconds`` of the source's audio to ``on_block``; return the frames fed.

    Stops early at the end of a file; AudioError when a device delivers nothing for
    ``stall_s``. The source is stopped on the way out (also on Ctrl-C).
    """
    target = int(round(seconds * source.sample_rate))
    fed = 0
    source.start()
    try:
        last = time.monotonic()
        while fed < target:
            block = source.read(0.1)
            if block is None:
                if getattr(source, 'finished', False):
                    break
                if time.monotonic() - last > stall_s:
                    raise AudioError(f'the device delivered no audio for {stall_s:g} s')
                continue
            last = time.monotonic()
            block_data = block.data[:target - fed]
            on_block(AudioBlock(block.first_sample_index, block.adc_time, block.host_time,
                                block_data, block.overflow, block.frames_lost_before))
            fed += block_data.shape[0]
    finally:
        source.stop()
    return fed


def check_audio(source: Any, seconds: float, out, silent_dbfs: float = lv.DEFAULT_SILENT_DBFS,
                max_dc: float = lv.DEFAULT_MAX_DC, stall_s: float = DEFAULT_STALL_S) -> int:
    """Record, print the per-channel table and the verdict; return the exit code."""
    meter = lv.LevelMeter(source.channel_names)
    lost: List[int] = []

    def on_block(block: AudioBlock) -> None:
        meter.feed(block.data)
        lost.append(block.frames_lost_before)

    print(f'recording {seconds:g} s from {_source_name(source)} '
          f'({source.channels} ch, {source.sample_rate:g} Hz)...', file=out, flush=True)
    stream(source, seconds, on_block, stall_s)
    levels = meter.levels(silent_dbfs, max_dc)
    print(lv.format_levels(levels), file=out)
    verdict = lv.levels_verdict(levels)
    if meter.frames < seconds * source.sample_rate - 1:
        verdict.notes.append(f'only {meter.frames / source.sample_rate:.2f} s of audio')
    if sum(lost):
        verdict.notes.append(f'{sum(lost)} frames were lost on the way (a busy computer or '
                             'a device that is not paced); the levels are of what arrived')
    return verdict.report(out)


def check_taps(source: Any, out, taps_per_pad: int = 3, seconds_per_pad: float = 4.0,
               stall_s: float = DEFAULT_STALL_S) -> int:
    """Prompt for each pad in turn, detect the taps, print them and the verdict."""
    names = source.channel_names
    detector = tp.TapDetector(source.sample_rate, source.channels)
    found: List[tp.Tap] = []
    prompted = [-1]

    def on_block(block: AudioBlock) -> None:
        t = (block.first_sample_index + block.frames) / source.sample_rate
        pad = tp.pad_of(t, seconds_per_pad)
        if pad > prompted[0] and pad < len(names):
            prompted[0] = pad
            print(f'tap {names[pad]} now ({taps_per_pad} times, {seconds_per_pad:g} s)',
                  file=out, flush=True)
        for tap in detector.feed(block.data, block.first_sample_index):
            found.append(tap)
            print(f'  tap at {tap.time_s:6.2f} s: loudest on channel {tap.channel} '
                  f'({names[tap.channel]})', file=out, flush=True)

    print(f'listening to {_source_name(source)}: keep the gripper still for '
          f'{tp.LEAD_IN_S:g} s', file=out, flush=True)
    stream(source, tp.LEAD_IN_S + len(names) * seconds_per_pad, on_block, stall_s)
    verdict = tp.taps_verdict(names, found, seconds_per_pad, taps_per_pad)
    return verdict.report(out)


def _source_name(source: Any) -> str:
    return getattr(source, 'device_name', None) or 'the recording'
