"""The ROS part of ``aslip check mocap``: listen to the finger and object PoseStamped topics
for a while and keep, per message, its receive time, header stamp and frame id; or, for
mocap4r2's drivers, to one RigidBodies topic, keeping the same per chosen body (picked by
:func:`aslip_ros.rigid_bodies.select_bodies`, which also counts the messages that lack it).

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
from rclpy.signals import SignalHandlerOptions

from aslip_ros.audio_frame import stamp_to_ns
from aslip_ros.runtime.qos import READER_DEPTH, SENSOR_QOS, deeper
from aslip_ros.rigid_bodies import BodyTally, select_bodies

#: Per topic: (receive times [ns], header stamps [ns], frame ids), in arrival order.
Samples = Tuple[List[int], List[int], List[str]]


class MocapCheck(Node):
    """Records the arrivals on each of ``topics``."""

    def __init__(self, topics: List[str], rigid_bodies: Optional[Tuple[str, dict]] = None,
                 **kwargs) -> None:
        """Subscribe to every PoseStamped topic of ``topics``, and with ``rigid_bodies``
        (``(topic, {"finger": body, "object": body})``) to that RigidBodies topic (best
        effort, deep queue)."""
        super().__init__('aslip_mocap_check', **kwargs)
        self._lock = threading.Lock()
        self._samples: Dict[str, Samples] = {t: ([], [], []) for t in topics}
        qos = deeper(SENSOR_QOS, READER_DEPTH)
        for topic in topics:
            self.create_subscription(PoseStamped, topic,
                                     lambda msg, t=topic: self._on_pose(t, msg), qos)
        self.bodies: dict = {}
        #: Stream name of each chosen body (the keys of :meth:`samples`).
        self.streams: Dict[str, str] = {}
        if rigid_bodies is not None:
            topic, self.bodies = rigid_bodies[0], dict(rigid_bodies[1])
            self.streams = {r: body_stream(topic, r, b) for r, b in self.bodies.items()}
            self._samples.update({s: ([], [], []) for s in self.streams.values()})
            from aslip_ros.nodes.convert import rigid_bodies_class
            self.create_subscription(rigid_bodies_class(), topic, self._on_rigid_bodies, qos)
        self.tally = BodyTally(self.bodies)

    def _on_rigid_bodies(self, msg) -> None:
        now = self.get_clock().now().nanoseconds
        sel = select_bodies(msg, self.bodies)
        with self._lock:
            self.tally.add(sel)
            for role in sel.poses:
                recv, stamps, frames = self._samples[self.streams[role]]
                recv.append(int(now))
                stamps.append(sel.stamp_ns)
                frames.append(sel.frame_id)

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

    def missing_bodies(self) -> str:
        """Which chosen bodies were missing from how many RigidBodies ('' when none was)."""
        with self._lock:
            return self.tally.text()


def body_stream(topic: str, role: str, body: str) -> str:
    """The name a chosen body's stream goes by in the check's report."""
    return f"{topic} body {body!r} ({role})"


def record(topics: List[str], seconds: float, context: Optional[object] = None
           ) -> Dict[str, Samples]:
    """Listen to ``topics`` for ``seconds`` of wall time and return what arrived.

    Without ``context`` rclpy is initialised here (its own SIGINT handling off, so Ctrl-C
    is a plain ``KeyboardInterrupt``) and shut down again.
    """
    return _listen(list(topics), None, seconds, context)[0]


def record_bodies(topic: str, bodies: dict, seconds: float,
                  context: Optional[object] = None) -> Tuple[Dict[str, Samples], str]:
    """Listen to the RigidBodies on ``topic`` for ``seconds`` (as :func:`record`) and return
    what arrived per chosen body (``bodies``: role -> name or ID; the streams named by
    :func:`body_stream`) and which bodies were missing from how many messages ('' when
    none was)."""
    return _listen([], (topic, bodies), seconds, context)


def _listen(topics: List[str], rigid_bodies: Optional[Tuple[str, dict]], seconds: float,
            context: Optional[object]) -> Tuple[Dict[str, Samples], str]:
    own = context is None
    if own:
        from rclpy.context import Context
        context = Context()
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = MocapCheck(list(topics), rigid_bodies, context=context)
        from rclpy.executors import SingleThreadedExecutor
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + float(seconds)
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))
        executor.remove_node(node)
        return node.samples(), node.missing_bodies()
    finally:
        if node is not None:
            node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)
