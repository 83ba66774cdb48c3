"""TF on the live graph: the standard TFMessage type, mocap_bridge's latched grasp-plane
calibration, and the scene's moving frames agreeing with its PoseStamped topics."""

from __future__ import annotations

import numpy as np
import pytest

from node_support import Bus, NodeProcess

pytestmark = pytest.mark.ros

#: A calibration with a real offset and rotation, so a swapped or dropped part shows.
CALIB_EULER_XYZ_DEG = (20.0, -35.0, 80.0)
CALIB_XYZ = (0.012, -0.021, 0.034)


def _calib() -> list:
    from scipy.spatial.transform import Rotation
    q = Rotation.from_euler("xyz", CALIB_EULER_XYZ_DEG, degrees=True).as_quat()
    return list(CALIB_XYZ) + [float(x) for x in q]


def _standard_tfmessage_hash() -> str:
    """RIHS01 hash of ROS 2 Jazzy's tf2_msgs/msg/TFMessage, computed by rosbags from its
    own copy of the Jazzy definitions (independent of the compat build)."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY).hash_rihs01("tf2_msgs/msg/TFMessage")


def _hash_str(type_hash) -> str:
    return f"RIHS{type_hash.version:02d}_{type_hash.value.hex()}"


def _static_edges(bus, topic="/tf_static") -> dict:
    """``child -> (parent, pose)`` from the newest /tf_static message of each publisher."""
    from aslip_ros.nodes.tf_frames import transform_pose
    out = {}
    for msg in bus.messages(topic):
        for t in msg.transforms:
            _, parent, child, pose = transform_pose(t)
            out[child] = (parent, pose)
    return out


def _same_pose(a, b, atol=1e-9) -> bool:
    """Equal poses (a quaternion and its negative are the same rotation)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return bool(np.allclose(a[:3], b[:3], atol=atol)
                and (np.allclose(a[3:], b[3:], atol=atol)
                     or np.allclose(a[3:], -b[3:], atol=atol)))


def test_tfmessage_has_the_standard_definition():
    """Same package, name and fields as Jazzy's tf2_msgs (whichever provides it here)."""
    from rosbags.typesys import Stores, get_typestore
    from tf2_msgs.msg import TFMessage
    assert TFMessage.get_fields_and_field_types() == {
        "transforms": "sequence<geometry_msgs/TransformStamped>"}
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    _, fields = jazzy.fielddefs["tf2_msgs/msg/TFMessage"]
    assert [name for name, _ in fields] == ["transforms"]
    assert fields[0][1][1][0][1] == "geometry_msgs/msg/TransformStamped"


def test_mocap_bridge_latches_its_calibration_on_tf_static(rclpy_context, ros_env):
    """A late joiner on another process gets finger -> grasp plane = grasp_plane_in_finger
    and grasp plane -> gripper (the audio frame), as the standard TFMessage type."""
    from tf2_msgs.msg import TFMessage

    from aslip_ros import frames
    from aslip_ros.runtime.qos import TF_STATIC_LISTENER_QOS, TF_STATIC_QOS
    calib = _calib()
    with NodeProcess("mocap_bridge", ros_env, {"grasp_plane_in_finger": calib}) as node:
        node.wait_ready()
        bus = Bus(rclpy_context)            # joins after the message was sent: latched
        bus.listen(TFMessage, "/tf_static", TF_STATIC_LISTENER_QOS)
        assert bus.wait(lambda: len(_static_edges(bus)) >= 2, 20), node.output
        edges = _static_edges(bus)
        parent, pose = edges[frames.GRASP_PLANE]
        assert parent == frames.FINGER
        assert _same_pose(pose, calib), (pose, calib)
        assert edges[frames.GRIPPER] == (frames.GRASP_PLANE, [0, 0, 0, 0, 0, 0, 1.0])
        infos = bus.node.get_publishers_info_by_topic("/tf_static")
        assert [i.topic_type for i in infos] == ["tf2_msgs/msg/TFMessage"]
        assert _hash_str(infos[0].topic_type_hash) == _standard_tfmessage_hash()
        qos = infos[0].qos_profile
        assert (qos.durability, qos.reliability) == (TF_STATIC_QOS.durability,
                                                     TF_STATIC_QOS.reliability)
        bus.close()


def _by_stamp(msgs) -> dict:
    from aslip_ros.nodes import convert
    return {stamp: pose for stamp, _, pose in (convert.pose_from_msg(m) for m in msgs)}


