"""Audio sources: real PortAudio capture on ALSA null/file devices, callback logic, WAV replay."""

import ctypes.util
import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.io import wavfile

from aslip_ros.hw.audio import AudioError, SoundDeviceCapture
from aslip_ros.hw.wav import WavReplay

ROOT = Path(__file__).resolve().parents[1]
RATE = 48000
CHANNELS = 4
BLOCK = 480

# A complete ALSA configuration (ALSA_CONFIG_PATH replaces alsa.conf, so nothing else is
# loaded). PortAudio aborts at initialisation without a default PCM, hence pcm.!default.
# aslip_file feeds the capture from a raw file in the format PortAudio negotiates; with
# dtype float32 that is little-endian float32 interleaved frames.
ASOUNDRC = """\
pcm.!default {{ type null }}
pcm.aslip_null {{ type null }}
pcm.aslip_file {{
    type file
    slave.pcm {{ type null }}
    file "/dev/null"
    infile "{infile}"
    format "raw"
}}
"""

CHILD = textwrap.dedent("""\
    import json, sys, time
    import numpy as np
    from aslip_ros.hw.audio import SoundDeviceCapture
    device, infile = sys.argv[1], sys.argv[2]
    cap = SoundDeviceCapture(device, channels=4, sample_rate=48000, block_frames=480,
                             channel_names=['lf', 'lb', 'rf', 'rb'], queue_blocks=32)
    cap.start()
    first = [cap.read(5.0) for _ in range(20)]
    time.sleep(0.2)          # the ALSA null PCM is not paced: the queue overflows
    more = [cap.read(5.0) for _ in range(40)]
    running = cap.running
    cap.stop()
    rest = list(cap.blocks(0.1))
    st = cap.stats()
    blocks = first + more + rest
    out = dict(
        device=cap.device_name, names=cap.channel_names, running=running,
        n_none=sum(b is None for b in first + more),
        index=[b.first_sample_index for b in blocks],
        lost=[b.frames_lost_before for b in blocks],
        shapes=sorted({tuple(b.data.shape) for b in blocks}),
        dtypes=sorted({str(b.data.dtype) for b in blocks}),
        adc_finite=all(np.isfinite(b.adc_time) for b in blocks),
        host_age=[time.time() - b.host_time for b in first[:1]],
        stats=st.__dict__)
    if infile != '-':
        ref = np.fromfile(infile, dtype='<f4').reshape(-1, 4)
        out['data_matches'] = all(np.array_equal(b.data, ref[b.first_sample_index:
                                                              b.first_sample_index + 480])
                                  for b in first[:20])
    print(json.dumps(out))
    """)


def _portaudio_missing():
    return ctypes.util.find_library('portaudio') is None


@pytest.fixture
def alsa_env(tmp_path):
    ramp = ((np.arange(RATE * CHANNELS) % 2000) / 2000.0 - 0.5).astype('<f4')
    infile = tmp_path / 'in.raw'
    ramp.tofile(infile)
    conf = tmp_path / 'asound.conf'
    conf.write_text(ASOUNDRC.format(infile=infile))
    script = tmp_path / 'child.py'
    script.write_text(CHILD)
    env = dict(os.environ, ALSA_CONFIG_PATH=str(conf), PYTHONPATH=str(ROOT))
    return env, script, infile


def _run_child(alsa_env, device, with_file):
    env, script, infile = alsa_env
    proc = subprocess.run([sys.executable, str(script), device, str(infile) if with_file
                           else '-'], env=env, capture_output=True, text=True, timeout=60,
                          cwd=str(ROOT))
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _check_accounting(out):
    st = out['stats']
    assert out['n_none'] == 0
    assert out['shapes'] == [[BLOCK, CHANNELS]]
    assert out['dtypes'] == ['float32']
    assert out['adc_finite']
    assert st['blocks_produced'] == st['blocks_read'] + st['blocks_dropped'] + st['queue_depth']
    assert st['frames_produced'] == st['blocks_produced'] * BLOCK
    assert st['blocks_read'] == len(out['index'])
    # Indices strictly increase; every gap is reported, and the gaps add up to the drops.
    index, lost = out['index'], out['lost']
    assert index[:20] == [i * BLOCK for i in range(20)]
    for prev, cur, gap in zip(index, index[1:], lost[1:]):
        assert cur - prev - BLOCK == gap
    assert st['blocks_dropped'] > 0
    assert sum(lost) == st['frames_dropped'] - (st['frames_produced'] - index[-1] - BLOCK)


