"""aslip export of a recording whose poses are mocap4r2 RigidBodies (no PoseStamped): the
same dataset as the PoseStamped recording of the same motion.

The RigidBodies bag is written with rosbags from mocap4r2's message layout (the test
stand-in's .msg files); the exporter registers the type from the definition the bag stores.
Each message holds every body as the OptiTrack driver sends them (named by their numeric
ID, frame ``map``, the header stamped before the receive time), here three: 1 (a still
marker set), 3 (the finger) and 5 (the object).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros import cli
from aslip_ros.data.bags import BagError, BagReader, BagWriter
from aslip_ros.data.export import export
from aslip_ros.data.synthetic import write_synthetic_bag

ROOT = Path(__file__).resolve().parents[1]
MSG_DIR = ROOT / "test" / "msgs" / "mocap4r2_msgs" / "msg"
RB = "mocap4r2_msgs/msg/RigidBodies"
FINGER = np.concatenate([[0.5, 0.2, 0.3],
                         Rotation.from_euler("xyz", [20, -30, 75], degrees=True).as_quat()])
CALIB = np.concatenate([[0.0, 0.01, -0.02],
                        Rotation.from_euler("xyz", [0, 0, 180], degrees=True).as_quat()])
STILL = [1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0]
LATENCY_NS = 3_000_000


def _store():
    """The project's typestore plus mocap4r2's messages, from their .msg text."""
    from rosbags.typesys import get_types_from_msg

    from aslip_ros.data.bag_format import project_store
    store = project_store()
    types = {}
    for p in sorted(MSG_DIR.glob("*.msg")):
        types.update(get_types_from_msg(p.read_text(), f"mocap4r2_msgs/msg/{p.stem}"))
    store.register(types)
    return store


def _rigid_bodies(store, stamp_ns, bodies):
    T = store.types

    def body(name, p):
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
            orientation=T["geometry_msgs/msg/Quaternion"](x=p[3], y=p[4], z=p[5], w=p[6]))
        return T["mocap4r2_msgs/msg/RigidBody"](rigid_body_name=name, markers=[], pose=pose)
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
        sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id="map")
    return T[RB](header=header, frame_number=0,
                 rigidbodies=[body(n, p) for n, p in bodies])


def as_rigid_bodies(src: Path, dst: Path, bodies=("3", "5"), meta_bodies=True,
                    keep=lambda k: ("1", "3", "5")) -> None:
    """Rewrite a PoseStamped recording as mocap4r2 would have recorded it: each finger and
    object pose pair as one RigidBodies on /rigid_bodies (bodies ``keep(k)`` of the k-th),
    received LATENCY_NS after its stamp; the metadata naming that topic and the bodies."""
    store = _store()
    with BagReader(src) as r:
        meta = dict(r.read_metadata())
        msgs = list(r.messages())
    meta["topics"] = dict(meta.get("topics", {}), finger="/rigid_bodies",
                          object="/rigid_bodies")
    if meta_bodies:
        meta["bodies"] = {"finger": bodies[0], "object": bodies[1]}
    pending = {}
    k = 0
    with BagWriter(dst, metadata=meta, store=store) as w:
        for m in msgs:
            if m.topic in ("/aslip/mocap/finger", "/aslip/mocap/object"):
                p = m.msg.pose
                pending[m.topic] = [p.position.x, p.position.y, p.position.z,
                                    p.orientation.x, p.orientation.y, p.orientation.z,
                                    p.orientation.w]
                if len(pending) == 2:
                    stamp = m.msg.header.stamp.sec * 10**9 + m.msg.header.stamp.nanosec
                    of = {"1": STILL, "3": pending["/aslip/mocap/finger"],
                          "5": pending["/aslip/mocap/object"]}
                    w.write("/rigid_bodies", RB, _rigid_bodies(
                        store, stamp, [(n, of[n]) for n in keep(k)]), stamp + LATENCY_NS)
                    pending, k = {}, k + 1
            elif m.topic != "/aslip/metadata":
                w.write(m.topic, m.msgtype, m.msg, m.log_ns)


@pytest.fixture
def pose_bag(tmp_path):
    path = tmp_path / "poses" / "trial"
    write_synthetic_bag(path, duration_s=2.0, finger_pose=FINGER, calibration=CALIB,
                        slip_velocity=(0.02, 0.0, -0.01), pose_rate_hz=120.0)
    return path


def _same_dataset(a: Path, b: Path) -> None:
    for name in ("windows.npy", "tracks/0.npy", "audio/0.npy"):
        np.testing.assert_array_equal(np.load(a / name), np.load(b / name), err_msg=name)
    ta, tb = (json.loads((d / "manifest.json").read_text())["trials"][0] for d in (a, b))
    for t in (ta, tb):
        t.pop("source_bag")
    assert ta == tb


def test_a_rigid_bodies_recording_exports_as_its_pose_stamped_twin(pose_bag, tmp_path):
    rigid = tmp_path / "rigid" / "trial"
    as_rigid_bodies(pose_bag, rigid)
    with BagReader(rigid) as r:
        assert r.info.topics["/rigid_bodies"] == RB
        assert "/aslip/mocap/finger" not in r.info.topics
    export([pose_bag], tmp_path / "ds_poses", progress=False)
    s = export([rigid], tmp_path / "ds_rigid", progress=False)
    assert s.kept > 10 and not [w for w in s.warnings if "rigid body" in w]
    _same_dataset(tmp_path / "ds_poses", tmp_path / "ds_rigid")


def test_bodies_given_on_the_command_line_by_name_or_id(pose_bag, tmp_path, capsys):
    """A bag whose metadata names no bodies: refused, naming the bodies it holds; the
    options pick them (an ID however written)."""
    rigid = tmp_path / "rigid" / "trial"
    as_rigid_bodies(pose_bag, rigid, meta_bodies=False)
    with pytest.raises(BagError, match=r"name the finger and object bodies \(--finger-body "
                       r"--object-body.*bodies in its first message: '1', '3', '5'"):
        export([rigid], tmp_path / "refused", progress=False)
    assert cli.main(["export", str(rigid), "-o", str(tmp_path / "ds_rigid"), "--no-progress",
                     "--finger-body", "3", "--object-body", "05"]) == 0
    export([pose_bag], tmp_path / "ds_poses", progress=False)
    _same_dataset(tmp_path / "ds_poses", tmp_path / "ds_rigid")


def test_a_missing_body_is_a_dropout_and_an_absent_one_refuses_the_bag(pose_bag, tmp_path):
    gappy = tmp_path / "gappy" / "trial"
    as_rigid_bodies(pose_bag, gappy, keep=lambda k: ("1", "3") if 60 <= k < 90 else
                    ("5", "1", "3"))
    s = export([gappy], tmp_path / "ds", progress=False, max_gap_s=0.05)
    note = [w for w in s.warnings if "rigid body" in w]
    assert len(note) == 1 and "rigid body '5' (object) is missing from 30 of the 241 " \
        "RigidBodies messages on /rigid_bodies; bodies present: '5', '1', '3'" in note[0]
    assert s.dropped["label_gap"] > 0
    absent = tmp_path / "absent" / "trial"
    as_rigid_bodies(pose_bag, absent, bodies=("3", "7"))
    with pytest.raises(BagError, match=r"rigid body '7' \(object\) is in none of the 241 "
                       r"RigidBodies messages on /rigid_bodies; bodies present: '1', '3', '5'"):
        export([absent], tmp_path / "refused", progress=False)