def _matched(bus) -> dict:
    """Per moving frame: how many pose-topic stamps also came on /tf (best-effort poses
    may be dropped under load, so the test waits for enough of both)."""
    from aslip_ros import frames
    from aslip_ros.nodes import common as c
    from aslip_ros.nodes.tf_frames import transform_pose
    on_tf = {(transform_pose(t)[2], transform_pose(t)[0])
             for msg in bus.messages("/tf") for t in msg.transforms}
    return {child: sum((child, s) in on_tf for s in _by_stamp(bus.messages(topic)))
            for topic, child in ((c.FINGER_TOPIC, frames.FINGER),
                                 (c.OBJECT_TOPIC, frames.OBJECT), (c.TCP_TOPIC, frames.TCP))}


def test_scene_tf_agrees_with_its_pose_topics(rclpy_context, ros_env):
    """scene_sim + mocap_bridge: the published edges are exactly frames.TF_TREE; each /tf
    pose equals the PoseStamped of the same stamp; the grasp plane composed through TF is
    the finger pose composed with the calibration."""
    from geometry_msgs.msg import PoseStamped
    from tf2_msgs.msg import TFMessage

    from aslip_ros import frames
    from aslip_ros.control.frames import compose
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import SENSOR_QOS
    from aslip_ros.nodes.tf_frames import transform_pose
    from aslip_ros.runtime.qos import TF_QOS, TF_STATIC_LISTENER_QOS
    calib = _calib()
    bus = Bus(rclpy_context)
    bus.listen(TFMessage, "/tf", TF_QOS)
    bus.listen(TFMessage, "/tf_static", TF_STATIC_LISTENER_QOS)
    for topic in (c.FINGER_TOPIC, c.OBJECT_TOPIC, c.TCP_TOPIC):
        bus.listen(PoseStamped, topic, SENSOR_QOS)
    # As the launch files run it beside the scene: scene_sim publishes the bodies.
    with NodeProcess("scene_sim", ros_env) as scene, \
            NodeProcess("mocap_bridge", ros_env, {"grasp_plane_in_finger": calib,
                                                  "publish_pose_tf": False}) as bridge:
        scene.wait_ready()
        bridge.wait_ready()
        assert bus.wait(lambda: len(_static_edges(bus)) >= 3
                        and min(_matched(bus).values()) >= 10, 60), \
            scene.output + bridge.output
    bus.close()

    dynamic = {}                     # (child, stamp) -> (parent, pose)
    for msg in bus.messages("/tf"):
        for t in msg.transforms:
            stamp, parent, child, pose = transform_pose(t)
            dynamic[(child, stamp)] = (parent, pose)
    static = _static_edges(bus)
    tree = {child: parent for (child, _), (parent, _) in dynamic.items()}
    tree.update({child: parent for child, (parent, _) in static.items()})
    assert tree == dict(frames.TF_TREE)
    assert _same_pose(static[frames.BASE][1], [0, 0, 0, 0, 0, 0, 1.0])

    checked = {}
    for topic, child in ((c.FINGER_TOPIC, frames.FINGER), (c.OBJECT_TOPIC, frames.OBJECT),
                         (c.TCP_TOPIC, frames.TCP)):
        poses = _by_stamp(bus.messages(topic))
        both = [s for s in poses if (child, s) in dynamic]
        checked[child] = len(both)
        for s in both:
            pose_tf = dynamic[(child, s)][1]
            if child == frames.TCP:                    # through link_base -> world
                pose_tf = compose(static[frames.BASE][1], pose_tf)
            assert _same_pose(pose_tf, poses[s]), (child, s)
    assert min(checked.values()) >= 10, checked

    finger = _by_stamp(bus.messages(c.FINGER_TOPIC))
    s = next(s for s in finger if (frames.FINGER, s) in dynamic)
    plane_tf = compose(dynamic[(frames.FINGER, s)][1], static[frames.GRASP_PLANE][1])
    assert _same_pose(plane_tf, compose(finger[s], calib))


def test_mocap_bridge_refuses_a_grasp_plane_that_is_its_own_parent(ros_env):
    """finger_frame == frame_id would publish a transform from a frame to itself."""
    proc = NodeProcess("mocap_bridge", ros_env, {"finger_frame": "aslip_grasp_plane"})
    assert proc.proc.wait(30) == 2
    assert "finger_frame and frame_id must differ" in proc.stop()


