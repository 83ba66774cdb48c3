"""Child process: the drivers a hardware trial records, one stream of which may stop.

    python driver_standin.py TOPIC [TOPIC ...] [--audio TOPIC]
        [--stop TOPIC --stop-after-s S --subscribers N [--readers-of TOPIC] [--heard-by N]]

Publishes ``geometry_msgs/PoseStamped`` (sensor-data QoS, frame ``mocap``, a still pose) on
every TOPIC at 120 Hz (on average, however late the loop wakes), like a motion-capture
driver whose rigid bodies are tracked, and with ``--audio`` an audio interface's
``aslip_ros/AudioFrame`` stream on that topic (16 kHz, 4 channels of quiet noise, 10 ms
blocks in real time; ``audio_capture source:=topic`` bridges it). ``--stop TOPIC`` stops
that one stream ``--stop-after-s`` after ``--readers-of`` (default: the stopped topic
itself) has ``--subscribers`` matched readers, the recording graph being up and reading it
(and, with ``--heard-by N``, once N nodes' diagnostics on /aslip/diagnostics count messages
received on it: a reader in the graph is not yet a reader matched to the writer, and a busy
machine can match it seconds later), printing ``stopped TOPIC at <time.time()>``; the
process stays up, like a driver that lost a rigid body or an interface that stalled. Exits
on SIGINT/SIGTERM and when its parent goes.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import signal
import time

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import String

from aslip_ros import topics
from aslip_ros.msg import AudioFrame
from aslip_ros.nodes.convert import audio_to_msg

RATE_HZ = 120.0
#: The audio stream: what a cell bridging it declares (sample_rate, channel_names).
AUDIO_RATE_HZ = 16000
AUDIO_CHANNELS = ("m0", "m1", "m2", "m3")
AUDIO_BLOCK = 160


def _pose(topic: str, first: str, now: float) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = "mocap"
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(now), int(now % 1 * 1e9)
    msg.pose.position.x = 0.4 if topic == first else 0.45
    msg.pose.orientation.w = 1.0
    return msg


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("topics", nargs="+")
    p.add_argument("--audio", default="")
    p.add_argument("--stop", default="")
    p.add_argument("--stop-after-s", type=float, default=1.0)
    p.add_argument("--subscribers", type=int, default=1)
    p.add_argument("--readers-of", default="")
    p.add_argument("--heard-by", type=int, default=0)
    a = p.parse_args()
    ctypes.CDLL(None).prctl(1, signal.SIGTERM)      # PR_SET_PDEATHSIG: die with the test
    rclpy.init()
    node = rclpy.create_node("driver_standin")
    pubs = {t: node.create_publisher(PoseStamped, t, qos_profile_sensor_data)
            for t in a.topics}
    if a.audio:
        pubs[a.audio] = node.create_publisher(AudioFrame, a.audio, qos_profile_sensor_data)
    readers_of = a.readers_of or a.stop
    heard: set = set()      # the nodes whose diagnostics count messages on readers_of

    def on_diagnostics(msg: String) -> None:
        doc = json.loads(msg.data)
        if int(doc.get("values", {}).get(f"messages {readers_of}", 0)) > 0:
            heard.add(doc["name"])
    if a.heard_by:
        node.create_subscription(String, topics.DIAGNOSTICS_JSON, on_diagnostics, 50)
    rng = np.random.default_rng(0)
    started, sent, posed = time.monotonic(), 0, 0
    stop_at = None
    print("standin ready", flush=True)
    try:
        while rclpy.ok():
            now = time.time()
            rclpy.spin_once(node, timeout_sec=0.0)
            if a.stop in pubs and stop_at is None and len(heard) >= a.heard_by and \
                    node.count_subscribers(readers_of) >= a.subscribers:
                stop_at = time.monotonic() + a.stop_after_s
            if stop_at is not None and time.monotonic() >= stop_at and a.stop in pubs:
                node.destroy_publisher(pubs.pop(a.stop))
                print(f"stopped {a.stop} at {now:.3f}", flush=True)
            # Paced by the clock, not by the loop: a loaded machine wakes the loop late,
            # and the driver catches up so that every second holds RATE_HZ poses.
            while posed < int((time.monotonic() - started) * RATE_HZ) + 1:
                for topic, pub in pubs.items():
                    if topic != a.audio:
                        pub.publish(_pose(topic, a.topics[0], now))
                posed += 1
            due = int((time.monotonic() - started) * AUDIO_RATE_HZ) // AUDIO_BLOCK
            while a.audio in pubs and sent < due:
                block = 0.01 * rng.standard_normal((AUDIO_BLOCK, len(AUDIO_CHANNELS)))
                pubs[a.audio].publish(audio_to_msg(sent * AUDIO_BLOCK, time.time_ns(),
                                                   AUDIO_RATE_HZ, AUDIO_CHANNELS, block))
                sent += 1
            time.sleep(1.0 / RATE_HZ)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
