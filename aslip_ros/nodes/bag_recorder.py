"""``bag_recorder``: record topics to a rosbag2 (mcap) bag without rosbag2.

``ros2 bag`` is not installable everywhere (it is no wheel); this node records the same way
for ``data_collection.launch.py recorder:=aslip``. Each message's serialized bytes are
written as received (no decoding), stamped with the time of receipt like ``ros2 bag
record``. The bag is written through the project's
:class:`aslip_ros.data.bag_writer.BagWriter` (typestore, offered-QoS records, atomic
directory): it appears at ``output`` only when the node shuts down cleanly.

When each topic is subscribed, and with which QoS:

- the latched topics of the contract (``LATCHED``: ``/aslip/metadata``, ``/tf_static``) at
  once, before any publisher exists, reliable and transient-local with a deep queue: a
  latched message reaches the bag whichever starts first, recorder or publisher, and
  however many publishers latch one (each keeps its own last message);
- the contract's streams (``STREAMS``: audio, poses, slip truth, /tf) at once too, with
  their documented types and reliability: a reader that waits for discovery to name them
  starts the recording late (1.3 s of a 3 s scene run was lost that way);
- any other topic (a motion-capture driver's own, say) once a *publisher* of it is seen (a
  subscriber alone names the topic but says nothing of the QoS to use), with the QoS every
  publisher can serve: reliable only where all of them are, transient-local only where all
  of them are; ``pose_topics`` names PoseStamped streams of a driver's own, and
  ``rigid_bodies_topics`` mocap4r2 RigidBodies streams, to subscribe at once like the
  contract's.

A type that the project's definitions lack (a driver's: ``mocap4r2_msgs/msg/RigidBodies``)
is recorded with the definition of its installed package, as ``ros2 bag record`` does.

``duration_s`` ends a recording by itself (the node exits 0) that long after every one of
``duration_topics`` (the audio and the poses, on a cell) has delivered a message: a
hardware trial is as long as asked with all its streams, however long the nodes and
discovery took to start (measured: a pose stream 2 s late); and not before the latched
topics that a publisher serves, or that ``latched_due`` names, have delivered (at most
``LATCHED_GRACE_S`` more, then a warning). ``latched_due`` is for a publisher the recorder
may not have discovered yet: under load, a fresh-clone CI run closed a 3 s trial's bag with
no sign of mocap_bridge's /tf_static publisher.

Subscribing to a latched topic on the strength of a subscriber alone (mocap_bridge reads
the metadata) made the reader volatile and best effort: a metadata message published
before the match never reached the bag (``test_nodes_bag_recorder.py``).
"""

from __future__ import annotations

import dataclasses
import importlib
import threading
import time
from typing import Optional

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

from aslip_ros import topics
from aslip_ros.data import bags
from aslip_ros.data.bag_format import add_installed_types, project_store
from aslip_ros.data.bag_writer import BagWriter
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import ConfigError, ready, run_node
from aslip_ros.runtime.qos import reader_qos
from aslip_ros.rigid_bodies import RIGID_BODIES_TYPE

#: What ``data_collection.launch.py`` records: the recording contract (the topics of
#: :data:`aslip_ros.data.bags.DEFAULT_TOPICS`, which export reads) plus TF.
RECORDED_TOPICS = list(dataclasses.astuple(bags.DEFAULT_TOPICS)) + [topics.TF,
                                                                    topics.TF_STATIC]

TF_TYPE = "tf2_msgs/msg/TFMessage"

#: The contract's latched topics and their types: subscribed before any publisher appears.
LATCHED = {topics.METADATA: bags.STRING_TYPE, topics.TF_STATIC: TF_TYPE}
#: How long past ``duration_s`` a timed recording waits for a latched message that is owed
#: and has not reached it yet [s] (``Recorder._latched_owed``). Fresh-clone CI runs closed
#: a 3 s trial's bag without /tf_static, whose match came after the trial's end.
LATCHED_GRACE_S = 10.0

#: The contract's other topics: type and whether their publishers are reliable
#: (docs/design.md, "Topics"). Subscribed at start too: waiting for discovery to name them
#: lost the first 1.3 s of a recording started before the scene (discovery's delay).
#: Streams are read best effort, which every publisher serves, whatever a driver offers.
STREAMS = {topics.AUDIO: (bags.AUDIO_TYPE, False), topics.FINGER: (bags.POSE_TYPE, False),
           topics.OBJECT: (bags.POSE_TYPE, False), topics.TCP: (bags.POSE_TYPE, False),
           topics.SLIP_TRUTH: (bags.SLIP_TYPE, True), topics.TF: (TF_TYPE, True)}


