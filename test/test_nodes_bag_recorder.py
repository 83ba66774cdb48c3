"""bag_recorder in one process: the metadata reaches the bag whatever starts first.

The data-collection launch lost ``/aslip/metadata`` from a bag in a fresh-clone CI run:
mocap_bridge subscribes to the metadata, so the topic was known before scene_sim's latched
publisher was; the recorder then subscribed volatile and best effort, and the one metadata
message, sent before the match, never reached the bag. The recorder, the publisher and that
subscriber here are nodes of one process, driven step by step by one executor.
"""

from __future__ import annotations

import json
import time

import pytest

pytestmark = pytest.mark.ros

META = {"object": "chips_can", "scenario": "external_induced", "sample_rate": 48000.0}


class Graph:
    """Nodes on one context and one executor; :meth:`until` spins until a predicate holds."""

    def __init__(self, context) -> None:
        from rclpy.executors import SingleThreadedExecutor
        self.context = context
        self.ex = SingleThreadedExecutor(context=context)
        self.nodes = []

    def add(self, node):
        self.nodes.append(node)
        self.ex.add_node(node)
        return node

    def node(self, name: str):
        import rclpy
        return self.add(rclpy.create_node(name, context=self.context))

    def until(self, predicate, what: str, timeout: float = 30.0):
        """Spin until ``predicate()`` is truthy; the deadline only stops a hang."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = predicate()
            if value:
                return value
            self.ex.spin_once(timeout_sec=0.05)
        raise AssertionError(f"no {what} within {timeout:g} s")

    def close(self) -> None:
        self.ex.shutdown()
        for n in self.nodes:
            n.destroy_node()


def _recorder(graph: Graph, out, topics=None):
    from rclpy.parameter import Parameter

    from aslip_ros.nodes.bag_recorder import Recorder
    extra = [] if topics is None else [Parameter("topics", value=list(topics))]
    return graph.add(Recorder(context=graph.context, parameter_overrides=[
        Parameter("output", value=str(out)), Parameter("discovery_period_s", value=0.05),
        *extra]))


def _metadata_reader(graph: Graph):
    """A node that reads the metadata, as mocap_bridge and the controllers do."""
    from std_msgs.msg import String

    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import LATCHED_QOS
    node = graph.node("metadata_reader")
    node.create_subscription(String, c.METADATA_TOPIC, lambda m: None, LATCHED_QOS)
    return node


def _latch_metadata(graph: Graph):
    """A node that latches the metadata once, as scene_sim and audio_capture do."""
    from std_msgs.msg import String

    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import LATCHED_QOS
    node = graph.node("metadata_source")
    pub = node.create_publisher(String, c.METADATA_TOPIC, LATCHED_QOS)
    pub.publish(String(data=json.dumps(META)))
    return node


def _bag_metadata(path):
    from aslip_ros.data.bags import BagReader
    with BagReader(path) as r:
        return r.read_metadata()


def test_the_metadata_reader_is_latched_before_any_publisher_exists(rclpy_context, tmp_path):
    """Only a subscriber names the topic so far: the recorder's reader is already the
    reliable, transient-local one that a latched publisher serves its past message to."""
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    from aslip_ros.nodes import common as c
    graph = Graph(rclpy_context)
    try:
        _metadata_reader(graph)
        rec = _recorder(graph, tmp_path / "bag")
        graph.until(lambda: c.METADATA_TOPIC in rec.counts, "metadata subscription")
        mine = [i for i in rec.get_subscriptions_info_by_topic(c.METADATA_TOPIC)
                if i.node_name == "bag_recorder"]
        assert len(mine) == 1
        assert mine[0].qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        assert mine[0].qos_profile.reliability == ReliabilityPolicy.RELIABLE
        rec.before_shutdown()
    finally:
        graph.close()


@pytest.mark.parametrize("first", ["recorder", "publisher"])
def test_the_metadata_reaches_the_bag_whatever_starts_first(rclpy_context, tmp_path, first):
    from aslip_ros.nodes import common as c
    graph = Graph(rclpy_context)
    bag = tmp_path / "bag"
    try:
        _metadata_reader(graph)
        if first == "recorder":
            rec = _recorder(graph, bag)
            graph.until(lambda: c.METADATA_TOPIC in rec.counts, "metadata subscription")
            _latch_metadata(graph)
        else:
            _latch_metadata(graph)
            rec = _recorder(graph, bag)
        graph.until(lambda: rec.counts.get(c.METADATA_TOPIC), "metadata in the recorder")
        rec.before_shutdown()
    finally:
        graph.close()
    assert _bag_metadata(bag) == META


def test_the_contract_streams_are_read_before_their_publishers_exist(rclpy_context,
                                                                     tmp_path):
    """Audio, poses, slip truth and TF are subscribed at start with their documented types:
    a recording started before the scene loses none of its beginning to discovery."""
    from aslip_ros.nodes.bag_recorder import RECORDED_TOPICS
    graph = Graph(rclpy_context)
    try:
        rec = _recorder(graph, tmp_path / "bag")
        graph.ex.spin_once(timeout_sec=0.0)
        assert set(rec.counts) == set(RECORDED_TOPICS)
        assert not rec.get_publishers_info_by_topic(RECORDED_TOPICS[0])
        rec.before_shutdown()
    finally:
        graph.close()


def test_a_topic_named_only_by_a_subscriber_waits_for_its_publisher(rclpy_context, tmp_path):
    """A topic outside the contract (a motion-capture driver's own) gets its reader from the
    publishers' QoS, so none is made while only a subscriber names the topic; then the
    publisher's reliability is followed."""
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import ReliabilityPolicy

    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
    driver = "/mocap/finger/pose"
    graph = Graph(rclpy_context)
    try:
        reader = graph.node("pose_reader")
        reader.create_subscription(PoseStamped, driver, lambda m: None, SENSOR_QOS)
        rec = _recorder(graph, tmp_path / "bag", [c.METADATA_TOPIC, driver])
        graph.until(lambda: driver in dict(rec.get_topic_names_and_types()),
                    "the subscriber's topic in the graph")
        for _ in range(10):
            graph.ex.spin_once(timeout_sec=0.06)     # discovery runs every 50 ms
        assert driver not in rec.counts
        graph.node("pose_source").create_publisher(PoseStamped, driver, RELIABLE_QOS)
        graph.until(lambda: driver in rec.counts, "driver topic subscription")
        mine = [i for i in rec.get_subscriptions_info_by_topic(driver)
                if i.node_name == "bag_recorder"]
        assert mine[0].qos_profile.reliability == ReliabilityPolicy.RELIABLE
        rec.before_shutdown()
    finally:
        graph.close()


def test_a_timed_recording_counts_from_its_streams_not_the_start_up(rclpy_context, tmp_path):
    """duration_s: the recording ends (the node is done) duration_s after the last of
    duration_topics delivered its first message, however late that came: a bag of the
    asked length on a cell whose nodes and discovery take seconds to start (a launch timer
    cut trials of the hardware rehearsal to under a second of audio, and a pose stream
    started 2 s into another)."""
    from rclpy.parameter import Parameter

    from aslip_ros.data.bags import BagReader
    from aslip_ros.msg import AudioFrame
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import SENSOR_QOS
    from aslip_ros.nodes.bag_recorder import Recorder
    graph = Graph(rclpy_context)
    rec = graph.add(Recorder(context=graph.context, parameter_overrides=[
        Parameter("output", value=str(tmp_path / "bag")),
        Parameter("topics", value=[c.AUDIO_TOPIC, "/driver/pose"]),
        Parameter("pose_topics", value=["/driver/pose"]),
        Parameter("duration_topics", value=[c.AUDIO_TOPIC, "/driver/pose"]),
        Parameter("duration_s", value=0.3)]))
    pub = graph.node("audio_source").create_publisher(AudioFrame, c.AUDIO_TOPIC,
                                                      SENSOR_QOS)
    from geometry_msgs.msg import PoseStamped
    poses = graph.node("mocap_driver").create_publisher(PoseStamped, "/driver/pose",
                                                        SENSOR_QOS)
    graph.until(lambda: pub.get_subscription_count() > 0 and
                poses.get_subscription_count() > 0, "match")
    # Audio alone for longer than duration_s: the poses are not in yet, not done.
    audio_only = time.monotonic() + 0.5
    graph.until(lambda: pub.publish(AudioFrame()) or time.monotonic() > audio_only,
                "half a second of audio alone", timeout=5)
    assert not rec.done and rec.counts[c.AUDIO_TOPIC] > 0
    t0 = time.monotonic()

    def send():
        pub.publish(AudioFrame())
        poses.publish(PoseStamped())
        return rec.done
    graph.until(send, "the end of the timed recording")
    assert time.monotonic() - t0 >= 0.3 and rec.counts[c.AUDIO_TOPIC] >= 2
    rec.before_shutdown()
    with BagReader(tmp_path / "bag") as reader:
        assert dict(reader.info.counts)[c.AUDIO_TOPIC] == rec.counts[c.AUDIO_TOPIC]
    graph.close()


@pytest.mark.parametrize("seen", [True, False])
def test_a_timed_recording_waits_for_a_latched_message_still_on_its_way(
        rclpy_context, tmp_path, seen):
    """Fresh-clone CI runs closed a 3 s trial's bag without /tf_static: the recording ended
    duration_s after its streams were in, before the static transforms, published and
    latched, reached the recorder. ``seen``: a transient-local /tf_static publisher exists
    but has sent nothing while the audio runs past duration_s; not seen: under load the
    recorder had not discovered it yet (the second CI failure), and the launch names the
    topic as due (``latched_due``). Either way the recording is not done, and once the
    transforms are latched it ends with them in the bag."""
    from rclpy.parameter import Parameter
    from tf2_msgs.msg import TFMessage

    from aslip_ros.data.bags import BagReader
    from aslip_ros.msg import AudioFrame
    from aslip_ros.nodes import common as c
    from aslip_ros.nodes.bag_recorder import Recorder
    from aslip_ros.runtime.qos import LATCHED_QOS, SENSOR_QOS
    from aslip_ros import topics
    graph = Graph(rclpy_context)
    rec = graph.add(Recorder(context=graph.context, parameter_overrides=[
        Parameter("output", value=str(tmp_path / "bag")),
        Parameter("topics", value=[c.AUDIO_TOPIC, topics.TF_STATIC]),
        Parameter("duration_topics", value=[c.AUDIO_TOPIC]),
        Parameter("latched_due", value=[""] if seen else [topics.TF_STATIC]),
        Parameter("duration_s", value=0.2)]))

    def static_publisher():
        return graph.node("frames").create_publisher(TFMessage, topics.TF_STATIC,
                                                     LATCHED_QOS)
    static = static_publisher() if seen else None
    pub = graph.node("audio_source").create_publisher(AudioFrame, c.AUDIO_TOPIC,
                                                      SENSOR_QOS)
    graph.until(lambda: pub.get_subscription_count() > 0
                and (static is None or static.get_subscription_count() > 0), "match")
    past = time.monotonic() + 0.8                 # four times duration_s of audio
    graph.until(lambda: pub.publish(AudioFrame()) or time.monotonic() > past,
                "audio past duration_s", timeout=5)
    assert not rec.done and rec.counts[topics.TF_STATIC] == 0
    (static or static_publisher()).publish(TFMessage())

    def send():
        pub.publish(AudioFrame())
        return rec.done
    graph.until(send, "the end of the timed recording")
    rec.before_shutdown()
    with BagReader(tmp_path / "bag") as reader:
        assert dict(reader.info.counts).get(topics.TF_STATIC) == 1
    graph.close()


@pytest.mark.parametrize("due", ["/aslip/audio", "/rosout"])
def test_latched_due_names_only_latched_topics_that_are_recorded(rclpy_context, tmp_path,
                                                                 due):
    from rclpy.parameter import Parameter

    from aslip_ros.nodes.bag_recorder import Recorder
    from aslip_ros.runtime.process import ConfigError
    with pytest.raises(ConfigError, match="latched_due"):
        Recorder(context=rclpy_context, parameter_overrides=[
            Parameter("output", value=str(tmp_path / "bag")),
            Parameter("topics", value=["/aslip/audio", "/tf_static"]),
            Parameter("latched_due", value=[due])])
    assert not (tmp_path / "bag").exists()


def test_the_stream_watch_ends_a_ros2_bag_trial_only_with_its_latched_topics_in(
        rclpy_context):
    """On the ros2 bag route stream_watch ends the trial: it too waits past duration_s for
    the latched topics the cell's nodes publish (``latched_due``), or ros2 bag's recording
    would lose a /tf_static discovered late the way bag_recorder's did."""
    from rclpy.parameter import Parameter
    from tf2_msgs.msg import TFMessage

    from aslip_ros.msg import AudioFrame
    from aslip_ros.nodes import common as c
    from aslip_ros.nodes.stream_watch import StreamWatchNode
    from aslip_ros.runtime.qos import LATCHED_QOS, SENSOR_QOS
    from aslip_ros import topics
    graph = Graph(rclpy_context)
    watch = graph.add(StreamWatchNode(context=graph.context, parameter_overrides=[
        Parameter("topics", value=[c.AUDIO_TOPIC]),
        Parameter("latched_due", value=[topics.TF_STATIC]),
        Parameter("duration_s", value=0.2)]))
    pub = graph.node("audio_source").create_publisher(AudioFrame, c.AUDIO_TOPIC,
                                                      SENSOR_QOS)
    graph.until(lambda: pub.get_subscription_count() > 0, "match")
    past = time.monotonic() + 1.0                 # five times duration_s of audio
    graph.until(lambda: pub.publish(AudioFrame()) or time.monotonic() > past,
                "audio past duration_s", timeout=5)
    assert watch.watch.complete(0.2) and not watch.done
    static = graph.node("frames").create_publisher(TFMessage, topics.TF_STATIC, LATCHED_QOS)
    static.publish(TFMessage())

    def send():
        pub.publish(AudioFrame())
        return watch.done
    graph.until(send, "the end of the trial")
    assert watch.exit_code == 0
    graph.close()
