"""audio_capture as a separate process: WAV, scene and PortAudio (ALSA file device) sources."""

from __future__ import annotations

import ctypes.util
import json

import numpy as np
import pytest

from node_support import Bus, NodeProcess, received_block, refusal

pytestmark = pytest.mark.ros

AUDIO = "/aslip/audio"
NAMES = ["lf", "lr", "rf", "rr"]


def _listen(bus):
    from std_msgs.msg import String

    from aslip_ros.msg import AudioFrame
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import LATCHED_QOS, RELIABLE_QOS, SENSOR_QOS
    bus.listen(AudioFrame, AUDIO, SENSOR_QOS)
    bus.listen(String, c.METADATA_TOPIC, LATCHED_QOS)
    bus.listen(String, "/aslip/diagnostics", RELIABLE_QOS)


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
              "metadata_json": '{"object": "chips_can"}', "autostart": False}
    with NodeProcess("audio_capture", ros_env, params) as node:
        node.wait_ready()
        start_when_discovered(bus, node)
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


def start_when_discovered(bus, node, timeout: float = 30.0) -> None:
    """Configure and activate an ``autostart:=false`` audio_capture once the bus sees its
    publisher: a finite replay started before discovery loses its first blocks on a busy
    machine (best effort), which says nothing about the node."""
    import time as _time

    from lifecycle_msgs.msg import Transition
    deadline = _time.monotonic() + timeout
    while bus.node.count_publishers(AUDIO) < 1 and _time.monotonic() < deadline:
        _time.sleep(0.05)
    assert bus.node.count_publishers(AUDIO) >= 1, node.output
    for t in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
        assert _change_state(bus, t, timeout), (t, node.output)


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
                        ({"source": "wav", "block_s": 0.0}, "block_s"),
                        ({"source": "device", "latency": "fast"}, "latency"),
                        ({"source": "device", "stall_timeout_s": 0.0}, "stall_timeout_s")):
        assert needle in refusal(rclpy_context, "audio_capture", bad)


def _bag_audio(path):
    """``{first_sample_index: (frames, channels) block}`` and the first AudioFrame of a bag."""
    from aslip_ros.data.bags import BagReader
    with BagReader(path) as r:
        msgs = [m.msg for m in r.messages([AUDIO])]
    names = list(msgs[0].channel_names)
    return {int(m.first_sample_index): np.asarray(m.data).reshape(-1, len(names))
            for m in msgs}, msgs[0]


def test_bag_replay_publishes_the_bags_audio_in_order(rclpy_context, ros_env, tmp_path):
    from aslip_ros.scene.simulate import simulate
    # 960-frame blocks: the bag's own blocks are replayed whatever block_s says.
    bag = simulate(tmp_path, "external", duration_s=2.0, block_frames=960,
                   progress=False)["bags"][0]
    blocks, first = _bag_audio(bag)
    names, rate = list(first.channel_names), float(first.sample_rate)
    assert sorted(blocks) == list(range(0, 96000, 960))
    bus = Bus(rclpy_context)
    _listen(bus)
    params = {"source": "bag", "bag_path": bag, "autostart": False}
    with NodeProcess("audio_capture", ros_env, params) as node:
        node.wait_ready()
        start_when_discovered(bus, node)
        assert node.wait_for("end of replay", 60), node.output
        assert bus.wait(lambda: bus.messages(c_meta()), 30)
        assert received_block(bus, AUDIO, 96000 - 960), node.output
    bus.close()
    assert "Traceback" not in node.output
    meta = json.loads(bus.messages(c_meta())[-1].data)
    assert meta["trial_id"] == "ext-0000" and meta["channel_names"] == names
    assert meta["sample_rate"] == rate == 48000.0
    frames = _decoded(bus)
    # Best-effort delivery may miss the blocks sent before discovery, none after.
    assert len(frames) >= 50, node.output
    idx = [f.first_sample_index for f in frames]
    assert idx == list(range(idx[0], 96000, 960))
    assert all(f.sample_rate == rate and f.channel_names == names and f.layout == "4mic"
               for f in frames)
    for f in frames:
        np.testing.assert_array_equal(f.block, blocks[f.first_sample_index])
    # Restamped at replay time, one block duration apart (float64 wall time: < 1 us off).
    stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)
    np.testing.assert_allclose(np.diff(stamps), 20_000_000, atol=1000)


