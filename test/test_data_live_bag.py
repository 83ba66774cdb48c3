"""A bag recorded from live rclpy publishers by a separate process exports.

The publisher imitates other hardware: 44.1 kHz, two channels with other names, 100 Hz
motion capture, no scenario metadata; labels therefore come from motion capture alone.
"""

from __future__ import annotations

import signal
import subprocess
import sys

import numpy as np
import pytest

from conftest import HELPERS

from aslip_ros.util import die_with_parent

pytestmark = pytest.mark.ros


def _child(args, env):
    proc = subprocess.Popen([sys.executable, *map(str, args)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=die_with_parent)
    line = proc.stdout.readline()
    if "ready" not in line:
        proc.kill()
        raise AssertionError(f"{args[0]} failed to start:\n{line}{proc.stdout.read()}")
    return proc


def test_live_recorded_bag_exports(tmp_path, ros_env):
    from aslip_ros.data.dataset import Dataset
    from aslip_ros.data.export import export

    bag = tmp_path / "live_bag"
    recorder = _child([HELPERS / "record_raw.py", bag], ros_env)
    try:
        publisher = _child([HELPERS / "pub_live.py", "30"], ros_env)
        pub_out = publisher.communicate(timeout=60)[0]
        assert publisher.returncode == 0, pub_out
    finally:
        recorder.send_signal(signal.SIGINT)
        rec_out = recorder.communicate(timeout=30)[0]
    assert recorder.returncode == 0, rec_out

    summary = export([bag], tmp_path / "ds", window_s=0.2, hop_s=0.1, progress=False)
    ds = Dataset(tmp_path / "ds")
    assert ds.manifest["sample_rate"] == pytest.approx(44100.0)
    assert list(ds.manifest["channel_names"]) == ["jaw_a", "jaw_b"]
    w = ds.windows
    assert len(w) >= 25, str(summary)  # 3 s at a 0.1 s hop
    # Windows entirely inside the slip phase carry +x at 20 mm/s in the grasp plane, even
    # though the motion is along world +y; windows entirely outside carry zero.
    rate = ds.manifest["sample_rate"]
    # Stream time of each window: blocks published before the recorder subscribed are not
    # in the bag, so file positions are offset by the trial's first stream sample.
    (trial,) = ds.manifest["trials"]
    assert trial["audio_gaps"] == 0, str(summary)
    t_start = (trial["first_sample_index"] + w["start"]) / rate
    inside = (t_start >= 0.85) & (t_start + 0.2 <= 2.15)
    outside = (t_start + 0.2 <= 0.75) | (t_start >= 2.25)
    assert inside.sum() >= 5 and outside.sum() >= 2, str(summary)
    np.testing.assert_allclose(w["vx"][inside], 0.02, atol=0.003)
    np.testing.assert_allclose(w["vz"][inside], 0.0, atol=0.003)
    assert np.all(w["slip"][inside] == 1)
    np.testing.assert_allclose(w["speed"][outside], 0.0, atol=0.003)
