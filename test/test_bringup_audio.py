"""aslip check audio: levels, clipping and silence on synthetic blocks, and the whole command
against a real PortAudio device (an ALSA ``file`` PCM fed from a raw float32 file)."""

import ctypes.util
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from aslip_ros.bringup import levels as lv
from aslip_ros.bringup.audio_checks import list_inputs

ROOT = Path(__file__).resolve().parents[1]
RATE = 48000

# A complete ALSA configuration, as test_hw_audio.py builds it: ALSA_CONFIG_PATH replaces
# alsa.conf; aslip_file captures little-endian float32 interleaved frames from `infile`.
ASOUNDRC = """\
pcm.!default {{ type null }}
pcm.aslip_file {{
    type file
    slave.pcm {{ type null }}
    file "/dev/null"
    infile "{infile}"
    format "raw"
}}
"""


def _sine(amplitude, hz=440.0, seconds=1.0, rate=RATE):
    t = np.arange(int(seconds * rate)) / rate
    return amplitude * np.sin(2 * np.pi * hz * t)


def _meter(columns, block=480):
    data = np.stack(columns, axis=1).astype(np.float32)
    meter = lv.LevelMeter([f'm{k}' for k in range(data.shape[1])])
    for i in range(0, len(data), block):
        meter.feed(data[i:i + block])
    return meter.levels()


def test_levels_of_known_signals():
    rng = np.random.default_rng(0)
    quiet = _sine(0.1)
    clipped = np.clip(_sine(1.5), -1.0, 1.0)
    dead = np.zeros_like(quiet)
    offset = 0.2 + _sine(0.05)
    hiss = 1e-6 * rng.standard_normal(len(quiet))     # a preamp's self-noise, -120 dBFS
    a, b, c, d, e = _meter([quiet, clipped, dead, offset, hiss])
    assert a.rms_dbfs == pytest.approx(20 * np.log10(0.1 / np.sqrt(2)), abs=0.05)
    assert a.peak_dbfs == pytest.approx(-20.0, abs=0.01)
    assert (a.status, a.clipped) == ('OK', 0)
    assert b.status == 'CLIPPING' and b.clipped > 1000 and b.peak_dbfs == 0.0
    assert c.status == 'SILENT' and c.rms_dbfs == -np.inf
    assert d.status == 'DC' and d.dc == pytest.approx(0.2, abs=1e-3)
    assert e.status == 'SILENT'
    verdict = lv.levels_verdict([a, b, c, d, e])
    assert not verdict.ok
    line = verdict.line()
    assert line.startswith('verdict: FAIL: ') and 'm0' not in line
    assert 'm1 CLIPPING (lower the gain)' in line and 'm2 SILENT (dead mic or wiring' in line
    assert 'm3 DC' in line and 'm4 SILENT' in line
    assert lv.levels_verdict([a]).line() == 'verdict: OK'


def test_meter_refuses_a_wrong_block_and_an_empty_recording():
    meter = lv.LevelMeter(['a', 'b'])
    with pytest.raises(ValueError):
        meter.feed(np.zeros((10, 3)))
    with pytest.raises(ValueError, match='no audio'):
        meter.levels()


def test_listing_shows_inputs_only_and_fails_without_any(capsys):
    devices = [dict(name='hdmi', max_input_channels=0, default_samplerate=48000.0),
               dict(name='Scarlett 4i4', max_input_channels=4, default_samplerate=48000.0)]
    assert list_inputs(sys.stdout, SimpleNamespace(query_devices=lambda: devices)) == 0
    out = capsys.readouterr().out
    assert 'Scarlett 4i4' in out and 'hdmi' not in out and out.rstrip().endswith('verdict: OK')
    assert list_inputs(sys.stdout, SimpleNamespace(query_devices=lambda: devices[:1])) == 1
    assert 'verdict: FAIL: PortAudio sees no audio input' in capsys.readouterr().out


def _portaudio_missing():
    return ctypes.util.find_library('portaudio') is None


def _run_check(tmp_path, columns, *extra):
    infile = tmp_path / 'in.raw'
    np.stack(columns, axis=1).astype('<f4').tofile(infile)
    conf = tmp_path / 'asound.conf'
    conf.write_text(ASOUNDRC.format(infile=infile))
    env = dict(os.environ, ALSA_CONFIG_PATH=str(conf))
    return subprocess.run(
        [sys.executable, '-P', '-m', 'aslip_ros.cli', 'check', 'audio', '--device',
         'aslip_file', '--sample-rate', str(RATE), '--seconds', '0.5', *extra],
        env=env, capture_output=True, text=True, timeout=120, cwd=str(ROOT))


@pytest.mark.skipif(_portaudio_missing(), reason='libportaudio2 not installed (make setup)')
def test_check_audio_on_a_device_with_a_clipped_and_a_silent_channel(tmp_path):
    good = _sine(0.1, seconds=4.0)
    proc = _run_check(tmp_path, [good, np.clip(_sine(1.3, seconds=4.0), -1, 1),
                                 np.zeros_like(good)],
                      '--channel-names', 'left_front,left_rear,right_front')
    assert proc.returncode == 1, proc.stdout + proc.stderr
    lines = proc.stdout.strip().splitlines()
    rows = {ln.split()[0]: ln for ln in lines if ln.split() and
            ln.split()[0] in ('left_front', 'left_rear', 'right_front')}
    assert rows['left_front'].rstrip().endswith('OK')
    assert 'CLIPPING (lower the gain)' in rows['left_rear']
    assert 'SILENT (dead mic or wiring' in rows['right_front']
    assert lines[-1].startswith('verdict: FAIL: ')
    assert 'left_rear CLIPPING' in lines[-1] and 'right_front SILENT' in lines[-1]
    assert 'left_front' not in lines[-1]


@pytest.mark.skipif(_portaudio_missing(), reason='libportaudio2 not installed (make setup)')
def test_check_audio_on_a_device_with_good_levels_passes(tmp_path):
    rng = np.random.default_rng(1)
    columns = [_sine(0.2, seconds=4.0), 0.01 * rng.standard_normal(4 * RATE)]
    proc = _run_check(tmp_path, columns, '--channels', '2')
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == 'verdict: OK'
    assert [ln.split()[0] for ln in lines if ln.rstrip().endswith('  OK')] == ['ch0', 'ch1']