def test_bag_replay_keeps_the_bags_audio_gaps(rclpy_context, ros_env, tmp_path):
    """Blocks missing from the bag stay missing: the sample index jumps over them."""
    from aslip_ros.data.synthetic import write_synthetic_bag
    bag = tmp_path / "gappy"
    write_synthetic_bag(bag, duration_s=1.5, audio_dropouts=[(1.0, 1.05)])
    blocks, _ = _bag_audio(bag)
    idx = sorted(blocks)
    gaps = [(a + 480, b) for a, b in zip(idx, idx[1:]) if b != a + 480]
    assert len(gaps) == 1 and gaps[0][0] == 48000            # five blocks from 1.0 s on
    lost, after = gaps[0][1] - gaps[0][0], gaps[0][1]
    bus = Bus(rclpy_context)
    _listen(bus)
    params = {"source": "bag", "bag_path": str(bag), "autostart": False}
    with NodeProcess("audio_capture", ros_env, params) as n:
        n.wait_ready()
        start_when_discovered(bus, n)
        assert n.wait_for("end of replay", 15), n.output
        assert n.wait_for(f"{lost} frames lost before sample {after}", 1), n.output
        assert received_block(bus, AUDIO, idx[-1]), n.output
    bus.close()
    frames = _decoded(bus)
    assert len(frames) >= 40, n.output
    for f in frames:
        np.testing.assert_array_equal(f.block, blocks[f.first_sample_index])
    assert frames[-1].first_sample_index == idx[-1]


