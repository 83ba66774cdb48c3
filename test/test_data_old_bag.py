"""Recordings and datasets from before rotational slip (issue #21) still work.

A bag recorded with the old ``SlipVector`` definition (no ``angular_velocity`` fields) is
read with the definition it stores, exports, and gets ``wy`` labels from its motion capture;
a version 1 dataset (no ``wy`` column) loads with ``wy`` NaN, "no angular label".
"""

import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros import topics
from aslip_ros.data import bags
from aslip_ros.data.dataset import (VERSION, WINDOW_DTYPE, WINDOW_DTYPE_V1, Dataset,
                                    upgrade_windows)
from aslip_ros.data.export import export
from aslip_ros.data.stream_labels import TRACK_COLUMNS, frame_labels, load_track

NEW_FIELDS = ("angular_velocity", "angular_velocity_sigma")
SR = 48000.0
NAMES = ["left", "right"]
WY = 1.2                                       # rad/s about the pad normal
PIVOT = np.array([0.02, 0.0, -0.03])           # the object turns about this pad point
FINGER = np.concatenate([[0.4, 0.1, 0.3],
                         Rotation.from_euler("xyz", [0, 0, 90], degrees=True).as_quat()])


def old_slip_vector_text() -> str:
    """SlipVector.msg as it was before issue #21: today's file without the new fields."""
    text = bags.project_msg_texts()[bags.SLIP_TYPE]
    assert all(re.search(rf"^float32 {f}\s*$", text, re.M) for f in NEW_FIELDS)
    return "\n".join(line for line in text.splitlines()
                     if not any(re.fullmatch(rf"float32 {f}\s*", line) for f in NEW_FIELDS))


def old_store():
    """A typestore with the project's types, SlipVector in its old definition."""
    from rosbags.typesys import get_types_from_msg
    store = bags.base_store()
    types = {}
    for name, text in bags.project_msg_texts().items():
        types.update(get_types_from_msg(old_slip_vector_text() if name == bags.SLIP_TYPE
                                        else text, name))
    store.register(types)
    return store


def object_pose(t: float) -> np.ndarray:
    """The object turning at WY about PIVOT (grasp plane = the finger), its origin off the
    pad centre."""
    q = Rotation.from_rotvec([0.0, WY * t, 0.0])
    r = PIVOT + q.apply(np.array([0.01, 0.003, 0.02]) - PIVOT)
    rf = Rotation.from_quat(FINGER[3:])
    return np.concatenate([FINGER[:3] + rf.apply(r), (rf * q).as_quat()])


def write_bag(path, store=None, duration=2.0):
    """Audio, finger and object poses, and SlipVectors on /aslip/slip and the truth topic
    in ``store``'s SlipVector definition (default: the project's)."""
    rng = np.random.default_rng(0)
    meta = bags.make_metadata(sample_rate=SR, channel_names=NAMES, layout="2mic",
                              object="pan", induced="external", condition="robot_off",
                              trial_id="old-0001")
    with bags.BagWriter(path, metadata=meta, start_ns=10**18, store=store) as w:
        T = w._store.types
        fields = T[bags.SLIP_TYPE].__dataclass_fields__
        k_pose = 0
        for first in range(0, int(duration * SR), 480):
            t = first / SR
            while k_pose / 120.0 <= t:
                tp = k_pose / 120.0
                w.write_pose("finger", tp, FINGER)
                w.write_pose("object", tp, object_pose(tp))
                k_pose += 1
            w.write_audio(t, first, (0.01 * rng.standard_normal((480, 2))).astype(np.float32),
                          SR, NAMES, "2mic")
            if first % 4800 == 0 and t > 0:
                extra = {f: 0.0 for f in NEW_FIELDS if f in fields}
                msg = T[bags.SLIP_TYPE](
                    header=w._header(w._ns(t), "aslip_grasp_plane"), probability=0.9,
                    slipping=True, threshold=0.5,
                    velocity=T["geometry_msgs/msg/Vector3"](x=0.06, y=0.0, z=0.024),
                    speed=0.0646, direction=0.38, direction_sigma=-1.0, window_length=0.2,
                    source="aslip_cnn", **extra)
                w.write(topics.SLIP, bags.SLIP_TYPE, msg, w._ns(t))


def stored_definition(path) -> str:
    with bags.BagReader(path) as r:
        (conn,) = [c for c in r._reader.connections if c.topic == topics.SLIP]
        return conn.msgdef.data


def expected_labels():
    """(vx, vz, wy) of a turn about PIVOT: the pad centre's point moves at -w x c."""
    return -WY * PIVOT[2], WY * PIVOT[0], WY


def test_old_definition_bag_exports_with_wy_labels(tmp_path):
    write_bag(tmp_path / "bags" / "old", store=old_store())
    definition = stored_definition(tmp_path / "bags" / "old")
    assert "direction_sigma" in definition and "angular_velocity" not in definition
    s = export([tmp_path / "bags"], tmp_path / "ds", progress=False)
    ds = Dataset(tmp_path / "ds")
    assert ds.version == VERSION == 2 and ds.windows.dtype == WINDOW_DTYPE
    assert len(ds) == s.kept >= 15
    vx, vz, wy = expected_labels()
    w = np.asarray(ds.windows)
    np.testing.assert_allclose(w["wy"], wy, atol=1e-5)
    # The pad centre's point runs on a circle, which the labels' quadratic smoothing of the
    # poses follows to 0.01 mm/s (the first window, where the fit meets the track's start).
    np.testing.assert_allclose(w["vx"], vx, atol=5e-5)
    np.testing.assert_allclose(w["vz"], vz, atol=5e-5)
    assert w["slip"].all()             # 42 mm/s at the pad centre: planar slip as well
    # The streaming labels' track has the rotation columns and gives the same motion.
    tr = load_track(tmp_path / "ds", 0)
    assert tr.shape[1] == TRACK_COLUMNS
    lab = frame_labels(tr, np.array([0.6, 1.2]) * SR, SR, ds.epsilon_m_s)
    np.testing.assert_allclose(lab["wy"], wy, atol=1e-3)
    np.testing.assert_allclose(lab["v"], [[vx, vz]] * 2, rtol=0.01)