@pytest.mark.skipif(_portaudio_missing(), reason='libportaudio2 not installed (make setup)')
def test_portaudio_capture_on_alsa_null_device(alsa_env):
    out = _run_child(alsa_env, 'aslip_null', with_file=False)
    assert out['device'] == 'aslip_null'
    assert out['names'] == ['lf', 'lb', 'rf', 'rb']
    assert out['running']
    _check_accounting(out)


@pytest.mark.skipif(_portaudio_missing(), reason='libportaudio2 not installed (make setup)')
def test_portaudio_capture_on_alsa_file_device_delivers_the_samples(alsa_env):
    out = _run_child(alsa_env, 'aslip_file', with_file=True)
    _check_accounting(out)
    assert out['data_matches']


# -- the callback, with a fake sounddevice module ------------------------------------------

class FakeStream:
    def __init__(self, **kwargs):
        self.kwargs = kwargs
        self.active = False

    def start(self):
        self.active = True

    def stop(self):
        self.active = False

    abort = stop

    def close(self):
        pass


class FakeSD:
    def __init__(self, inputs=8):
        self.inputs = inputs
        self.streams = []

    def query_devices(self, device=None, kind=None):
        if device is None and kind is None:
            return [dict(name='mic', max_input_channels=self.inputs)]
        if device not in (None, 0, 'mic'):
            raise ValueError(f'No input device matching {device!r}')
        return dict(name='mic', index=0, max_input_channels=self.inputs)

    def InputStream(self, **kwargs):
        s = FakeStream(**kwargs)
        self.streams.append(s)
        return s


def _status(overflow=False):
    return SimpleNamespace(input_overflow=overflow)


def _times(adc, current):
    return SimpleNamespace(inputBufferAdcTime=adc, currentTime=current)


def test_callback_copies_counts_overflow_and_queue_full():
    sd = FakeSD()
    cap = SoundDeviceCapture('mic', 2, RATE, block_frames=4, queue_blocks=2, sd_module=sd)
    cap.start()
    kwargs = sd.streams[0].kwargs
    assert kwargs['dtype'] == 'float32' and kwargs['blocksize'] == 4
    assert kwargs['channels'] == 2 and kwargs['samplerate'] == RATE
    cb = kwargs['callback']
    buf = np.ones((4, 2), dtype=np.float32)
    step = 4 / RATE
    cb(buf, 4, _times(10.0, 10.01), _status())
    buf[:] = 2.0                                   # the callback must have copied
    # Overflow flagged while the ADC times show no hole: the loss is real, its size
    # unknown; one block length goes into the index, so the consumer sees a gap.
    cb(buf, 4, _times(10.0 + step, 10.0101), _status(overflow=True))
    cb(buf, 4, _times(10.0 + 2 * step, 10.0102), _status())   # queue full: dropped, counted
    b0 = cap.read(0)
    assert b0.first_sample_index == 0 and np.all(b0.data == 1.0)
    assert b0.adc_time == 10.0
    assert time.time() - b0.host_time == pytest.approx(0.01, abs=0.05)
    b1 = cap.read(0)
    assert b1.overflow and b1.first_sample_index == 8 and b1.frames_lost_before == 4
    cb(buf, 4, _times(0.0, 0.0), _status())      # driver without timestamps
    b3 = cap.read(0)
    assert b3.first_sample_index == 16 and b3.frames_lost_before == 4
    assert cap.read(0) is None
    st = cap.stats()
    assert (st.blocks_produced, st.blocks_read, st.blocks_dropped, st.frames_dropped,
            st.input_overflows, st.frames_overflowed) == (4, 3, 1, 4, 1, 4)
    cap.stop()
    assert not cap.running


