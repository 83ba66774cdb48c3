"""Bags that also hold /tf and /tf_static (as the data-collection launch records them)
export exactly like the same bag without them. ROS-free: rosbags writes the TF topics."""

from __future__ import annotations

import json

import numpy as np

from aslip_ros import frames


def _add_tf(src, dst) -> int:
    """Copy bag ``src`` to ``dst`` with a /tf_static message and a /tf message per finger
    pose added; returns the number of TF messages added."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer

    from aslip_ros.data.bags import typestore
    store = typestore()                      # Jazzy's types plus the project's
    tf_type = "tf2_msgs/msg/TFMessage"
    TF = store.types[tf_type]
    TS = store.types["geometry_msgs/msg/TransformStamped"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    Transform = store.types["geometry_msgs/msg/Transform"]
    Vec = store.types["geometry_msgs/msg/Vector3"]
    Quat = store.types["geometry_msgs/msg/Quaternion"]

    def tf_msg(parent, child, ns):
        t = TS(header=Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9),
                             frame_id=parent), child_frame_id=child,
               transform=Transform(translation=Vec(x=0.0, y=0.0, z=0.0),
                                   rotation=Quat(x=0.0, y=0.0, z=0.0, w=1.0)))
        return TF(transforms=[t])

    from aslip_ros.data.bags import BagReader
    with BagReader(src) as r:
        custom = dict(r.info.custom_data)
    added = 0
    with Reader(src) as reader:
        with Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            for k, v in custom.items():
                writer.set_custom_data(k, v)
            conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store,
                                                 serialization_format="cdr",
                                                 offered_qos_profiles=c.ext.offered_qos_profiles)
                     for c in reader.connections}
            tf = writer.add_connection("/tf", tf_type, typestore=store)
            tf_static = writer.add_connection("/tf_static", tf_type, typestore=store)
            first = True
            for conn, ns, raw in reader.messages():
                if first:
                    writer.write(tf_static, ns, store.serialize_cdr(
                        tf_msg(frames.FINGER, frames.GRASP_PLANE, ns), tf_type))
                    added += 1
                    first = False
                writer.write(conns[conn.id], ns, raw)
                if conn.topic == "/aslip/mocap/finger":
                    writer.write(tf, ns, store.serialize_cdr(
                        tf_msg(frames.WORLD, frames.FINGER, ns), tf_type))
                    added += 1
    return added


def test_tf_topics_do_not_change_the_export(tmp_path):
    from aslip_ros.data.bags import BagReader
    from aslip_ros.data.export import export
    from aslip_ros.data.synthetic import write_synthetic_bag
    plain = tmp_path / "plain"
    write_synthetic_bag(plain, duration_s=2.0)
    with_tf = tmp_path / "with_tf"
    assert _add_tf(plain, with_tf) > 100
    with BagReader(with_tf) as r:
        assert {"/tf", "/tf_static"} <= set(r.info.topics)
    a = export([plain], tmp_path / "a")
    b = export([with_tf], tmp_path / "b")
    assert a.kept > 0 and (a.kept, a.dropped) == (b.kept, b.dropped)
    assert b.warnings == a.warnings
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*")
                   if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*")
                           if p.is_file())
    for name in files:
        pa, pb = tmp_path / "a" / name, tmp_path / "b" / name
        if pa.suffix == ".npy":
            np.testing.assert_array_equal(np.load(pa), np.load(pb))
        elif pa.suffix == ".json":
            ja, jb = json.loads(pa.read_text()), json.loads(pb.read_text())
            assert _without_paths(ja) == _without_paths(jb), name
        else:
            assert pa.read_bytes() == pb.read_bytes(), name


def _without_paths(doc):
    """The JSON without values that name the source bag or output folder."""
    if isinstance(doc, dict):
        return {k: _without_paths(v) for k, v in doc.items()
                if k not in ("bag", "bags", "dataset", "path", "created", "elapsed_s")}
    if isinstance(doc, list):
        return [_without_paths(v) for v in doc]
    if isinstance(doc, str) and ("plain" in doc or "with_tf" in doc):
        return "<path>"
    return doc
