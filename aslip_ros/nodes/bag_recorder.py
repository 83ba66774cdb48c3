"""``bag_recorder``: record topics to a rosbag2 (mcap) bag without rosbag2.

``ros2 bag`` is not installable everywhere (it is no wheel); this node records the same way
for ``data_collection.launch.py recorder:=aslip``: every topic in ``topics`` is subscribed
as soon as a publisher appears, with the type and durability the publisher offers, and each
message's serialized bytes are written as received (no decoding), stamped with the time of
receipt like ``ros2 bag record``. The bag is written through the project's
:class:`aslip_ros.data.bag_writer.BagWriter` (typestore, offered-QoS records, atomic directory):
it appears at ``output`` only when the node shuts down cleanly.
"""

from __future__ import annotations

import importlib
import threading
from typing import Optional

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from aslip_ros import topics
from aslip_ros.data import bags
from aslip_ros.data.bag_writer import BagWriter
from aslip_ros.nodes import common as c

#: What ``data_collection.launch.py`` records: the recording contract plus TF.
DEFAULT_TOPICS = [c.AUDIO_TOPIC, c.FINGER_TOPIC, c.OBJECT_TOPIC, c.TCP_TOPIC,
                  c.METADATA_TOPIC, c.SLIP_TRUTH_TOPIC, topics.TF, topics.TF_STATIC]


class RawBagWriter(BagWriter):
    """A :class:`BagWriter` that also takes already-serialized CDR messages."""

    def write_raw(self, topic: str, msgtype: str, data: bytes, log_ns: int,
                  qos: str = "reliable") -> None:
        """Append serialized ``data`` of ``msgtype`` on ``topic`` at ``log_ns``."""
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self._store,
                                               offered_qos_profiles=bags._qos(qos))
            self._conns[topic] = conn
        self._writer.write(conn, int(log_ns), bytes(data))


def _topic_list(v) -> Optional[str]:
    names = list(v)
    if not names or any(not str(n).startswith("/") for n in names):
        return f"must be a non-empty list of absolute topic names, got {names}"
    return None


def message_class(type_name: str):
    """The Python class of ``pkg/msg/Name``; raises ImportError when it is not installed."""
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class Recorder(Node):
    """Subscribes to the requested topics as they appear and writes what arrives."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("bag_recorder", **kwargs)
        specs = [
            c.Param("output", "aslip_bag", "bag directory to create (rosbag2, mcap)",
                    c.non_empty, read_only=True),
            c.Param("topics", list(DEFAULT_TOPICS), "topics to record", _topic_list,
                    read_only=True),
            c.Param("overwrite", False, "replace an existing bag at output", read_only=True),
            c.Param("discovery_period_s", 0.2, "look for new publishers this often [s]",
                    c.in_range(0.01, 10.0), read_only=True),
        ]
        self.p = c.declare_params(self, specs)
        try:
            self.writer = RawBagWriter(self.p["output"], overwrite=bool(self.p["overwrite"]))
            self.writer.__enter__()
        except (bags.BagError, OSError) as exc:
            raise c.ConfigError(f"cannot record to {self.p['output']}: {exc}") from exc
        self._lock = threading.Lock()
        self._closed = False
        self._subs: dict = {}
        self.counts: dict = {}
        self.refused: dict = {}
        self.diag = c.Diagnostics(self, "aslip: bag_recorder", self.p["output"])
        self.create_timer(self.p["discovery_period_s"], self._discover)
        self.create_timer(1.0, self._diagnose)
        self._discover()
        c.ready(self, f"recording {len(self.p['topics'])} topics to {self.p['output']}")

    def _discover(self) -> None:
        available = dict(self.get_topic_names_and_types())
        for topic in self.p["topics"]:
            if topic in self._subs or topic in self.refused or topic not in available:
                continue
            type_name = available[topic][0]
            if type_name not in self.writer._store.types:
                self._refuse(topic, f"type {type_name} has no definition to record")
                continue
            try:
                cls = message_class(type_name)
            except (ImportError, AttributeError, ValueError) as exc:
                self._refuse(topic, f"type {type_name} is not importable ({exc})")
                continue
            latched = any(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                          for i in self.get_publishers_info_by_topic(topic))
            kind = "latched" if latched else "sensor"
            # Best effort receives from reliable and best-effort publishers alike; latched
            # topics need a reliable, transient-local reader to get the last message.
            qos = QoSProfile(
                history=HistoryPolicy.KEEP_LAST, depth=1000,
                reliability=ReliabilityPolicy.RELIABLE if latched
                else ReliabilityPolicy.BEST_EFFORT,
                durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                else DurabilityPolicy.VOLATILE)
            self._subs[topic] = self.create_subscription(
                cls, topic, self._writer_for(topic, type_name, kind), qos, raw=True)
            self.counts[topic] = 0
            self.get_logger().info(f"recording {topic} ({type_name})")

    def _refuse(self, topic: str, why: str) -> None:
        self.refused[topic] = why
        self.get_logger().error(f"not recording {topic}: {why}")

    def _writer_for(self, topic: str, type_name: str, kind: str):
        def write(data: bytes) -> None:
            with self._lock:
                if self._closed:
                    return
                self.writer.write_raw(topic, type_name, data,
                                      self.get_clock().now().nanoseconds, kind)
                self.counts[topic] += 1
        return write

    def _diagnose(self) -> None:
        missing = [t for t in self.p["topics"] if t not in self._subs]
        level = c.Diagnostics.ERROR if self.refused else \
            c.Diagnostics.WARN if missing else c.Diagnostics.OK
        msg = "recording" + (f"; no publisher yet on {', '.join(missing)}" if missing else "")
        values = {f"messages {t}": n for t, n in self.counts.items()}
        values.update({f"refused {t}": why for t, why in self.refused.items()})
        self.diag.publish(level, msg, values)

    def before_shutdown(self) -> None:
        """Close the bag: it appears at ``output`` now."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self.writer.__exit__(None, None, None)
        total = sum(self.counts.values())
        self.get_logger().info(f"bag written to {self.p['output']}: {total} messages "
                               f"({', '.join(f'{t} {n}' for t, n in self.counts.items())})")


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros bag_recorder``."""
    return c.run_node(Recorder, args)


if __name__ == "__main__":
    raise SystemExit(main())