def _static_listener_receives(context, qos) -> set:
    """Two nodes latch their static transforms (as scene_sim and mocap_bridge do); a
    listener with ``qos`` joins after both, and every latched sample is in its queue before
    it takes the first. Returns the children it got."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from tf2_msgs.msg import TFMessage

    from aslip_ros import frames
    from aslip_ros.nodes.tf_frames import StaticFrames
    scene = rclpy.create_node("static_scene", context=context)
    bridge = rclpy.create_node("static_bridge", context=context)
    listener = rclpy.create_node("static_listener", context=context)
    try:
        scene_tf, bridge_tf = StaticFrames(scene), StaticFrames(bridge)
        scene_tf.set(frames.WORLD, frames.BASE, [0, 0, 0, 0, 0, 0, 1.0])
        bridge_tf.set(frames.GRASP_PLANE, frames.GRIPPER, [0, 0, 0, 0, 0, 0, 1.0])
        bridge_tf.set(frames.FINGER, frames.GRASP_PLANE, _calib())
        got = []
        listener.create_subscription(TFMessage, "/tf_static", got.append, qos)
        # Not spun yet: wait until both writers have matched the reader and it has
        # acknowledged their latched samples, so both sit in its queue together.
        pubs = [scene_tf._pub, bridge_tf._pub]
        for pub in pubs:
            for _ in range(200):
                if pub.get_subscription_count() and pub.wait_for_all_acked(
                        rclpy.duration.Duration(seconds=0.1)):
                    break
            else:
                raise AssertionError("the listener never matched a static publisher")
        ex = SingleThreadedExecutor(context=context)
        ex.add_node(listener)
        # Take what the queue holds: stop at the first spin that delivers nothing.
        for _ in range(50):
            before = len(got)
            ex.spin_once(timeout_sec=0.5)
            if len(got) == before:
                break
        ex.shutdown()
        return {t.child_frame_id for m in got for t in m.transforms}
    finally:
        for n in (scene, bridge, listener):
            n.destroy_node()


def test_a_static_listener_keeps_every_publishers_transforms(rclpy_context):
    """The TF listener QoS the launch tests' probe and the node tests use (tf2_ros's
    StaticListenerQoS, 100 deep) keeps the latched transforms of every publisher. A reader
    one deep (the probe's before: the rviz launch test then missed mocap_bridge's grasp
    plane) keeps one publisher's only: that is what this test tells apart."""
    import launch_case
    from rclpy.qos import QoSProfile

    from aslip_ros import frames
    from aslip_ros.runtime.qos import LATCHED_QOS
    from aslip_ros.runtime.qos import TF_STATIC_LISTENER_QOS
    every = {frames.BASE, frames.GRIPPER, frames.GRASP_PLANE}
    assert _static_listener_receives(rclpy_context, TF_STATIC_LISTENER_QOS) == every
    if launch_case.MISSING is None:
        probe_qos = launch_case.rviz_topics([])["/tf_static"][2]
        assert probe_qos.depth >= TF_STATIC_LISTENER_QOS.depth
    one_deep = QoSProfile(history=LATCHED_QOS.history, depth=1,
                          reliability=LATCHED_QOS.reliability,
                          durability=LATCHED_QOS.durability)
    assert _static_listener_receives(rclpy_context, one_deep) < every


def _tree(bus) -> dict:
    """``child -> parent`` of every transform received on /tf and /tf_static."""
    from aslip_ros.nodes.tf_frames import transform_pose
    return {transform_pose(t)[2]: transform_pose(t)[1]
            for topic in ("/tf", "/tf_static") for msg in bus.messages(topic)
            for t in msg.transforms}