def test_input_overflow_shows_as_a_gap_in_the_sample_index():
    """PortAudio lost two blocks (flagged, ADC time 20 ms on): the index jumps by them."""
    sd = FakeSD()
    cap = SoundDeviceCapture('mic', 2, RATE, block_frames=BLOCK, sd_module=sd)
    cap.start()
    cb = sd.streams[0].kwargs['callback']
    buf = np.zeros((BLOCK, 2), dtype=np.float32)
    t = 100.0
    dt = BLOCK / RATE
    for adc, overflow in ((t, False), (t + dt, False), (t + 4 * dt, True),
                          (t + 5 * dt + 0.0004, False),      # ADC jitter: no loss
                          (t + 9 * dt + 0.0004, False)):     # unflagged ADC jump
        cb(buf, BLOCK, _times(adc, adc + 0.01), _status(overflow))
    blocks = [cap.read(0) for _ in range(5)]
    # An unflagged ADC jump is no loss: drivers whose ADC times follow the callback's wall
    # clock jump whenever the host is busy (or the device is unpaced, as ALSA's null PCM).
    assert [b.first_sample_index for b in blocks] == [0, BLOCK, 4 * BLOCK, 5 * BLOCK,
                                                      6 * BLOCK]
    assert [b.frames_lost_before for b in blocks] == [0, 0, 2 * BLOCK, 0, 0]
    st = cap.stats()
    assert st.frames_overflowed == 2 * BLOCK and st.input_overflows == 1
    assert st.frames_produced == 5 * BLOCK           # frames delivered


def test_adc_clock_drift_makes_no_phantom_losses():
    sd = FakeSD()
    cap = SoundDeviceCapture('mic', 1, RATE, block_frames=BLOCK, queue_blocks=20000,
                             sd_module=sd)
    cap.start()
    cb = sd.streams[0].kwargs['callback']
    buf = np.zeros((BLOCK, 1), dtype=np.float32)
    step = BLOCK / RATE * (1 + 200e-6)               # ADC clock 200 ppm fast
    for i in range(10000):
        cb(buf, BLOCK, _times(50.0 + i * step, 50.0 + i * step + 0.01), _status())
    assert cap.stats().frames_overflowed == 0
    assert cap._next_index == 10000 * BLOCK


def test_silent_device_and_callback_errors_are_visible():
    sd = FakeSD()
    cap = SoundDeviceCapture('mic', 2, RATE, block_frames=4, sd_module=sd)
    cap.start()
    assert cap.seconds_since_data() < 1.0
    time.sleep(0.05)
    assert cap.seconds_since_data() >= 0.05          # nothing delivered since start
    cb = sd.streams[0].kwargs['callback']
    cb(np.zeros((4, 2), np.float32), 4, _times(1.0, 1.01), _status())
    assert cap.seconds_since_data() < 0.05
    cb(None, 4, None, None)                           # garbage: refused, counted
    cb(np.zeros((3, 2), np.float32), 4, None, None)   # not the frames it claims
    cb(np.zeros((4, 2), np.float32), 4, _times(1.0, 1.01), _status())
    assert cap.stats().callback_errors == 2
    # The failed callbacks' frames are gone: the next block's index shows the gap.
    got = [(b.first_sample_index, b.frames_lost_before)
           for b in iter(lambda: cap.read(0), None)]
    assert got == [(0, 0), (12, 8)]


def test_latency_is_validated_and_passed_to_portaudio():
    sd = FakeSD()
    cap = SoundDeviceCapture('mic', 2, RATE, sd_module=sd)
    cap.start()
    assert sd.streams[0].kwargs['latency'] == 'low'      # the default
    for given, passed in (('high', 'high'), (' LOW ', 'low'), (0.02, 0.02), ('0.05', 0.05)):
        SoundDeviceCapture('mic', 2, RATE, latency=given, sd_module=sd).start()
        assert sd.streams[-1].kwargs['latency'] == passed
    for bad in ('fast', '', 0.0, -1.0, float('nan'), 11.0, True, None):
        with pytest.raises(ValueError, match='latency'):
            SoundDeviceCapture('mic', 2, RATE, latency=bad, sd_module=sd)


def test_callback_never_raises():
    sd = FakeSD()
    cap = SoundDeviceCapture(None, 2, RATE, block_frames=4, sd_module=sd)
    cap.start()
    sd.streams[0].kwargs['callback'](None, 4, None, None)   # garbage in
    assert cap.stats().callback_errors == 1 and cap.read(0) is None


def test_device_resolution_and_validation():
    with pytest.raises(AudioError, match='no audio input device'):
        SoundDeviceCapture('nope', 2, RATE, sd_module=FakeSD())
    with pytest.raises(AudioError, match='input channels'):
        SoundDeviceCapture('mic', 4, RATE, sd_module=FakeSD(inputs=2))
    for kwargs in (dict(channels=0), dict(sample_rate=0.0), dict(sample_rate=float('nan')),
                   dict(block_frames=0), dict(channel_names=['a']),
                   dict(channel_names=['a', 'a']), dict(device=1.5)):
        args = dict(device='mic', channels=2, sample_rate=RATE, sd_module=FakeSD())
        args.update(kwargs)
        with pytest.raises(ValueError):
            SoundDeviceCapture(**args)


