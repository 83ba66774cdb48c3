"""A cell whose motion capture is mocap4r2 (one RigidBodies topic, bodies by ID): every
launch file wires mocap_bridge to it, and data collection records that topic with either
recorder and names the bodies in the recording's metadata (what `aslip export` reads)."""

from __future__ import annotations

import json

import pytest

from test_launch_files import _by_exe, check_parameters, evaluate, needs_launch

pytestmark = pytest.mark.ros

CELL = """\
audio_capture:
  device: "rig_pcm"
  channel_names: [pad_a, pad_b]
mocap_bridge:
  pose_source: rigid_bodies
  finger_body: 3            # OptiTrack names a body by its Motive ID
  object_body: 5
  grasp_plane_in_finger: [0.01, 0.0, 0.05, 0, 0, 0, 1]
"""


@pytest.fixture
def cell(tmp_path):
    path = tmp_path / "optitrack_cell.yaml"
    path.write_text(CELL)
    return str(path)


@needs_launch
@pytest.mark.parametrize("launch_file, args", [
    ("data_collection.launch.py", {"recorder": "aslip"}),
    ("slip_stop.launch.py", {"checkpoint": "my_model.pt"}),
    ("slip_track.launch.py", {"checkpoint": "my_model.pt"}),
])
def test_the_bridge_takes_the_cells_bodies(cell, launch_file, args):
    ev = evaluate(launch_file, dict(args, sim="false", cell=cell))
    bridge = _by_exe(ev)["mocap_bridge"]
    assert (bridge["pose_source"], bridge["finger_body"], bridge["object_body"]) == \
        ("rigid_bodies", "3", "5")
    assert "finger_topic" not in bridge and "object_topic" not in bridge
    check_parameters(ev)


@needs_launch
def test_the_aslip_recorder_records_the_rigid_bodies_and_the_metadata_names_the_bodies(cell):
    nodes = _by_exe(evaluate("data_collection.launch.py",
                             {"sim": "false", "cell": cell, "recorder": "aslip"}))
    rec = nodes["bag_recorder"]
    assert rec["topics"].count("/rigid_bodies") == 1
    assert not {"/aslip/mocap/finger", "/aslip/mocap/object"} & set(rec["topics"])
    assert list(rec["rigid_bodies_topics"]) == ["/rigid_bodies"]
    assert list(rec["pose_topics"]) == [""]
    assert "/rigid_bodies" in rec["duration_topics"]
    meta = json.loads(nodes["audio_capture"]["metadata_json"])
    assert meta["topics"]["finger"] == meta["topics"]["object"] == "/rigid_bodies"
    assert meta["bodies"] == {"finger": "3", "object": "5"}


@needs_launch
def test_ros2_bag_records_the_rigid_bodies_topic(cell, monkeypatch):
    """recorder:=ros2bag (rosbag2 taken as installed): `ros2 bag record` is given the
    RigidBodies topic, once, and not the contract's pose topics nobody publishes."""
    import shutil

    import ament_index_python.packages as ament
    real_prefix, real_which = ament.get_package_prefix, shutil.which
    monkeypatch.setattr(ament, "get_package_prefix", lambda name: "/opt/ros/jazzy"
                        if name == "ros2bag" else real_prefix(name))
    monkeypatch.setattr(shutil, "which", lambda name, *a, **k: "/opt/ros/jazzy/bin/ros2"
                        if name == "ros2" else real_which(name, *a, **k))
    ev = evaluate("data_collection.launch.py",
                  {"sim": "false", "cell": cell, "recorder": "ros2bag"})
    cmds = [cmd for cmd, _ in ev.processes if cmd[:3] == ["ros2", "bag", "record"]]
    assert len(cmds) == 1, ev.processes
    assert cmds[0].count("/rigid_bodies") == 1
    assert "/aslip/mocap/finger" not in cmds[0] and "/aslip/audio" in cmds[0]


@needs_launch
def test_a_pose_topic_argument_beside_rigid_bodies_is_refused(cell):
    ev = evaluate("data_collection.launch.py",
                  {"sim": "false", "cell": cell, "finger_topic": "/natnet/finger/pose"})
    assert any("finger_topic:= name PoseStamped topics" in m for m in ev.logs), ev.logs
    assert "mocap_bridge" not in _by_exe(ev)
