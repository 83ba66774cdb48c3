"""aslip check mocap: the statistics on hand-made arrivals, and the rclpy listener on poses
published in-process at a known rate."""

import time

import numpy as np
import pytest

from aslip_ros.bringup.mocap_stats import mocap_verdict, stream_stats

MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000


def _stream(n=200, period_ms=10.0, latency_ms=4.0, drop=(), jitter_ms=0.0, seed=0):
    rng = np.random.default_rng(seed)
    k = np.array([i for i in range(n) if i not in drop])
    stamp = T0 + (k * period_ms * MS).astype(np.int64)
    recv = stamp + int(latency_ms * MS) + (jitter_ms * MS * rng.random(k.size)).astype(int)
    return recv, stamp


def test_a_good_stream():
    s = stream_stats('/f', *_stream(jitter_ms=1.0), frame_ids=['world'] * 200)
    assert s.count == 200 and s.rate_hz == pytest.approx(100.0)
    assert s.dropouts == 0 and s.longest_gap_s == pytest.approx(0.01)
    assert 0.004 <= s.latency_median_s <= 0.005 and s.latency_p95_s <= 0.005
    assert 0.0 < s.jitter_s < 0.001 and not s.clocks_unsynchronised
    assert s.frame_ids == ('world',)
    assert mocap_verdict({'/f': s, '/o': s}).line() == 'verdict: OK'


def test_dropouts_slow_rate_silence_and_clocks_fail():
    gappy = stream_stats('/f', *_stream(drop=range(50, 60)), ['world'] * 190)
    assert gappy.dropouts == 1 and gappy.longest_gap_s == pytest.approx(0.11)
    slow = stream_stats('/o', *_stream(period_ms=50.0), ['world'] * 200)
    assert slow.rate_hz == pytest.approx(20.0)
    text = mocap_verdict({'/f': gappy, '/o': slow}).line()
    assert '/f: 1 dropout(s), longest gap 110 ms' in text
    assert '/o at 20.0 Hz, below 30 Hz' in text
    none = stream_stats('/o', [], [])
    assert 'no messages on /o' in mocap_verdict({'/o': none}).line()
    ahead = stream_stats('/f', *_stream(latency_ms=-20.0), ['world'] * 200)
    behind = stream_stats('/o', *_stream(latency_ms=900.0), ['world'] * 200)
    assert ahead.clocks_unsynchronised and behind.clocks_unsynchronised
    text = mocap_verdict({'/f': ahead, '/o': behind}).line()
    assert text.count('unsynchronised') == 2


def test_different_frames_fail():
    a = stream_stats('/f', *_stream(), ['world'] * 200)
    b = stream_stats('/o', *_stream(), ['optitrack'] * 200)
    assert 'different frames' in mocap_verdict({'/f': a, '/o': b}).line()


def test_stamps_that_do_not_advance_fall_back_to_arrivals():
    recv, _ = _stream(period_ms=8.0)
    s = stream_stats('/f', recv, recv * 0)
    assert s.rate_hz == pytest.approx(125.0)


@pytest.mark.ros
def test_listener_reports_the_published_rate(rclpy_context):
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from aslip_ros.nodes.mocap_check import MocapCheck
    import rclpy
    topics = ['/aslip_test/finger', '/aslip_test/object']
    node = MocapCheck(topics, context=rclpy_context)
    talker = rclpy.create_node('aslip_test_talker', context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    executor.add_node(talker)
    # One publisher reliable, one best effort: the check listens to both kinds.
    pubs = [talker.create_publisher(PoseStamped, topics[0], QoSProfile(depth=100)),
            talker.create_publisher(PoseStamped, topics[1], QoSProfile(
                depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))]
    deadline = time.monotonic() + 30.0
    while any(p.get_subscription_count() == 0 for p in pubs):
        assert time.monotonic() < deadline, 'the listener was never discovered'
        executor.spin_once(timeout_sec=0.05)
    start = talker.get_clock().now().nanoseconds
    n = 120
    for k in range(n):
        for p in pubs:
            msg = PoseStamped()
            ns = start + k * 10 * MS            # stamps at 100 Hz, the mocap's own clock
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
            msg.header.frame_id = 'world'
            msg.pose.orientation.w = 1.0
            p.publish(msg)
        executor.spin_once(timeout_sec=0.0)
    while node.count() < 2 * n * 0.9 and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    samples = node.samples()
    executor.shutdown()
    node.destroy_node()
    talker.destroy_node()
    for topic in topics:
        s = stream_stats(topic, *samples[topic])
        assert s.count >= n // 2, s
        assert s.rate_hz == pytest.approx(100.0, rel=1e-6)
        assert s.frame_ids == ('world',)
        assert s.latency_median_s > -1.0        # received on the same clock
