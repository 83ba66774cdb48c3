"""Every QoS profile of the package's topics, in one place (docs/design.md, "Topics").

The topic names are in :mod:`aslip_ros.topics`; which node publishes and reads what is in
docs/nodes.md. A profile that a subscription deepens for its own queue is derived here
(:func:`deeper`), so its reliability and durability stay those of the stream it reads.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: High-rate sensor streams: a late sample is worth less than the next one.
SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                        reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
#: Results and commands: every message matters.
RELIABLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
#: Latched configuration (metadata, results): late joiners get the last message.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Simulated time in lockstep (scene_sim's ``/clock``): a lockstep controller steps once per
#: tick, so none may be lost (reliable; rclpy's own time source subscribes best effort, which
#: a reliable publisher serves too).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
#: rviz markers: only the newest matters.
MARKER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)


def deeper(qos: QoSProfile, depth: int) -> QoSProfile:
    """``qos`` with a ``depth``-deep keep-last queue (same reliability and durability)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=qos.reliability, durability=qos.durability)


#: slip_inference's audio subscription: the sensor QoS (best effort, volatile) with a 1 s
#: queue at 10 ms blocks. With the default 10-deep queue, a process starved of CPU for 100 ms
#: (two busy processes on a 2-core host do it) lost blocks, and each gap restarts the window:
#: a 200 ms model then published nothing for 200 ms, tripping the controllers' stale-input
#: stop. A backlog is cheap to catch up with (a hop supersedes the waiting one); lost audio
#: is not.
AUDIO_QOS = deeper(SENSOR_QOS, 100)

#: audio_common's audio_capture_node publishes ``audio_stamped`` reliable, 10 deep; read
#: reliable (it serves that) with room for a burst while the capture thread is busy (as
#: many blocks as the topic source's queue holds: nodes/topic_audio.py).
AUDIO_COMMON_QOS = deeper(RELIABLE_QOS, 100)

#: stream_watch: arrivals are only counted: a shallow best-effort reader (matches any
#: publisher).
WATCH_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                       reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)

#: The recorder's and the mocap check's reader queue: a burst that arrives while the reader
#: is busy is kept.
READER_DEPTH = 1000


def reader_qos(latched: bool, reliable: bool, depth: int = READER_DEPTH) -> QoSProfile:
    """A recorder's subscription QoS for publishers that serve ``latched`` / ``reliable``
    (a transient-local reader is reliable)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if (reliable or latched)
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


#: tf2_ros's DynamicBroadcasterQoS / DynamicListenerQoS: reliable, volatile, 100 deep.
TF_QOS = deeper(RELIABLE_QOS, 100)
#: tf2_ros's StaticBroadcasterQoS: latched, one message per publisher (the latched profile).
TF_STATIC_QOS = LATCHED_QOS
#: tf2_ros's StaticListenerQoS: latched, 100 deep. Every static publisher (scene_sim,
#: mocap_bridge, a driver) latches its own message; a reader one deep keeps only the last
#: to arrive of those delivered together at the match, and loses the others for good.
TF_STATIC_LISTENER_QOS = deeper(LATCHED_QOS, 100)
