"""audio_capture bridging audio_common (``input_type:=audio_common``), in one process: the
driver's messages as ``audio_capture_node`` sends them (``audio_stamped`` reliable 10 deep,
``audio_info`` latched, empty frame_id, wall-clock stamps, S16LE bytes, MP3 by default)."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from node_support import Bus, driver_msgs

pytestmark = pytest.mark.ros

AUDIO = "/aslip/audio"
STAMPED, INFO = "/audio/audio_stamped", "/audio/audio_info"
RATE, BLOCK = 16000, 160


@pytest.fixture
def rig(rclpy_context):
    """The capture node (spun on its own executor) and a bus standing in for the driver."""
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile
    from std_msgs.msg import String

    from aslip_ros.msg import AudioFrame
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import LATCHED_QOS, RELIABLE_QOS, SENSOR_QOS
    from aslip_ros.nodes.audio_capture import AudioCapture
    acm = driver_msgs("audio_common_msgs")
    bus = Bus(rclpy_context)
    bus.listen(AudioFrame, AUDIO, SENSOR_QOS)
    bus.listen(String, c.METADATA_TOPIC, LATCHED_QOS)
    bus.listen(String, c.DIAG_JSON_TOPIC, RELIABLE_QOS)
    # The driver's QoS: rclcpp's QoS(10) for the audio, KeepLast(1).transient_local() info.
    audio_pub = bus.node.create_publisher(acm.AudioDataStamped, STAMPED, 10)
    info_pub = bus.node.create_publisher(acm.AudioInfo, INFO, QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node = AudioCapture(context=rclpy_context, parameter_overrides=[
        Parameter("source", value="topic"), Parameter("input_type", value="audio_common"),
        Parameter("input_topic", value=STAMPED), Parameter("channel_names", value=["mic"]),
        Parameter("layout", value="")])
    ex = MultiThreadedExecutor(context=rclpy_context)
    ex.add_node(node)
    spin = threading.Thread(target=ex.spin, daemon=True)
    spin.start()
    assert bus.wait(lambda: audio_pub.get_subscription_count() >= 1, 10)
    yield bus, node, acm, audio_pub, info_pub
    node.before_shutdown()
    ex.shutdown()
    spin.join(5)                # not under a wait on the node's entities (see test_live_estimator)
    node.destroy_node()
    bus.close()


def info(acm, coding="wave", rate=RATE, fmt="S16LE", channels=1):
    return acm.AudioInfo(channels=channels, sample_rate=rate, sample_format=fmt, bitrate=192,
                         coding_format=coding)


def stamped(acm, k: int, t0_ns: int):
    """Block ``k`` as the driver sends it: S16LE bytes of value 100 k, its capture time."""
    msg = acm.AudioDataStamped()
    ns = t0_ns + k * BLOCK * 1_000_000_000 // RATE
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    msg.audio.data = np.full(BLOCK, 100 * k, "<i2").tobytes()
    return msg


def level(name: str) -> int:
    from aslip_ros.nodes.common import Diagnostics
    return getattr(Diagnostics, name)


def diag(bus, predicate, timeout=10.0):
    found = []

    def ok():
        docs = bus.diagnostics("audio_capture")
        if docs and predicate(docs[-1]):
            found.append(docs[-1])
            return True
        return False
    assert bus.wait(ok, timeout), bus.diagnostics("audio_capture")[-3:]
    return found[-1]


def test_s16le_after_a_late_audio_info_becomes_audio_frames(rig):
    from aslip_ros.nodes import convert
    bus, node, acm, audio_pub, info_pub = rig
    t0 = time.time_ns()
    # Audio before the AudioInfo: held back, and the diagnostics say what is missing.
    for k in range(5):
        audio_pub.publish(stamped(acm, k, t0))
    d = diag(bus, lambda d: "waiting for audio_info" in d["message"])
    assert d["level"] == level("WARN") and INFO in d["message"]
    assert not bus.messages(AUDIO) and not bus.messages("/aslip/metadata")
    info_pub.publish(info(acm))
    assert bus.wait(lambda: node.src.waiting_for == "", 10)
    sent = [k for k in range(5, 40) if k != 20]          # block 20 lost on the way
    for k in sent:
        audio_pub.publish(stamped(acm, k, t0))
        time.sleep(0.002)
    assert bus.wait(lambda: len(bus.messages(AUDIO)) >= len(sent) - 2, 10)
    frames = [convert.audio_from_msg(m) for m in bus.messages(AUDIO)]
    k = np.array([round(f.block[0, 0] * 32768 / 100) for f in frames])
    idx = np.array([f.first_sample_index for f in frames])
    # Channels and rate from the AudioInfo; the frame the node's; S16LE at +-1 full scale.
    assert all(f.channel_names == ["mic"] and f.sample_rate == RATE and f.frame_id and
               f.block.shape == (BLOCK, 1) for f in frames)
    np.testing.assert_array_equal([f.block[-1, 0] for f in frames], 100 * k / 32768.0)
    # The counter starts at the first published block and leaves the lost block's gap.
    np.testing.assert_array_equal(idx, BLOCK * (k - 5))
    assert 20 not in k and (idx[k == 21] - idx[k == 19] == 2 * BLOCK).all()
    # Stamps are the driver's capture times (to the float seconds an AudioBlock holds).
    np.testing.assert_allclose([f.stamp_ns - t0 for f in frames],
                               [kk * BLOCK * 1_000_000_000 // RATE for kk in k], atol=1000)
    meta = json.loads(bus.messages("/aslip/metadata")[-1].data)
    assert meta["sample_rate"] == RATE and meta["channel_names"] == ["mic"]
    assert meta["source_info_topic"] == INFO

    # Another format mid-stream is refused (its audio dropped) until the first returns.
    info_pub.publish(info(acm, rate=48000))
    d = diag(bus, lambda d: d["level"] == level("ERROR"))
    assert "changed mid-stream" in d["message"] and "restart audio_capture" in d["message"]
    n, held = len(bus.messages(AUDIO)), node.src.held
    for k in range(40, 45):
        audio_pub.publish(stamped(acm, k, t0))
    assert bus.wait(lambda: node.src.held == held + 5, 10)
    info_pub.publish(info(acm))
    assert bus.wait(lambda: node.src.refusal == "", 10)
    audio_pub.publish(stamped(acm, 45, t0))
    assert bus.wait(lambda: len(bus.messages(AUDIO)) > n, 10)
    last = convert.audio_from_msg(bus.messages(AUDIO)[-1])
    assert len(bus.messages(AUDIO)) == n + 1 and last.first_sample_index == (45 - 5) * BLOCK


def test_mp3_is_refused_with_what_to_set(rig):
    bus, node, acm, audio_pub, info_pub = rig
    info_pub.publish(info(acm, coding="mp3"))            # audio_capture_node's default
    t0 = time.time_ns()
    for k in range(10):
        msg = acm.AudioDataStamped()
        msg.audio.data = bytes(range(200))                # not PCM at all
        audio_pub.publish(msg)
    d = diag(bus, lambda d: d["level"] == level("ERROR"))
    assert "format:=wave" in d["message"] and "'mp3'" in d["message"], d
    # Wrong channel count: refused too, naming the parameter to set.
    info_pub.publish(info(acm, channels=2))
    d = diag(bus, lambda d: "channel_names" in d["message"])
    assert d["level"] == level("ERROR") and "2 channel(s)" in d["message"]
    audio_pub.publish(stamped(acm, 0, t0))
    assert bus.wait(lambda: node.src.held == 11, 10)       # every block held back
    assert not bus.messages(AUDIO) and not bus.messages("/aslip/metadata")
    assert node.error == ""
