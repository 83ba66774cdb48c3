"""Child process: a live rclpy graph like other hardware would produce.

44.1 kHz two-channel audio with channel names unlike the scene's, 100 Hz motion capture of
a finger and an object, no scenario metadata. The object slides along the finger's +x at
SLIP_SPEED m/s between SLIP_T0 and SLIP_T1 seconds (finger frame rotated 90 deg about z in
world, so world-frame motion differs from grasp-plane motion).
"""

import math
import sys
import time

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.qos import qos_profile_sensor_data

from aslip_ros.msg import AudioFrame

RATE = 44100.0
BLOCK = 441
MOCAP_HZ = 100.0
SLIP_SPEED = 0.02
SLIP_T0, SLIP_T1 = 0.8, 2.2
DURATION = 3.0
# Finger frame: rotated +90 deg about world z, so finger +x points along world +y.
Q_FINGER = (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4))


def object_offset(t: float) -> float:
    """Displacement of the object along the finger's x [m] at time t since start."""
    return SLIP_SPEED * (min(max(t, SLIP_T0), SLIP_T1) - SLIP_T0)


def main() -> int:
    rclpy.init()
    node = rclpy.create_node("aslip_live_publisher")
    audio_pub = node.create_publisher(AudioFrame, "/aslip/audio", qos_profile_sensor_data)
    finger_pub = node.create_publisher(PoseStamped, "/aslip/mocap/finger",
                                       qos_profile_sensor_data)
    object_pub = node.create_publisher(PoseStamped, "/aslip/mocap/object",
                                       qos_profile_sensor_data)
    rng = np.random.default_rng(0)
    print("publisher ready", flush=True)
    # Data flows only once the recorder has matched every topic (discovery is slow on a
    # loaded machine), so the bag holds the whole motion.
    deadline = time.monotonic() + (float(sys.argv[1]) if len(sys.argv) > 1 else 30.0)
    while any(p.get_subscription_count() == 0 for p in (audio_pub, finger_pub, object_pub)):
        if time.monotonic() > deadline:
            print("no recorder matched", flush=True)
            return 1
        time.sleep(0.05)
    time.sleep(0.2)
    t0 = time.monotonic()
    start_ns = node.get_clock().now().nanoseconds
    sent_frames = 0
    next_mocap = 0.0
    while True:
        t = time.monotonic() - t0
        if t > DURATION:
            break
        while sent_frames / RATE <= t:
            msg = AudioFrame()
            stamp_ns = start_ns + int(sent_frames / RATE * 1e9)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
            msg.header.frame_id = "my_gripper"
            msg.sample_rate = RATE
            msg.channel_names = ["jaw_a", "jaw_b"]
            msg.first_sample_index = sent_frames
            msg.data = (0.01 * rng.standard_normal(BLOCK * 2)).astype(np.float32).tolist()
            audio_pub.publish(msg)
            sent_frames += BLOCK
        while next_mocap <= t:
            stamp_ns = start_ns + int(next_mocap * 1e9)
            for pub, y in ((finger_pub, 0.0), (object_pub, object_offset(next_mocap))):
                p = PoseStamped()
                p.header.stamp.sec, p.header.stamp.nanosec = divmod(stamp_ns, 10**9)
                p.header.frame_id = "world"
                # finger +x is world +y
                p.pose.position.x, p.pose.position.y, p.pose.position.z = 0.4, 0.1 + y, 0.3
                (p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z,
                 p.pose.orientation.w) = Q_FINGER
                pub.publish(p)
            next_mocap += 1.0 / MOCAP_HZ
        time.sleep(0.002)
    print("publisher done", flush=True)
    time.sleep(0.5)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