def test_stream_open_failure_is_audio_error():
    sd = FakeSD()

    def broken(**kwargs):
        raise RuntimeError('Invalid sample rate')
    sd.InputStream = broken
    cap = SoundDeviceCapture('mic', 2, 12345, sd_module=sd)
    with pytest.raises(AudioError, match='Invalid sample rate'):
        cap.start()


# -- WAV replay ------------------------------------------------------------------------------

def _write(tmp_path, dtype, frames=1000, channels=3, rate=RATE):
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.9, 0.9, size=(frames, channels))
    if dtype == 'int16':
        raw = np.round(x * 32767).astype(np.int16)
        ref = raw / 32768.0
    elif dtype == 'int32':
        raw = np.round(x * 2147483647).astype(np.int32)
        ref = raw / 2147483648.0
    elif dtype == 'uint8':
        raw = np.round(x * 127 + 128).astype(np.uint8)
        ref = (raw.astype(np.float64) - 128) / 128.0
    else:
        raw = x.astype(np.float32)
        ref = raw
    path = tmp_path / f'{dtype}.wav'
    wavfile.write(path, rate, raw)
    return path, ref


@pytest.mark.parametrize('dtype', ['int16', 'int32', 'uint8', 'float32'])
def test_wav_replay_unpaced_round_trip(tmp_path, dtype):
    path, ref = _write(tmp_path, dtype)
    src = WavReplay(str(path), block_frames=128, paced=False, channel_names=['a', 'b', 'c'])
    assert src.sample_rate == RATE and src.channels == 3 and src.n_frames == 1000
    blocks = list(src.blocks())
    assert src.finished
    assert [b.first_sample_index for b in blocks] == list(range(0, 1000, 128))
    assert blocks[-1].frames == 1000 - 7 * 128
    assert all(b.data.dtype == np.float32 for b in blocks)
    data = np.concatenate([b.data for b in blocks])
    assert np.allclose(data, ref, atol=1e-6)
    assert blocks[3].adc_time == pytest.approx(3 * 128 / RATE)
    assert src.read() is None
    assert src.stats().blocks_read == 8


def test_wav_replay_mono_and_channel_name_check(tmp_path):
    path = tmp_path / 'mono.wav'
    wavfile.write(path, 16000, np.zeros(100, dtype=np.int16))
    src = WavReplay(str(path), paced=False)
    assert src.channels == 1 and src.channel_names == ['ch0']
    with pytest.raises(ValueError):
        WavReplay(str(path), channel_names=['a', 'b'])


def test_wav_replay_paced_with_fake_clock(tmp_path):
    path, _ = _write(tmp_path, 'int16', frames=4800)
    clock = [0.0]
    sleeps = []

    def sleep(s):
        sleeps.append(s)
        clock[0] += s

    src = WavReplay(str(path), block_frames=480, paced=True, clock=lambda: clock[0],
                    sleep=sleep)
    b = src.read()
    assert b.first_sample_index == 0 and clock[0] == pytest.approx(0.01)
    assert src.read(timeout_s=0.001) is None       # next block not due within 1 ms
    clock[0] = 0.5                                 # late consumer: no sleeping, catch up
    n_sleeps = len(sleeps)
    rest = list(src.blocks())
    assert len(rest) == 9 and len(sleeps) == n_sleeps


def test_wav_replay_loop_keeps_counting(tmp_path):
    path, ref = _write(tmp_path, 'float32', frames=300, channels=2)
    src = WavReplay(str(path), block_frames=200, paced=False, loop=True)
    blocks = [src.read() for _ in range(4)]
    assert [b.first_sample_index for b in blocks] == [0, 200, 300, 500]
    assert [b.frames for b in blocks] == [200, 100, 200, 100]
    assert np.allclose(blocks[2].data, ref[:200])
    assert not src.finished
    src.stop()
    assert src.read() is None


def test_wav_replay_bad_file(tmp_path):
    bad = tmp_path / 'bad.wav'
    bad.write_bytes(b'not a wav file')
    with pytest.raises(AudioError):
        WavReplay(str(bad))
    with pytest.raises(AudioError):
        WavReplay(str(tmp_path / 'missing.wav'))
