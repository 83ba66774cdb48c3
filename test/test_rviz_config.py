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