def test_old_slip_vectors_decode_with_the_bags_definition(tmp_path):
    write_bag(tmp_path / "old", store=old_store(), duration=1.0)
    with bags.BagReader(tmp_path / "old") as r:
        msgs = list(r.messages([topics.SLIP]))
    assert len(msgs) == 9
    for m in msgs:
        assert m.msgtype == bags.SLIP_TYPE and m.msg.source == "aslip_cnn"
        assert (m.msg.velocity.x, m.msg.velocity.z) == pytest.approx((0.06, 0.024))
        assert m.msg.window_length == pytest.approx(0.2)
        assert not hasattr(m.msg, "angular_velocity")
    # Read with today's definition instead, the same bytes would not decode as they were
    # written: the reader must take the bag's own definition.
    with bags.BagReader(tmp_path / "old") as r:
        raw = next(raw for c, _, raw in r._reader.messages()
                   if c.topic == topics.SLIP)
    try:
        wrong = bags.typestore().deserialize_cdr(raw, bags.SLIP_TYPE)
    except Exception:                  # noqa: BLE001 (any decoder error is the point)
        wrong = None
    assert wrong is None or wrong.window_length != pytest.approx(0.2)


def test_new_definition_bag_carries_the_angular_velocity(tmp_path):
    write_bag(tmp_path / "new", duration=0.5)
    with bags.BagWriter(tmp_path / "truth") as w:
        w.write_slip_truth(0.2, 0.0, 0.0, 0.2, 0.005, wy=-0.8)
    assert "float32 angular_velocity" in stored_definition(tmp_path / "new")
    with bags.BagReader(tmp_path / "truth") as r:
        (m,) = list(r.messages([topics.SLIP_TRUTH]))
    # A pure rotation: not slipping (planar), the angular velocity published all the same.
    assert not m.msg.slipping and m.msg.angular_velocity == pytest.approx(-0.8)
    assert m.msg.angular_velocity_sigma == -1.0


# --------------------------------------------------------------------------- datasets

def write_v1_dataset(root):
    """A dataset as version 1 wrote it: no wy column, manifest version 1."""
    (root / "audio").mkdir(parents=True)
    np.save(root / "audio" / "0.npy", np.zeros((4000, 2), np.float32))
    rows = np.zeros(3, WINDOW_DTYPE_V1)
    rows["start"] = [0, 1000, 2000]
    rows["vx"] = [0.0, 0.01, 0.02]
    rows["speed"] = np.abs(rows["vx"])
    rows["slip"] = rows["speed"] > 0.005
    np.save(root / "windows.npy", rows)
    trial = {"id": "t0", "file": "audio/0.npy", "n_samples": 4000, "object": "can",
             "pad": "textured", "layout": "2mic", "condition": "robot_off",
             "induced": "external", "source_bag": "", "label_source": "mocap"}
    (root / "manifest.json").write_text(json.dumps({
        "format": "aslip-dataset", "version": 1, "sample_rate": 10000.0,
        "channel_names": NAMES, "layout": "2mic", "window_s": 0.2, "hop_s": 0.1,
        "epsilon_m_s": 0.005, "n_windows": 3, "trials": [trial]}))
    return rows


def test_version_1_dataset_loads_with_wy_nan(tmp_path):
    rows = write_v1_dataset(tmp_path / "v1")
    ds = Dataset(tmp_path / "v1")
    assert ds.version == 1 and ds.windows.dtype == WINDOW_DTYPE and len(ds) == 3
    assert np.isnan(ds.windows["wy"]).all()
    for name in WINDOW_DTYPE_V1.names:
        np.testing.assert_array_equal(ds.windows[name], rows[name])
    audio, row = ds.window(1)
    assert audio.shape == (2000, 2) and row["start"] == 1000 and np.isnan(row["wy"])
    assert list(ds.select(object="can")) == [0, 1, 2]


def test_dataset_tables_must_match_their_version(tmp_path):
    write_v1_dataset(tmp_path / "v1")
    man = tmp_path / "v1" / "manifest.json"
    doc = json.loads(man.read_text())
    doc["version"] = 2                    # says v2, holds a v1 table
    man.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="windows.npy has dtype"):
        Dataset(tmp_path / "v1")
    doc["version"] = 3
    man.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="newer than this reader"):
        Dataset(tmp_path / "v1")


def test_upgrade_windows():
    old = np.zeros(2, WINDOW_DTYPE_V1)
    old["vz"] = [0.5, -0.5]
    new = upgrade_windows(old)
    assert new.dtype == WINDOW_DTYPE and np.isnan(new["wy"]).all()
    np.testing.assert_array_equal(new["vz"], old["vz"])
    assert upgrade_windows(new) is new
    with pytest.raises(ValueError, match="dtype"):
        upgrade_windows(np.zeros(2, [("x", "<f4")]))
