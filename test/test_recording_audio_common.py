"""Recording audio_common's pair where a cell bridges it: data_collection.launch.py names
``audio_stamped`` and the latched ``audio_info`` to its recorder (either one), and the
package's bag_recorder takes the AudioInfo the driver latched before the recorder started
(transient-local), so ``aslip export`` can read the pair alone."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from node_support import Bus, driver_msgs
from test_launch_files import _by_exe, check_parameters, evaluate, needs_launch

pytestmark = pytest.mark.ros

STAMPED, INFO = "/audio/audio_stamped", "/audio/audio_info"
CELL = f"""\
audio_capture:
  source: topic
  input_type: audio_common
  input_topic: {STAMPED}
  channel_names: [mic]
"""


@needs_launch
def test_a_cell_bridging_audio_common_records_its_pair(tmp_path):
    cell = tmp_path / "cell.yaml"
    cell.write_text(CELL)
    ev = evaluate("data_collection.launch.py", {"sim": "false", "cell": str(cell),
                                                "recorder": "aslip"})
    nodes = _by_exe(ev)
    assert {STAMPED, INFO, "/aslip/audio"} <= set(nodes["bag_recorder"]["topics"])
    cap = nodes["audio_capture"]
    assert (cap["source"], cap["input_type"], cap["input_topic"]) == \
        ("topic", "audio_common", STAMPED)
    check_parameters(ev)
    # Without the bridge, nothing of the driver's is recorded.
    ev = evaluate("data_collection.launch.py", {"sim": "false", "recorder": "aslip"})
    assert STAMPED not in _by_exe(ev)["bag_recorder"]["topics"]


def test_bag_recorder_takes_the_latched_audio_info_and_the_audio(rclpy_context, tmp_path):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile

    from aslip_ros.data.audio_common import AudioCommonFrames
    from aslip_ros.data.bags import BagReader
    from aslip_ros.nodes.bag_recorder import Recorder
    acm = driver_msgs("audio_common_msgs")
    bus = Bus(rclpy_context)
    audio_pub = bus.node.create_publisher(acm.AudioDataStamped, STAMPED, 10)
    info_pub = bus.node.create_publisher(acm.AudioInfo, INFO, QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    # Latched before the recorder exists: it reaches the bag only through transient local.
    info_pub.publish(acm.AudioInfo(channels=1, sample_rate=16000, sample_format="S16LE",
                                   bitrate=192, coding_format="wave"))
    bag = tmp_path / "bag"
    rec = Recorder(context=rclpy_context, parameter_overrides=[
        Parameter("output", value=str(bag)), Parameter("topics", value=[STAMPED, INFO]),
        Parameter("discovery_period_s", value=0.05)])
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(rec)
    spin = threading.Thread(target=ex.spin, daemon=True)
    spin.start()
    try:
        assert bus.wait(lambda: audio_pub.get_subscription_count() >= 1, 10), rec.refused
        t0 = time.time_ns()
        for k in range(20):
            msg = acm.AudioDataStamped()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t0 + k * 10_000_000,
                                                                    1_000_000_000)
            msg.audio.data = np.full(160, k, "<i2").tobytes()
            audio_pub.publish(msg)
        assert bus.wait(lambda: rec.counts.get(STAMPED) == 20 and rec.counts.get(INFO), 10), \
            (rec.counts, rec.refused)
    finally:
        rec.before_shutdown()
        ex.shutdown()
        spin.join(5)            # not under a wait on the node's entities (see test_live_estimator)
        rec.destroy_node()
        bus.close()
    with BagReader(bag) as r:
        frames = AudioCommonFrames(r, STAMPED, {})
        got = [frames.frame(m.msg) for m in r.messages([STAMPED])]
    assert str(frames.fmt) == "16000 Hz, 1 ch, S16LE" and frames.channel_names == ["ch0"]
    assert [f.first_sample_index for f in got] == [160 * k for k in range(20)]
    np.testing.assert_array_equal([f.data[0] * 32768 for f in got], np.arange(20))
