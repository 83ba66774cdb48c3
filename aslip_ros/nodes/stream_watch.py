"""``stream_watch``: a trial fails, exit code 1, when one of its streams never arrives or stops.

``data_collection.launch.py`` runs it beside the recorder on a hardware trial, whichever
the recorder (``ros2 bag record`` or ``bag_recorder``), watching the audio and the two pose
streams the recording uses; its exit ends the launch with exit status 1 and the recorder
closes its bag. The verdict is :class:`aslip_ros.data.stream_watch.StreamWatch`'s: no
message on a topic within ``start_timeout_s`` of the node's start, or none for
``stall_timeout_s`` after it had delivered. The first failed stream gets one ERROR line
that names it, then the node exits 1. With ``duration_s`` > 0 it exits 0 that long after
every stream is in (the end of a trial recorded by ``ros2 bag record``, which has no
duration of its own), and not before the latched topics of ``latched_due`` (the metadata,
mocap_bridge's /tf_static) have reached it, at most ``LATCHED_GRACE_S`` more: a latched
publisher discovered late would otherwise miss the bag, as it did ``bag_recorder``'s.

Each topic is subscribed once a publisher of it is seen, with the type the graph gives,
best effort (which every publisher serves), as serialized bytes: nothing is decoded, so any
message type counts (PoseStamped, AudioFrame, a driver's own).
"""

from __future__ import annotations

import importlib
import time
from typing import Optional

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from aslip_ros.data.stream_watch import (START_TIMEOUT_RANGE_S, STALL_TIMEOUT_RANGE_S,
                                         StreamWatch, WatchConfig)
from aslip_ros.nodes import common as c
from aslip_ros.nodes.bag_recorder import LATCHED, LATCHED_GRACE_S
from aslip_ros.runtime.process import ConfigError, ready, run_node
from aslip_ros.runtime.qos import WATCH_QOS, reader_qos

#: How often the verdict is taken, and the graph searched for the watched topics [s]: the
#: verdict comes at most this late after a threshold passed.
CHECK_PERIOD_S = 0.05
DISCOVERY_PERIOD_S = 0.2
#: A check this much later than its period finds the process was stalled (a loaded
#: machine): the messages that came meanwhile may still wait in the executor's queue, so
#: that round gives no verdict (the next one, a period later, does).
LATE_CHECK_S = 0.25


def _topic_list(v) -> Optional[str]:
    names = [str(n) for n in v]
    if not names or any(not n.startswith("/") for n in names) or len(set(names)) != len(names):
        return f"must be a non-empty list of distinct absolute topic names, got {names}"
    return None


def _message_class(type_name: str):
    """The class of ``pkg/msg/Name`` (ImportError, AttributeError or ValueError if none)."""
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def watch_params() -> list:
    """The parameters of ``stream_watch``; the thresholds' defaults are the core's."""
    return [
        c.Param("topics", [c.AUDIO_TOPIC, c.FINGER_TOPIC, c.OBJECT_TOPIC],
                "the streams every trial needs", c.Rule(_topic_list, "absolute topic names"),
                read_only=True),
        c.from_config(WatchConfig, "start_timeout_s", "every topic's first message within "
                      "this long of the node's start [s]", c.in_range(*START_TIMEOUT_RANGE_S),
                      read_only=True),
        c.from_config(WatchConfig, "stall_timeout_s", "a topic silent this long after it "
                      "delivered has stopped [s]", c.in_range(*STALL_TIMEOUT_RANGE_S),
                      read_only=True),
        c.Param("duration_s", 0.0, "exit 0 this long after every topic is in [s]; 0 = run "
                "until stopped", c.in_range(0.0, 86400.0), read_only=True),
        c.Param("latched_due", [""], "latched topics duration_s also waits for, at most "
                f"{LATCHED_GRACE_S:g} s more ('' = none)", read_only=True),
    ]