@pytest.mark.parametrize("damage", ["missing", "truncated", "no_audio_topic"])
def test_bad_bag_is_reported_with_its_path(rclpy_context, ros_env, tmp_path, damage):
    from aslip_ros.data.synthetic import write_synthetic_bag
    bag = tmp_path / "bad_bag"
    params = {"source": "bag", "bag_path": str(bag)}
    if damage == "truncated":
        write_synthetic_bag(bag, duration_s=0.5)
        mcap = bag / "bad_bag.mcap"
        data = mcap.read_bytes()
        mcap.write_bytes(data[:len(data) // 2])
    elif damage == "no_audio_topic":
        write_synthetic_bag(bag, duration_s=0.5)
        params["bag_topic"] = "/elsewhere/audio"
    bus = Bus(rclpy_context)
    _listen(bus)
    with NodeProcess("audio_capture", ros_env, params) as node:
        node.wait_ready()
        assert bus.wait(lambda: any(d["level"] == 2 for d in
                                    bus.diagnostics("audio_capture")), 10), node.output
        assert node.proc.poll() is None
    bus.close()
    errors = [ln for ln in node.output.splitlines() if "cannot open audio source" in ln]
    assert errors and str(bag) in errors[0], node.output
    assert "Traceback" not in node.output and bus.messages(AUDIO) == []
    diag = [d for d in bus.diagnostics("audio_capture") if d["level"] == 2][-1]
    assert str(bag) in diag["message"]


# ------------------------------------------------------------------------- real-hardware faults

def _change_state(bus, transition_id: int, timeout: float = 20.0) -> bool:
    import time as _time

    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    cli = bus.node.create_client(ChangeState, "/audio_capture/change_state")
    assert cli.wait_for_service(timeout_sec=timeout)
    fut = cli.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
    deadline = _time.monotonic() + timeout
    while not fut.done() and _time.monotonic() < deadline:
        _time.sleep(0.02)
    return fut.done() and fut.result().success


def test_a_reopened_source_never_sends_the_index_back(rclpy_context, ros_env):
    """deactivate/activate, and cleanup/configure (a new source counting from 0): the
    published index goes on after the last block, moved on by the pause, so index and stamp
    stay consistent and a consumer sees one gap at each restart."""
    import time

    from lifecycle_msgs.msg import Transition
    bus = Bus(rclpy_context)
    _listen(bus)
    with NodeProcess("audio_capture", ros_env, {"source": "sim"}) as node:
        node.wait_ready()
        assert bus.wait(lambda: len(bus.messages(AUDIO)) >= 30, 20), node.output
        for transitions in ([Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_ACTIVATE],
                            [Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP,
                             Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE]):
            n = len(bus.messages(AUDIO))
            for t in transitions:
                assert _change_state(bus, t), (t, node.output)
                time.sleep(0.3)
            assert bus.wait(lambda: len(bus.messages(AUDIO)) >= n + 30, 20), node.output
        counted = bus.wait(lambda: any(d["values"].get("stream_restarts") == 2
                                       for d in bus.diagnostics("audio_capture")), 5)
    bus.close()
    frames = _decoded(bus)
    idx = np.array([f.first_sample_index for f in frames], dtype=np.int64)
    stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)
    step = np.diff(idx)
    assert np.all(step > 0), idx                    # never back, never repeated
    gaps = np.flatnonzero(step != 480)
    assert len(gaps) >= 2, step                     # each restart is a gap
    # Across every pair of blocks, the index advances with the stamp (to within 50 ms).
    drift = (np.diff(stamps) * 1e-9 - step / 48000.0)
    assert np.all(np.abs(drift) < 0.05), drift[np.abs(drift) >= 0.05]
    assert counted, node.output


@pytest.fixture
def fifo_device(tmp_path):
    """A PortAudio input (ALSA `file` PCM) that reads a FIFO: it delivers exactly what the
    test writes and stops delivering when the test stops writing, like a hung device."""
    import os
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    conf = tmp_path / "asound.conf"
    conf.write_text("pcm.!default { type null }\n"
                    "pcm.aslip_fifo { type file\n slave.pcm { type null }\n"
                    f' file "/dev/null"\n infile "{fifo}"\n format "raw"\n}}\n')
    fd = os.open(fifo, os.O_RDWR)             # a writer that never blocks the open
    yield fd, str(conf)
    os.close(fd)


def _feed(fd, seconds: float, stop_event=None) -> None:
    """Write ``seconds`` of 4-channel float32 audio at real time, in 10 ms pieces."""
    import os
    import time
    piece = (0.01 * np.ones((480, 4), "<f4")).tobytes()
    t0 = time.monotonic()
    for i in range(int(round(seconds / 0.01))):
        if stop_event is not None and stop_event.is_set():
            return
        os.write(fd, piece)
        time.sleep(max(0.0, t0 + (i + 1) * 0.01 - time.monotonic()))


@pytest.mark.skipif(ctypes.util.find_library("portaudio") is None,
                    reason="libportaudio2 is not installed")
def test_a_device_that_stops_delivering_is_an_error_within_a_second(
        rclpy_context, ros_env, fifo_device):
    import threading
    import time
    fd, conf = fifo_device
    env = dict(ros_env, ALSA_CONFIG_PATH=conf)
    bus = Bus(rclpy_context)
    _listen(bus)
    params = {"source": "device", "device": "aslip_fifo", "channels": 4,
              "channel_names": NAMES}
    stop = threading.Event()
    feeder = threading.Thread(target=_feed, args=(fd, 60.0, stop), daemon=True)
    feeder.start()
    try:
        with NodeProcess("audio_capture", env, params) as node:
            node.wait_ready()
            assert bus.wait(lambda: len(bus.messages(AUDIO)) >= 30, 20), node.output
            assert bus.wait(lambda: any(d["level"] == 0
                                        for d in bus.diagnostics("audio_capture")), 5), \
                node.output
            stop.set()                                   # the device stops delivering
            feeder.join()
            assert bus.wait(lambda: any(d["level"] == 2 and "no audio" in d["message"]
                                        for d in bus.diagnostics("audio_capture")), 10), \
                node.output
            err = [d for d in bus.diagnostics("audio_capture") if d["level"] == 2][0]
            # The node decided on its own clock: ERROR at its first check past the timeout
            # (the check of a capture thread starved on a loaded machine may come late: the
            # upper bound says "about the timeout", not how promptly a busy host checks).
            assert 0.5 <= err["values"]["seconds_without_audio"] < 2.0, err
            _feed(fd, 0.5)                               # it comes back
            assert node.wait_for("audio is back", 10), node.output
            t0 = time.monotonic()
    finally:
        # Also when a check failed: the fixture closes the device's fd after the test, and
        # a feeder still writing could write into whatever file reuses its number.
        stop.set()
        feeder.join(5)
    # Stopped while hung again (nothing written any more): the node still exits promptly.
    assert node.proc.returncode == 0 and time.monotonic() - t0 < 15, node.output
    bus.close()
    stats = [d["values"] for d in bus.diagnostics("audio_capture")]
    assert stats[-1]["stream_latency_ms"] > 0 and "capture_latency_p50_ms" in stats[-1]
