"""Child process: record topics from a live ROS graph into an mcap rosbag2 bag.

A stand-in for `ros2 bag record` (not installable from PyPI): subscribes with raw=True, so
the serialized CDR bytes go to the bag unchanged, with the receive time as log time.
Stops on SIGINT/SIGTERM and closes the bag.
"""

import signal
import sys

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import StoragePlugin, Writer

from aslip_ros.data.bags import typestore
from aslip_ros.msg import AudioFrame

TOPICS = {"/aslip/audio": (AudioFrame, "aslip_ros/msg/AudioFrame"),
          "/aslip/mocap/finger": (PoseStamped, "geometry_msgs/msg/PoseStamped"),
          "/aslip/mocap/object": (PoseStamped, "geometry_msgs/msg/PoseStamped")}


def main() -> int:
    out = sys.argv[1]
    rclpy.init()
    node = rclpy.create_node("aslip_raw_recorder")
    store = typestore()
    writer = Writer(out, version=8, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
    counts = {}
    for topic, (cls, name) in TOPICS.items():
        conn = writer.add_connection(topic, name, typestore=store)

        def cb(raw, conn=conn, topic=topic):
            writer.write(conn, node.get_clock().now().nanoseconds, raw)
            counts[topic] = counts.get(topic, 0) + 1
        node.create_subscription(cls, topic, cb, qos, raw=True)
    stop = []
    signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
    signal.signal(signal.SIGINT, lambda *a: stop.append(1))
    print("recorder ready", flush=True)
    while not stop:
        rclpy.spin_once(node, timeout_sec=0.05)
    writer.close()
    print("recorded", counts, flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