def test_mocap_bridge_puts_a_drivers_bodies_on_tf(rclpy_context, ros_env):
    """A driver that publishes poses only, in a frame of its own (vrpn_mocap, mocap4r2):
    mocap_bridge publishes each body under that frame, with the pose's stamp and values,
    that frame as world, and the cell's link_base in world, so every frame rviz shows joins
    world (rviz on hardware showed no slip arrow: nothing joined the finger to world)."""
    from geometry_msgs.msg import PoseStamped
    from tf2_msgs.msg import TFMessage

    from aslip_ros import frames
    from aslip_ros.runtime.qos import SENSOR_QOS
    from aslip_ros.nodes import convert
    from aslip_ros.nodes.tf_frames import transform_pose
    from aslip_ros.runtime.qos import TF_QOS, TF_STATIC_LISTENER_QOS
    finger_topic, object_topic = "/natnet/aslip_finger/pose", "/natnet/aslip_object/pose"
    base = [0.5, -0.2, 0.0, 0.0, 0.0, 0.7071067811865476, 0.7071067811865476]
    bus = Bus(rclpy_context)
    bus.listen(TFMessage, "/tf", TF_QOS)
    bus.listen(TFMessage, "/tf_static", TF_STATIC_LISTENER_QOS)
    pub_f = bus.node.create_publisher(PoseStamped, finger_topic, SENSOR_QOS)
    pub_o = bus.node.create_publisher(PoseStamped, object_topic, SENSOR_QOS)
    finger = [0.1, 0.2, 0.3] + _calib()[3:]
    obj = [0.11, 0.2, 0.31, 0.0, 0.0, 0.0, 1.0]
    sent = []
    params = {"finger_topic": finger_topic, "object_topic": object_topic,
              "publish_base_tf": True, "base_in_world": base}
    with NodeProcess("mocap_bridge", ros_env, params) as bridge:
        bridge.wait_ready()

        def fed() -> bool:
            stamp = 10**9 + len(sent) * 10**7
            sent.append(stamp)
            pub_f.publish(convert.pose_to_msg(finger, stamp, "mocap"))
            pub_o.publish(convert.pose_to_msg(obj, stamp, "mocap"))
            tree = _tree(bus)
            return all(frames.connected(f, frames.WORLD, tree)
                       for f in (frames.GRIPPER, frames.OBJECT, frames.BASE))
        assert bus.wait(fed, 30), (_tree(bus), bridge.output)
    bus.close()
    tree = _tree(bus)
    assert tree[frames.FINGER] == tree[frames.OBJECT] == "mocap"
    assert tree["mocap"] == frames.WORLD and tree[frames.BASE] == frames.WORLD
    static = _static_edges(bus)
    assert _same_pose(static["mocap"][1], [0, 0, 0, 0, 0, 0, 1.0])
    assert _same_pose(static[frames.BASE][1], base)
    got = {(child, stamp): pose for msg in bus.messages("/tf") for t in msg.transforms
           for stamp, _, child, pose in [transform_pose(t)]}
    assert got and {s for _, s in got} <= set(sent)
    for (child, _), pose in got.items():
        assert _same_pose(pose, finger if child == frames.FINGER else obj, atol=1e-6)


def test_mocap_bridge_leaves_the_bodies_to_a_driver_that_publishes_them(rclpy_context,
                                                                        ros_env):
    """publish_pose_tf: false (the scene, or a driver with TF): nothing on /tf from it."""
    from geometry_msgs.msg import PoseStamped
    from tf2_msgs.msg import TFMessage

    from aslip_ros import frames
    from aslip_ros.msg import SlipVector
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
    from aslip_ros.nodes import convert
    from aslip_ros.runtime.qos import TF_QOS, TF_STATIC_LISTENER_QOS
    bus = Bus(rclpy_context)
    bus.listen(TFMessage, "/tf", TF_QOS)
    bus.listen(TFMessage, "/tf_static", TF_STATIC_LISTENER_QOS)
    bus.listen(SlipVector, c.SLIP_TRUTH_TOPIC, RELIABLE_QOS)
    pub_f = bus.node.create_publisher(PoseStamped, c.FINGER_TOPIC, SENSOR_QOS)
    pub_o = bus.node.create_publisher(PoseStamped, c.OBJECT_TOPIC, SENSOR_QOS)
    n = [0]
    with NodeProcess("mocap_bridge", ros_env, {"publish_pose_tf": False}) as bridge:
        bridge.wait_ready()

        def fed() -> bool:
            n[0] += 1
            stamp = 10**9 + n[0] * 10**7
            pub_f.publish(convert.pose_to_msg([0, 0, 0, 0, 0, 0, 1.0], stamp, "mocap"))
            pub_o.publish(convert.pose_to_msg([0, 0, 0, 0, 0, 0, 1.0], stamp, "mocap"))
            return len(bus.messages(c.SLIP_TRUTH_TOPIC)) >= 5
        assert bus.wait(fed, 30), bridge.output
        # The static frames arrive on their own topic: wait for them, do not just look.
        assert bus.wait(lambda: set(_tree(bus)) >= {frames.GRASP_PLANE, frames.GRIPPER}, 10), \
            bridge.output
    bus.close()
    assert bus.messages("/tf") == []
    assert set(_tree(bus)) == {frames.GRASP_PLANE, frames.GRIPPER}
