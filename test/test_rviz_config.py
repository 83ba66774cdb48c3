"""config/aslip.rviz: one fixed frame in which the slip arrows and every pose show together.

The frames each display needs come from the code that stamps the messages, and the tree
from aslip_ros.frames.TF_TREE, which test_nodes_tf.py checks against what the nodes publish.
"""

from __future__ import annotations

import pytest
import yaml

from aslip_ros import frames
from conftest import ROOT

RVIZ = ROOT / "config" / "aslip.rviz"


def _config() -> dict:
    return yaml.safe_load(RVIZ.read_text())


def _displays() -> list:
    return _config()["Visualization Manager"]["Displays"]


def _topic_frames() -> dict:
    """Each displayed topic -> the frame its messages are stamped in (docs/design.md)."""
    return {"/aslip/slip_marker": frames.GRASP_PLANE,
            "/aslip/slip_marker_truth": frames.GRASP_PLANE,
            "/aslip/mocap/finger": frames.WORLD, "/aslip/mocap/object": frames.WORLD,
            "/aslip/robot/tcp_pose": frames.BASE}


@pytest.mark.ros
def test_marker_frame_is_the_one_the_nodes_stamp():
    from aslip_ros.nodes import convert
    msg = convert.slip_to_msg(0.01, 0.0, 0.9, True, 0.5, 10**9, 0.2, "cnn")
    arrows = convert.slip_markers(msg)
    assert {m.header.frame_id for m in arrows.markers} == {frames.GRASP_PLANE}


def test_fixed_frame_is_the_tree_root_and_reaches_every_display():
    fixed = _config()["Visualization Manager"]["Global Options"]["Fixed Frame"]
    # A root does not move: the poses and the arrows are drawn where they are, not relative
    # to a frame that itself slides with the grasp.
    assert frames.chain(fixed)[-1] == fixed, f"{fixed} is not the root of the TF tree"
    shown = {d["Topic"]["Value"] for d in _displays() if "Topic" in d}
    wanted = _topic_frames()
    assert set(wanted) <= shown, sorted(set(wanted) - shown)
    for topic in shown:
        assert frames.connected(fixed, wanted[topic]), (topic, wanted[topic], fixed)


def test_tf_display_and_view_follow_the_grasp_plane():
    assert any(d["Class"] == "rviz_default_plugins/TF" and d.get("Enabled", True)
               for d in _displays())
    view = _config()["Visualization Manager"]["Views"]["Current"]
    assert frames.connected(view["Target Frame"], frames.GRASP_PLANE)


def test_frames_chain_and_connected():
    assert frames.chain(frames.GRIPPER) == [frames.GRIPPER, frames.GRASP_PLANE, frames.FINGER,
                                            frames.WORLD]
    assert frames.connected(frames.TCP, frames.OBJECT)
    assert not frames.connected(frames.TCP, "elsewhere")
    with pytest.raises(ValueError, match="loop"):
        frames.chain("a", {"a": "b", "b": "a"})


def test_the_written_view_follows_the_graphs_pose_topics(tmp_path):
    """rviz on a cell subscribes to its driver's topics, not the contract's (it showed no
    finger or object on hardware); the rest of the shipped view is kept."""
    from aslip_ros import topics
    from aslip_ros.launch_support.rviz_view import display_topic, displays, write_view
    env = {"ROS_HOME": str(tmp_path)}
    finger, obj = "/vrpn_mocap/aslip_finger/pose", "/vrpn_mocap/aslip_object/pose"
    path, notes = write_view(RVIZ, finger, obj, tcp_placed=True, env=env)
    assert path.parent == tmp_path / "aslip_ros" / "rviz" and notes == []
    doc = yaml.safe_load(path.read_text())
    shown = [display_topic(d) for d in displays(doc)]
    assert finger in shown and obj in shown and topics.TCP in shown
    assert topics.FINGER not in shown and topics.OBJECT not in shown
    assert doc["Visualization Manager"]["Global Options"]["Fixed Frame"] == frames.WORLD
    assert len(displays(doc)) == len(_displays())
    # The same graph writes the same file; another graph another file, never half of one.
    assert write_view(RVIZ, finger, obj, True, env=env)[0] == path
    other, _ = write_view(RVIZ, topics.FINGER, topics.OBJECT, True, env=env)
    assert other != path and path.read_text() != other.read_text()
    assert sorted(p.name for p in path.parent.iterdir()) == sorted([path.name, other.name])


def test_the_tcp_display_is_left_out_where_nothing_places_link_base(tmp_path):
    from aslip_ros import topics
    from aslip_ros.launch_support.rviz_view import display_topic, displays, write_view
    path, notes = write_view(RVIZ, topics.FINGER, topics.OBJECT, tcp_placed=False,
                             env={"ROS_HOME": str(tmp_path)})
    shown = [display_topic(d) for d in displays(yaml.safe_load(path.read_text()))]
    assert topics.TCP not in shown and topics.FINGER in shown
    assert len(notes) == 1 and "base_in_world" in notes[0]


def test_pose_displays_are_left_out_where_the_mocap_publishes_no_posestamped(tmp_path):
    """mocap4r2 (one RigidBodies topic): rviz's Pose displays cannot read it; the bodies
    show through the TF display (mocap_bridge puts them on /tf)."""
    from aslip_ros import topics
    from aslip_ros.launch_support.rviz_view import display_topic, displays, write_view
    path, notes = write_view(RVIZ, None, None, tcp_placed=True,
                             env={"ROS_HOME": str(tmp_path)})
    doc = yaml.safe_load(path.read_text())
    shown = [display_topic(d) for d in displays(doc)]
    assert topics.FINGER not in shown and topics.OBJECT not in shown
    assert topics.TCP in shown and len(notes) == 2
    assert any(d["Class"] == "rviz_default_plugins/TF" for d in displays(doc))
