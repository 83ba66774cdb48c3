"""Child process: publish the sample AudioFrame and SlipVector until terminated."""

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy

from aslip_ros.msg import AudioFrame, SlipVector
from aslip_samples import fill


def main() -> int:
    rclpy.init()
    node = rclpy.create_node("aslip_sample_publisher")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pubs = [(node.create_publisher(AudioFrame, "/aslip/audio", qos), fill(AudioFrame())),
            (node.create_publisher(SlipVector, "/aslip/slip", qos), fill(SlipVector()))]
    print("publisher ready", flush=True)

    def tick():
        for pub, msg in pubs:
            pub.publish(msg)

    node.create_timer(0.05, tick)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
