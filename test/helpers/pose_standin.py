"""Child process: a motion-capture driver's pose streams, one of which may stop mid-trial.

    python pose_standin.py TOPIC [TOPIC ...] [--stop TOPIC --stop-after-s S --subscribers N]

Publishes ``geometry_msgs/PoseStamped`` (sensor-data QoS, frame ``mocap``, a still pose)
on every TOPIC at 120 Hz, like a driver whose rigid bodies are tracked. ``--stop TOPIC``
stops that one stream ``--stop-after-s`` after it has ``--subscribers`` matched readers
(the recording graph is up and has seen it), printing ``stopped TOPIC at <time.time()>``;
the process stays up, like a driver that lost a rigid body. Exits on SIGINT/SIGTERM and
when its parent goes.
"""

from __future__ import annotations

import argparse
import ctypes
import signal
import time

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.qos import qos_profile_sensor_data

RATE_HZ = 120.0


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("topics", nargs="+")
    p.add_argument("--stop", default="")
    p.add_argument("--stop-after-s", type=float, default=1.0)
    p.add_argument("--subscribers", type=int, default=1)
    a = p.parse_args()
    ctypes.CDLL(None).prctl(1, signal.SIGTERM)      # PR_SET_PDEATHSIG: die with the test
    rclpy.init()
    node = rclpy.create_node("pose_standin")
    pubs = {t: node.create_publisher(PoseStamped, t, qos_profile_sensor_data)
            for t in a.topics}
    stop_at = None
    print("standin ready", flush=True)
    try:
        while rclpy.ok():
            now = time.time()
            if a.stop in pubs and stop_at is None and \
                    pubs[a.stop].get_subscription_count() >= a.subscribers:
                stop_at = time.monotonic() + a.stop_after_s
            if stop_at is not None and time.monotonic() >= stop_at and a.stop in pubs:
                node.destroy_publisher(pubs.pop(a.stop))
                print(f"stopped {a.stop} at {now:.3f}", flush=True)
            for topic, pub in pubs.items():
                msg = PoseStamped()
                msg.header.frame_id = "mocap"
                msg.header.stamp.sec, msg.header.stamp.nanosec = int(now), int(now % 1 * 1e9)
                msg.pose.position.x = 0.4 if topic == a.topics[0] else 0.45
                msg.pose.orientation.w = 1.0
                pub.publish(msg)
            time.sleep(1.0 / RATE_HZ)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
