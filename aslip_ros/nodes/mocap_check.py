"""The ROS part of ``aslip check mocap``: listen to the finger and object PoseStamped topics
for a while and keep, per message, its receive time, header stamp and frame id.

The statistics and the verdict are ROS-free (:mod:`aslip_ros.bringup.mocap_stats`). The
subscriptions are best effort (``SENSOR_QOS``, what the mocap drivers offer), which also
matches reliable publishers; their queue is deep so that a slow spin here is not what
shows as a dropout.
"""

from __future__ import annotations

import threading
import time
from typing import Dict, List, Optional, Tuple

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions

from aslip_ros.audio_frame import stamp_to_ns
from aslip_ros.nodes import common as c

#: Per topic: (receive times [ns], header stamps [ns], frame ids), in arrival order.
Samples = Tuple[List[int], List[int], List[str]]

QUEUE_DEPTH = 1000


class MocapCheck(Node):
    """Records the arrivals on each of ``topics``."""

    def __init__(self, topics: List[str], **kwargs) -> None:
        """Subscribe to every topic (best effort, deep queue)."""
        super().__init__('aslip_mocap_check', **kwargs)
        self._lock = threading.Lock()
        self._samples: Dict[str, Samples] = {t: ([], [], []) for t in topics}
        qos = QoSProfile(history=c.SENSOR_QOS.history, depth=QUEUE_DEPTH,
                         reliability=c.SENSOR_QOS.reliability,
                         durability=c.SENSOR_QOS.durability)
        for topic in topics:
            self.create_subscription(PoseStamped, topic,
                                     lambda msg, t=topic: self._on_pose(t, msg), qos)

    def _on_pose(self, topic: str, msg: PoseStamped) -> None:
        now = self.get_clock().now().nanoseconds
        with self._lock:
            recv, stamps, frames = self._samples[topic]
            recv.append(int(now))
            stamps.append(stamp_to_ns(msg.header.stamp))
            frames.append(msg.header.frame_id)

    def samples(self) -> Dict[str, Samples]:
        """A copy of what arrived so far."""
        with self._lock:
            return {t: (list(r), list(s), list(f)) for t, (r, s, f) in self._samples.items()}

    def count(self) -> int:
        """Messages received on all topics together."""
        with self._lock:
            return sum(len(r) for r, _, _ in self._samples.values())


def record(topics: List[str], seconds: float, context: Optional[object] = None
           ) -> Dict[str, Samples]:
    """Listen to ``topics`` for ``seconds`` of wall time and return what arrived.

    Without ``context`` rclpy is initialised here (its own SIGINT handling off, so Ctrl-C
    is a plain ``KeyboardInterrupt``) and shut down again.
    """
    own = context is None
    if own:
        from rclpy.context import Context
        context = Context()
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = MocapCheck(list(topics), context=context)
        from rclpy.executors import SingleThreadedExecutor
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + float(seconds)
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))
        executor.remove_node(node)
        return node.samples()
    finally:
        if node is not None:
            node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)