def record_topics(finger: str = topics.FINGER, object_: str = topics.OBJECT) -> list:
    """What ``data_collection.launch.py`` records when the poses come on ``finger`` and
    ``object_`` (a motion-capture driver's own names): :data:`RECORDED_TOPICS` with those."""
    swap = {topics.FINGER: finger, topics.OBJECT: object_}
    # One topic may carry both bodies (mocap4r2's RigidBodies): recorded once.
    return list(dict.fromkeys(swap.get(t, t) for t in RECORDED_TOPICS))


def qos_for_publishers(infos) -> Optional[tuple]:
    """``(latched, reliable)`` that every publisher in ``infos`` (``TopicEndpointInfo``) can
    serve, or None while there is none (the topic is only known from a subscriber)."""
    if not infos:
        return None
    latched = all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                  for i in infos)
    reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
    return latched, reliable


class RawBagWriter(BagWriter):
    """A :class:`BagWriter` that also takes already-serialized CDR messages."""

    def write_raw(self, topic: str, msgtype: str, data: bytes, log_ns: int,
                  qos: str = "reliable") -> None:
        """Append serialized ``data`` of ``msgtype`` on ``topic`` at ``log_ns``."""
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self._store,
                                               offered_qos_profiles=bags.offered_qos(qos))
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
            c.Param("topics", list(RECORDED_TOPICS), "topics to record", _topic_list,
                    read_only=True),
            c.Param("pose_topics", [""], "PoseStamped streams among topics, subscribed at "
                    "start like the contract's (a mocap driver's own names; '' = none)",
                    read_only=True),
            c.Param("rigid_bodies_topics", [""], "mocap4r2 RigidBodies streams among topics, "
                    "subscribed at start like the contract's ('' = none)", read_only=True),
            c.Param("duration_s", 0.0, "end the recording duration_s after every one of "
                    "duration_topics has delivered a message [s], then exit; 0 = until "
                    "stopped", c.in_range(0.0, 86400.0), read_only=True),
            c.Param("duration_topics", [topics.AUDIO], "the streams duration_s waits for",
                    _topic_list, read_only=True),
            c.Param("latched_due", [""], "latched topics among topics that a timed recording "
                    f"waits for past duration_s (at most {LATCHED_GRACE_S:g} s), its publisher "
                    "seen or not ('' = none: only those a publisher is seen to serve)",
                    read_only=True),
            c.Param("overwrite", False, "replace an existing bag at output", read_only=True),
            c.Param("discovery_period_s", 0.2, "look for new publishers this often [s]",
                    c.in_range(0.01, 10.0), read_only=True),
        ]
        self.p = c.declare_params(self, specs)
        self.due = [t for t in self.p["latched_due"] if t]
        stray = [t for t in self.due if t not in LATCHED or t not in self.p["topics"]]
        if stray:
            raise ConfigError(f"latched_due: {', '.join(stray)} is not a latched topic among "
                              f"topics (latched: {', '.join(LATCHED)})")
        self.streams = dict(STREAMS, **{t: (bags.POSE_TYPE, False)
                                        for t in self.p["pose_topics"] if t})
        self.streams.update({t: (RIGID_BODIES_TYPE, False)
                             for t in self.p["rigid_bodies_topics"] if t})
        try:
            # A store of its own: a driver's types are added to it as they are met.
            self.writer = RawBagWriter(self.p["output"], overwrite=bool(self.p["overwrite"]),
                                       store=project_store())
            self.writer.__enter__()
        except (bags.BagError, OSError) as exc:
            raise ConfigError(f"cannot record to {self.p['output']}: {exc}") from exc
        self._lock = threading.Lock()
        self._closed = False
        self.done = False
        self._waiting = set(self.p["duration_topics"])   # not delivered yet
        self._start: Optional[float] = None    # when the last of them did (monotonic)
        self._subs: dict = {}
        self.counts: dict = {}
        self.refused: dict = {}
        self.diag = c.Diagnostics(self, "aslip: bag_recorder", self.p["output"])
        self.create_timer(self.p["discovery_period_s"], self._discover)
        self.create_timer(1.0, self._diagnose)
        self._discover()
        ready(self, f"recording {len(self.p['topics'])} topics to {self.p['output']}")

    def _discover(self) -> None:
        available = None
        for topic in self.p["topics"]:
            if topic in self._subs or topic in self.refused:
                continue
            if topic in LATCHED:
                self._subscribe(topic, LATCHED[topic], latched=True, reliable=True)
                continue
            if topic in self.streams:
                self._subscribe(topic, self.streams[topic][0], False, self.streams[topic][1])
                continue
            if available is None:
                available = dict(self.get_topic_names_and_types())
            if topic not in available:
                continue
            serve = qos_for_publishers(self.get_publishers_info_by_topic(topic))
            if serve is None:
                continue            # only subscribers so far: wait for a publisher
            self._subscribe(topic, available[topic][0], *serve)

    def _subscribe(self, topic: str, type_name: str, latched: bool, reliable: bool) -> None:
        if not add_installed_types(self.writer._store, type_name):
            self._refuse(topic, f"type {type_name} has no definition to record (its "
                         "package is not installed)")
            return
        try:
            cls = message_class(type_name)
        except (ImportError, AttributeError, ValueError) as exc:
            self._refuse(topic, f"type {type_name} is not importable ({exc})")
            return
        kind = "latched" if latched else "reliable" if reliable else "sensor"
        self._subs[topic] = self.create_subscription(
            cls, topic, self._writer_for(topic, type_name, kind),
            reader_qos(latched, reliable), raw=True)
        self.counts[topic] = 0
        self.get_logger().info(f"recording {topic} ({type_name}, {kind})")

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
                if self.p["duration_s"] > 0:
                    self._count_duration(topic)
        return write

    def _count_duration(self, topic: str) -> None:
        """Called with ``_lock`` held: the recording is done ``duration_s`` after the last of
        ``duration_topics`` delivered its first message (not after the start: the nodes and
        discovery take their time, and a trial gets its full length with every stream)."""
        now = time.monotonic()
        if self._start is None:
            self._waiting.discard(topic)
            if not self._waiting:
                self._start = now
                self.get_logger().info(f"every stream of {self.p['duration_topics']} is in: "
                                       f"recording {self.p['duration_s']:g} s")
        elif not self.done and now - self._start >= self.p["duration_s"]:
            owed = self._latched_owed()
            late = now - self._start - self.p["duration_s"]
            if owed and late < LATCHED_GRACE_S:
                return              # a latched message still on its way: not done yet
            if owed:
                self.get_logger().warning(
                    f"recorded {self.p['duration_s']:g} s, but {', '.join(owed)} never "
                    f"delivered within {LATCHED_GRACE_S:g} s more although published")
            self.done = True
            self.get_logger().info(f"recorded {self.p['duration_s']:g} s: done")

    def _latched_owed(self) -> list:
        """The latched topics subscribed at start that have delivered nothing yet and are
        owed: ``latched_due`` names them, or a transient-local publisher is seen to serve
        them (matched late, under load). A timed recording waits for them, at most
        ``LATCHED_GRACE_S``, so its bag does not close without the metadata or the static
        transforms that were published."""
        return [t for t in LATCHED if t in self._subs and not self.counts.get(t)
                and (t in self.due or any(
                    i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                    for i in self.get_publishers_info_by_topic(t)))]

    def _diagnose(self) -> None:
        # Subscribed at start or not, a topic nobody publishes yet is reported as missing.
        missing = [t for t in self.p["topics"]
                   if t not in self._subs or not self.get_publishers_info_by_topic(t)]
        # A volatile publisher on a latched topic cannot serve the latched reader.
        volatile = [t for t in self._subs if t in LATCHED and any(
            i.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL
            for i in self.get_publishers_info_by_topic(t))]
        level = c.Diagnostics.ERROR if self.refused or volatile else \
            c.Diagnostics.WARN if missing else c.Diagnostics.OK
        msg = "recording" + (f"; no publisher yet on {', '.join(missing)}" if missing else "")
        if volatile:
            msg += (f"; not recorded from volatile publishers on {', '.join(volatile)} "
                    "(publish them reliable and transient-local)")
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
    return run_node(Recorder, args)


if __name__ == "__main__":
    raise SystemExit(main())
