"""audio_capture as a separate process: WAV, scene and PortAudio (ALSA file device) sources."""

from __future__ import annotations

import ctypes.util
import json

import numpy as np
import pytest

from test_nodes_support import Bus, NodeProcess

pytestmark = pytest.mark.ros

AUDIO = "/aslip/audio"
NAMES = ["lf", "lr", "rf", "rr"]


def _listen(bus):
    from std_msgs.msg import String

    from aslip_ros.msg import AudioFrame
    from aslip_ros.nodes import common as c
    bus.listen(AudioFrame, AUDIO, c.SENSOR_QOS)
    bus.listen(String, c.METADATA_TOPIC, c.LATCHED_QOS)
    bus.listen(String, "/aslip/diagnostics", c.RELIABLE_QOS)


def _decoded(bus):
    from aslip_ros.nodes import convert
    return [convert.audio_from_msg(m) for m in bus.messages(AUDIO)]


def test_wav_replay_publishes_10ms_blocks_with_metadata(rclpy_context, ros_env, tmp_path):
    from scipy.io import wavfile
    rate = 16000
    ramp = (np.arange(rate * 2 * 4).reshape(-1, 4) % 1000 - 500).astype(np.int16)
    wav = tmp_path / "four.wav"
    wavfile.write(wav, rate, ramp)
    bus = Bus(rclpy_context)
    _listen(bus)
    params = {"source": "wav", "wav_path": str(wav), "channel_names": NAMES,
              "metadata_json": '{"object": "chips_can"}'}
    with NodeProcess("audio_capture", ros_env, params) as node:
        node.wait_ready()
        assert bus.wait(lambda: len(bus.messages(AUDIO)) >= 30, 20), node.output
        assert bus.wait(lambda: bus.messages(c_meta()), 5)
    bus.close()
    frames = _decoded(bus)
    assert all(f.block.shape == (160, 4) for f in frames)          # 10 ms at 16 kHz
    assert all(f.channel_names == NAMES and f.sample_rate == rate for f in frames)
    idx = [f.first_sample_index for f in frames]
    assert idx == list(range(idx[0], idx[0] + 160 * len(idx), 160))
    first = frames[0]
    np.testing.assert_allclose(first.block, ramp[first.first_sample_index:
                                                 first.first_sample_index + 160] / 32768.0)
    meta = json.loads(bus.messages(c_meta())[-1].data)
    assert meta["object"] == "chips_can" and meta["channel_names"] == NAMES


def c_meta():
    return "/aslip/metadata"


def test_sim_source_streams_the_scene(rclpy_context, ros_env):
    bus = Bus(rclpy_context)
    _listen(bus)
    with NodeProcess("audio_capture", ros_env, {"source": "sim", "sim.object": "pla_rod"}) as n:
        n.wait_ready()
        assert bus.wait(lambda: len(bus.messages(AUDIO)) >= 20, 20), n.output
        assert bus.wait(lambda: bus.messages(c_meta()), 5)
    bus.close()
    meta = json.loads(bus.messages(c_meta())[-1].data)
    assert meta["object"] == "pla_rod" and meta["sample_rate"] == 48000.0
    frames = _decoded(bus)
    assert all(f.block.shape == (480, 4) and np.isfinite(f.block).all() for f in frames)
    assert frames[0].channel_names == meta["channel_names"]


@pytest.mark.skipif(ctypes.util.find_library("portaudio") is None,
                    reason="libportaudio2 is not installed")
def test_device_source_through_a_real_portaudio_stream(rclpy_context, ros_env, tmp_path):
    """PortAudio capture from an ALSA `file` PCM fed with a known ramp."""
    ramp = ((np.arange(48000 * 4) % 2000) / 2000.0 - 0.5).astype("<f4")
    infile = tmp_path / "in.raw"
    ramp.tofile(infile)
    conf = tmp_path / "asound.conf"
    conf.write_text("pcm.!default { type null }\n"
                    "pcm.aslip_file { type file\n slave.pcm { type null }\n"
                    f' file "/dev/null"\n infile "{infile}"\n format "raw"\n}}\n')
    env = dict(ros_env, ALSA_CONFIG_PATH=str(conf))
    bus = Bus(rclpy_context)
    _listen(bus)
    params = {"source": "device", "device": "aslip_file", "channels": 4,
              "channel_names": NAMES}
    with NodeProcess("audio_capture", env, params) as node:
        node.wait_ready()
        assert bus.wait(lambda: len(bus.messages(AUDIO)) >= 10, 20), node.output
    bus.close()
    frames = _decoded(bus)
    assert all(f.block.shape == (480, 4) and f.channel_names == NAMES for f in frames)
    idx = [f.first_sample_index for f in frames]
    assert all(b > a for a, b in zip(idx, idx[1:])) and all(i % 480 == 0 for i in idx)
    # The null PCM is not paced, so most blocks may lie past the ramp; those within it
    # must carry it exactly (sample order and scaling through PortAudio and the message).
    ref = ramp.reshape(-1, 4)
    for f in frames:
        if f.first_sample_index + 480 <= ref.shape[0]:
            np.testing.assert_array_equal(f.block, ref[f.first_sample_index:
                                                       f.first_sample_index + 480])


def test_missing_device_is_reported_and_bad_params_refused(rclpy_context, ros_env):
    bus = Bus(rclpy_context)
    _listen(bus)
    params = {"source": "device", "device": "no_such_device_anywhere"}
    with NodeProcess("audio_capture", ros_env, params) as node:
        node.wait_ready()
        assert bus.wait(lambda: any(d["level"] == 2 for d in
                                    bus.diagnostics("audio_capture")), 10), node.output
        assert node.proc.poll() is None and bus.messages(AUDIO) == []
    bus.close()
    for bad, needle in (({"source": "microphone"}, "source"),
                        ({"source": "wav", "block_s": 0.0}, "block_s")):
        proc = NodeProcess("audio_capture", ros_env, bad)
        assert proc.proc.wait(30) == 2
        out = proc.stop()
        assert "refused to start" in out and needle in out, out