class StreamWatchNode(Node):
    """Counts arrivals per topic and exits 1 (``done``, ``exit_code``) on the first fault."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("stream_watch", **kwargs)
        self.p = c.declare_params(self, watch_params())
        config = WatchConfig(**c.config_kwargs(WatchConfig, self.p))
        self.watch = StreamWatch(self.p["topics"], config)
        self.done = False
        self.exit_code = 0
        self._subs: dict = {}
        self.refused: dict = {}
        self._last_check = time.monotonic()
        self.due = [t for t in self.p["latched_due"] if t]
        if any(t not in LATCHED for t in self.due):
            raise ConfigError(f"latched_due: {self.due} names a topic that is not latched "
                              f"(latched: {', '.join(LATCHED)})")
        self._latched_in: set = set()
        self._complete_at: Optional[float] = None
        for topic in self.due:
            self._subs[topic] = self.create_subscription(
                _message_class(LATCHED[topic]), topic,
                lambda _data, t=topic: self._latched_in.add(t), reader_qos(True, True),
                raw=True)
        self.diag = c.Diagnostics(self, "aslip: stream_watch", ", ".join(self.watch.streams))
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(CHECK_PERIOD_S, self._check, clock=steady)
        self.create_timer(DISCOVERY_PERIOD_S, self._discover, clock=steady)
        self.create_timer(1.0, self._diagnose, clock=steady)
        self._discover()
        ready(self, f"watching {', '.join(self.watch.streams)}")

    def _discover(self) -> None:
        wanted = [t for t in self.watch.streams if t not in self._subs and t not in self.refused]
        if not wanted:
            return
        available = dict(self.get_topic_names_and_types())
        for topic in wanted:
            if topic not in available or not self.get_publishers_info_by_topic(topic):
                continue
            type_name = available[topic][0]
            try:
                cls = _message_class(type_name)
            except (AttributeError, ImportError, ValueError) as exc:
                self.refused[topic] = f"type {type_name} is not importable ({exc})"
                self.get_logger().error(f"cannot watch {topic}: {self.refused[topic]}")
                continue
            self._subs[topic] = self.create_subscription(
                cls, topic, lambda _data, t=topic: self.watch.arrived(t), WATCH_QOS, raw=True)
            self.get_logger().info(f"watching {topic} ({type_name})")

    def _check(self) -> None:
        now = time.monotonic()
        late, self._last_check = now - self._last_check > CHECK_PERIOD_S + LATE_CHECK_S, now
        if self.done or late:
            return
        fault = self.watch.check(now)
        if fault is None:
            duration = self.p["duration_s"]
            if duration > 0 and self.watch.complete(duration):
                self._end(now)
            return
        why = self.refused.get(fault.stream)
        self.get_logger().error(fault.message() + (f" ({why})" if why else ""))
        self.exit_code = 1
        self.done = True
        self._diagnose()

    def _end(self, now: float) -> None:
        """The duration is complete: done, once the due latched topics are in too."""
        if self._complete_at is None:
            self._complete_at = now
        owed = [t for t in self.due if t not in self._latched_in]
        if owed and now - self._complete_at < LATCHED_GRACE_S:
            return
        if owed:
            self.get_logger().warning(
                f"{', '.join(owed)} never arrived within {LATCHED_GRACE_S:g} s past the "
                "duration: the bag may lack it")
        self.get_logger().info(f"every stream has been in for {self.p['duration_s']:g} s: "
                               "done")
        self.done = True

    def _diagnose(self) -> None:
        waiting = self.watch.waiting()
        values = {f"messages {t}": n for t, n in self.watch.counts().items()}
        if self.exit_code:
            level, msg = c.Diagnostics.ERROR, "a stream failed: the trial failed"
        elif waiting:
            level, msg = c.Diagnostics.WARN, f"waiting for {', '.join(waiting)}"
        else:
            level, msg = c.Diagnostics.OK, "every stream is arriving"
        self.diag.publish(level, msg, values)


def main(args: Optional[list] = None) -> int:
    """Entry point of ``stream_watch``."""
    return run_node(StreamWatchNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
