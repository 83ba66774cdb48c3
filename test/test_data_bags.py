"""rosbag2 round trip with rosbags (aslip_ros.data.bags)."""

import json

import numpy as np
import pytest

from aslip_ros.data import bags


def test_msg_dir_found_and_types_registered():
    d = bags.find_msg_dir()
    assert (d / "AudioFrame.msg").is_file()
    store = bags.typestore()
    assert bags.AUDIO_TYPE in store.types and bags.SLIP_TYPE in store.types


def test_msg_dir_env_override(tmp_path, monkeypatch):
    monkeypatch.setenv("ASLIP_MSG_DIR", str(tmp_path))
    (tmp_path / "AudioFrame.msg").write_text("float64 sample_rate\n")
    assert bags.find_msg_dir() == tmp_path


def test_round_trip(tmp_path):
    meta = bags.make_metadata(sample_rate=48000.0, channel_names=["a", "b"], object="x",
                              induced="external")
    path = tmp_path / "bag"
    rng = np.random.default_rng(0)
    blocks = [rng.standard_normal((480, 2)).astype(np.float32) for _ in range(5)]
    with bags.BagWriter(path, metadata=meta, start_ns=123_000_000_000) as w:
        for k, b in enumerate(blocks):
            w.write_audio(k * 0.01, k * 480, b, 48000.0, ["a", "b"], "2mic")
        # Written out of order on purpose: the reader yields them in time order.
        w.write_pose("object", 0.02, [1, 2, 3, 0, 0, 0, 1])
        w.write_pose("finger", 0.005, [0.1, 0.2, 0.3, 0, 0, np.sin(0.2), np.cos(0.2)])
        w.write_pose("tcp", 0.015, [0, 0, 0.5, 1, 0, 0, 0])
        w.write_slip_truth(0.04, 0.01, -0.02, 0.2, 0.005)
    assert (path / "metadata.yaml").is_file()
    with bags.BagReader(path) as r:
        assert r.info.topics == {
            "/aslip/metadata": "std_msgs/msg/String", "/aslip/audio": bags.AUDIO_TYPE,
            "/aslip/mocap/object": bags.POSE_TYPE, "/aslip/mocap/finger": bags.POSE_TYPE,
            "/aslip/robot/tcp_pose": bags.POSE_TYPE, "/aslip/slip_truth": bags.SLIP_TYPE}
        assert r.info.counts["/aslip/audio"] == 5
        assert json.loads(r.info.custom_data["aslip"])["object"] == "x"
        assert r.metadata == meta
        msgs = list(r.messages())
    times = [m.log_ns for m in msgs]
    assert times == sorted(times)
    audio = [m.msg for m in msgs if m.topic == "/aslip/audio"]
    for k, a in enumerate(audio):
        assert a.first_sample_index == k * 480 and list(a.channel_names) == ["a", "b"]
        assert bags.stamp_to_ns(a.header.stamp) == 123_000_000_000 + k * 10_000_000
        np.testing.assert_array_equal(a.data.reshape(-1, 2), blocks[k])
    finger = next(m.msg for m in msgs if m.topic == "/aslip/mocap/finger")
    assert finger.header.frame_id == "world"
    np.testing.assert_allclose(bags.pose_from_msg(finger)[:3], [0.1, 0.2, 0.3])
    slip = next(m.msg for m in msgs if m.topic == "/aslip/slip_truth")
    assert slip.slipping and abs(slip.speed - np.hypot(0.01, 0.02)) < 1e-6
    # The bare .mcap file opens too; metadata then comes from the topic.
    with bags.BagReader(path / "bag.mcap") as r:
        assert r.metadata == meta


def test_metadata_only_on_topic_and_no_metadata(tmp_path):
    with bags.BagWriter(tmp_path / "none") as w:
        w.write_pose("tcp", 0.0, [0, 0, 0, 0, 0, 0, 1])
    with bags.BagReader(tmp_path / "none") as r:
        assert r.metadata is None
    with pytest.raises(bags.BagError, match="exists"):
        bags.BagWriter(tmp_path / "none")


def test_writer_is_atomic(tmp_path):
    with pytest.raises(RuntimeError):
        with bags.BagWriter(tmp_path / "b") as w:
            w.write_pose("tcp", 0.0, [0, 0, 0, 0, 0, 0, 1])
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("little", [True, False])
@pytest.mark.parametrize("frame", ["", "w", "wor", "worl", "world", "link_base7"])
def test_fast_pose_decode_matches_rosbags(frame, little):
    store = bags.typestore()
    T = store.types
    msg = T[bags.POSE_TYPE](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=17, nanosec=999), frame_id=frame),
        pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=1.5, y=-2.0, z=3.25),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.1, y=0.2, z=0.3, w=0.9)))
    raw = store.serialize_cdr(msg, bags.POSE_TYPE, little_endian=little)
    sp = bags.decode_pose_stamped(raw)
    assert sp.stamp_ns == 17_000_000_999 and sp.frame_id == frame
    np.testing.assert_array_equal(sp.pose, bags.pose_from_msg(msg))
    with pytest.raises(bags.BagError):
        bags.decode_pose_stamped(bytes(raw)[:-8])


def test_find_bags(tmp_path):
    for name in ("b2", "sub/b1"):
        with bags.BagWriter(tmp_path / name) as w:
            w.write_pose("tcp", 0.0, [0, 0, 0, 0, 0, 0, 1])
    found = bags.find_bags([tmp_path, tmp_path / "b2"])
    assert [p.name for p in found] == ["b2", "b1"] or sorted(p.name for p in found) == [
        "b1", "b2"]
    assert len(found) == 2
    with pytest.raises(bags.BagError, match="does not exist"):
        bags.find_bags([tmp_path / "nope"])
