"""aslip check taps: tap detection on synthetic pads, the verdict on a swapped channel order,
and the whole command on a recording."""

import numpy as np
import pytest
from scipy.io import wavfile

from aslip_ros import cli
from aslip_ros.bringup import taps as tp

RATE = 48000
NAMES = ['left_front_top', 'left_rear_bottom', 'right_front_bottom', 'right_rear_top']
SPP = 4.0


def recording(loudest_channel_of_pad, taps_per_pad=3, seed=0, rate=RATE):
    """Quiet noise on every channel; pad i tapped ``taps_per_pad`` times in its interval,
    each tap ringing loudest on ``loudest_channel_of_pad[i]`` with crosstalk on the rest."""
    rng = np.random.default_rng(seed)
    n_ch = len(loudest_channel_of_pad)
    total = tp.LEAD_IN_S + n_ch * SPP + 0.5
    x = 1e-3 * rng.standard_normal((int(total * rate), n_ch))
    ring = np.arange(int(0.08 * rate)) / rate
    burst = np.sin(2 * np.pi * 900 * ring) * np.exp(-ring / 0.015)
    onsets = []
    for pad, ch in enumerate(loudest_channel_of_pad):
        for k in range(taps_per_pad):
            t = tp.LEAD_IN_S + pad * SPP + 0.6 + k * 1.1
            i = int(t * rate)
            gains = np.full(n_ch, 0.05)
            gains[ch] = 0.5
            x[i:i + len(burst)] += burst[:, None] * gains[None, :]
            onsets.append((t, ch))
    return x.astype(np.float32), onsets


def detect(x, block=480):
    det = tp.TapDetector(RATE, x.shape[1])
    found = []
    for i in range(0, len(x), block):
        found += det.feed(x[i:i + block], i)
    return found


def test_every_tap_is_found_once_on_its_channel():
    x, onsets = recording([0, 1, 2, 3])
    found = detect(x)
    assert [t.channel for t in found] == [ch for _, ch in onsets]
    for tap, (t, _) in zip(found, onsets):
        assert tap.time_s == pytest.approx(t, abs=0.011)
    verdict = tp.taps_verdict(NAMES, found, SPP, taps_per_pad=3)
    assert verdict.line() == 'verdict: OK' and not verdict.notes


def test_detection_does_not_depend_on_block_size_or_gaps():
    x, onsets = recording([0, 1, 2, 3], seed=3)
    assert [t.channel for t in detect(x, block=333)] == [ch for _, ch in onsets]
    # A dropped block far from any tap changes nothing.
    det = tp.TapDetector(RATE, 4)
    found = []
    for i in range(0, len(x), 480):
        if i != 480 * 20:
            found += det.feed(x[i:i + 480], i)
    assert [t.channel for t in found] == [ch for _, ch in onsets]


def test_a_swapped_pair_is_named_with_the_swap():
    x, _ = recording([2, 1, 0, 3])       # left_front_top and right_front_bottom swapped
    verdict = tp.taps_verdict(NAMES, detect(x), SPP, taps_per_pad=3)
    assert not verdict.ok
    text = verdict.line()
    assert ('you tapped left_front_top but channel 2 (right_front_bottom) was loudest: swap '
            'channels 0 and 2') in text
    assert ('you tapped right_front_bottom but channel 0 (left_front_top) was loudest: swap '
            'channels 0 and 2') in text
    assert 'left_rear_bottom' not in text and 'right_rear_top' not in text
    assert verdict.notes == ['the channel names in input order are: right_front_bottom,'
                             'left_rear_bottom,left_front_top,right_rear_top']


def test_a_rotated_order_and_a_silent_pad():
    x, _ = recording([1, 2, 0, 3])
    text = tp.taps_verdict(NAMES, detect(x), SPP).line()
    assert 'you tapped left_front_top but channel 1 (left_rear_bottom) was loudest: ' \
           'left_front_top is wired to input 1' in text
    x, _ = recording([0, 1, 2, 3])
    x[int((tp.LEAD_IN_S + 3 * SPP) * RATE):] = 1e-3   # nothing while right_rear_top is asked
    verdict = tp.taps_verdict(NAMES, detect(x), SPP)
    assert verdict.problems == ['no tap detected while right_rear_top was prompted: tap '
                                'harder, or channel 3 (right_rear_top) is dead (run aslip '
                                'check audio)']


def test_check_taps_command_on_a_recording(tmp_path, capsys):
    x, _ = recording([0, 3, 2, 1])
    wav = tmp_path / 'taps.wav'
    wavfile.write(wav, RATE, x)
    rc = cli.main(['check', 'taps', '--wav', str(wav), '--channel-names', ','.join(NAMES)])
    out = capsys.readouterr().out
    assert rc == 1, out
    prompts = [ln for ln in out.splitlines() if ln.startswith('tap ')]
    assert prompts == [f'tap {n} now (3 times, 4 s)' for n in NAMES]
    assert 'swap channels 1 and 3' in out.splitlines()[-1]
    x, _ = recording([0, 1, 2, 3])
    wavfile.write(wav, RATE, x)
    assert cli.main(['check', 'taps', '--wav', str(wav), '--channel-names',
                     ','.join(NAMES)]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == 'verdict: OK'
