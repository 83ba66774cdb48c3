"""Bags -> dataset export (aslip_ros.data.export), including every bad-input case."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros import cli
from aslip_ros.data import bags
from aslip_ros.data.dataset import Dataset
from aslip_ros.data.export import ExportConfig, export
from aslip_ros.data.synthetic import write_synthetic_bag

FINGER = np.concatenate([[0.5, 0.2, 0.3],
                         Rotation.from_euler("xyz", [20, -30, 75], degrees=True).as_quat()])
CALIB = np.concatenate([[0.0, 0.01, -0.02],
                        Rotation.from_euler("xyz", [0, 0, 180], degrees=True).as_quat()])


def leftovers(root):
    """Anything an export left beside its target (temporary directories included)."""
    return sorted(p.name for p in root.iterdir() if p.name != "bags")


def test_export_other_hardware_without_metadata(tmp_path):
    # 44.1 kHz, 100 Hz mocap, three channels with other names, no scenario metadata.
    names = ["mic_a", "mic_b", "mic_c"]
    write_synthetic_bag(tmp_path / "bags" / "rec_001", duration_s=3.0, sample_rate=44100.0,
                        channel_names=names, block_frames=441, pose_rate_hz=100.0,
                        slip_velocity=(0.03, 0.01, 0.0), finger_pose=FINGER,
                        finger_velocity=(0.02, 0.0, -0.01), metadata=False, layout="")
    s = export([tmp_path / "bags"], tmp_path / "ds", progress=False)
    ds = Dataset(tmp_path / "ds")
    assert ds.sample_rate == 44100.0 and ds.channel_names == names
    assert ds.n_window_samples == 8820 and ds.layout == ""
    t = ds.trials[0]
    assert t["id"] == "rec_001" and t["object"] == "unknown" and t["label_source"] == "mocap"
    assert t["label_rate_hz"] == pytest.approx(100.0)
    assert len(ds) == s.kept >= 25
    # It says so, and what it took from the data instead.
    note = [w for w in s.warnings if "has no metadata" in w]
    assert len(note) == 1 and "rec_001" in note[0], s.warnings
    assert "sample rate, channel names" in note[0] and "identity grasp-plane" in note[0]
    assert "has no metadata" in str(s)
    w = np.asarray(ds.windows)
    np.testing.assert_allclose(w["vx"], 0.03, atol=1e-5)
    np.testing.assert_allclose(w["vz"], 0.0, atol=1e-5)
    assert w["slip"].all()
    a, row = ds.window(3)
    assert a.shape == (8820, 3) and a.dtype == np.float32
    np.testing.assert_array_equal(a, np.load(tmp_path / "ds" / "audio" / "0.npy")[
        row["start"]:row["start"] + 8820])


def test_export_robot_and_external_with_calibration(tmp_path):
    write_synthetic_bag(tmp_path / "bags" / "ext", duration_s=2.0, finger_pose=FINGER,
                        calibration=CALIB, slip_velocity=(0.02, 0.0, -0.01))
    write_synthetic_bag(tmp_path / "bags" / "rob", duration_s=2.0, induced="robot", seed=1,
                        finger_pose=FINGER, calibration=CALIB, slip_velocity=(0.0, 0.0, 0.002))
    s = export([tmp_path / "bags"], tmp_path / "ds", window_s=0.1, hop_s=0.05,
               epsilon_m_s=0.005, progress=False)
    ds = Dataset(tmp_path / "ds")
    assert [t["label_source"] for t in ds.trials] == ["mocap", "robot"]
    ext = np.asarray(ds.windows[ds.select(induced="external")])
    rob = np.asarray(ds.windows[ds.select(induced="robot")])
    np.testing.assert_allclose(ext["vx"], 0.02, atol=1e-5)
    np.testing.assert_allclose(ext["vz"], -0.01, atol=1e-5)
    assert ext["slip"].all()
    np.testing.assert_allclose(rob["vz"], 0.002, atol=1e-6)
    assert not rob["slip"].any()             # 2 mm/s is below epsilon
    assert ds.n_window_samples == 4800 and ds.hop_s == 0.05
    assert "windows kept" in str(s) and s.kept == len(ds)


def test_forced_label_source_and_custom_topics(tmp_path):
    topics = bags.Topics(audio="/mics", tcp="/arm/pose")
    write_synthetic_bag(tmp_path / "rob", duration_s=1.0, induced="robot", topics=topics)
    with pytest.raises(bags.BagError, match="/aslip/audio"):
        export([tmp_path / "rob"], tmp_path / "ds", progress=False)
    with pytest.raises(bags.BagError, match="/aslip/mocap/finger"):
        export([tmp_path / "rob"], tmp_path / "ds", label_source="mocap", topics=topics,
               progress=False)
    s = export([tmp_path / "rob"], tmp_path / "ds", topics=topics, progress=False)
    assert s.kept > 0
    assert leftovers(tmp_path) == ["ds", "rob"]


def test_missing_topic_names_it(tmp_path):
    with bags.BagWriter(tmp_path / "b") as w:
        w.write_pose("finger", 0.0, [0, 0, 0, 0, 0, 0, 1])
        w.write_pose("object", 0.0, [0, 0, 0, 0, 0, 0, 1])
    with pytest.raises(ValueError, match=r"no topic /aslip/audio"):
        export([tmp_path / "b"], tmp_path / "ds", progress=False)
    assert not (tmp_path / "ds").exists()


def test_audio_gap_windows_dropped_and_counted(tmp_path):
    write_synthetic_bag(tmp_path / "b", duration_s=2.0, audio_dropouts=[(1.0, 1.05)])
    s = export([tmp_path / "b"], tmp_path / "ds", window_s=0.2, hop_s=0.1, progress=False)
    starts = np.arange(0.0, 2.0 - 0.2 + 1e-9, 0.1)
    crossing = int(np.sum((starts < 1.05 - 1e-9) & (starts + 0.2 > 1.0 + 1e-9)))
    assert crossing == 2
    assert s.dropped["audio_gap"] == crossing
    ds = Dataset(tmp_path / "ds")
    assert ds.trials[0]["audio_gaps"] == 1
    assert ds.trials[0]["n_samples"] == 96000 - 2400
    assert len(ds) + crossing + s.dropped["label_coverage"] == starts.size
    # Windows after the gap point at the right audio: the synthetic noise repeats every
    # 48000 frames of stream index, and the file lacks the 2400 frames of the gap.
    noise = (0.01 * np.random.default_rng(0).standard_normal((48000, 4))).astype(np.float32)
    after = [int(r["start"]) for r in np.asarray(ds.windows) if r["start"] >= 48000]
    assert after
    for start in after:
        stream_index = start + 2400
        expect = noise[np.arange(stream_index, stream_index + 9600) % 48000]
        np.testing.assert_array_equal(ds.window_audio(0, start), expect)


def test_mocap_dropouts_interpolated_or_dropped(tmp_path):
    write_synthetic_bag(tmp_path / "short", duration_s=2.0, pose_dropouts=[(0.5, 0.54)],
                        slip_velocity=(0.01, 0, 0.01))
    write_synthetic_bag(tmp_path / "long", duration_s=2.0, pose_dropouts=[(0.5, 0.8)],
                        slip_velocity=(0.01, 0, 0.01), seed=1)
    s1 = export([tmp_path / "short"], tmp_path / "d1", progress=False)
    assert s1.dropped["label_gap"] == 0
    s2 = export([tmp_path / "long"], tmp_path / "d2", progress=False, max_gap_s=0.05)
    assert s2.dropped["label_gap"] >= 4
    assert s2.kept == s1.kept - s2.dropped["label_gap"]
    w = np.asarray(Dataset(tmp_path / "d2").windows)
    np.testing.assert_allclose(w["vx"], 0.01, atol=1e-5)
    assert "label_gap" in str(s2)


@pytest.mark.parametrize("damage", ["truncate", "garbage_yaml", "no_storage"])
def test_corrupt_or_truncated_bag_clear_error_no_partial_dataset(tmp_path, damage):
    write_synthetic_bag(tmp_path / "bags" / "a_good", duration_s=1.0)
    bad = tmp_path / "bags" / "b_bad"
    write_synthetic_bag(bad, duration_s=1.0)
    mcap = bad / "b_bad.mcap"
    if damage == "truncate":
        data = mcap.read_bytes()
        mcap.write_bytes(data[:len(data) // 2])
    elif damage == "garbage_yaml":
        (bad / "metadata.yaml").write_text("rosbag2_bagfile_information: [oops\n")
    else:
        mcap.unlink()
    with pytest.raises(bags.BagError, match="b_bad"):
        export([tmp_path / "bags"], tmp_path / "ds", progress=False)
    assert leftovers(tmp_path) == []
    # With skip_bad the good bag is exported and the bad one reported.
    s = export([tmp_path / "bags"], tmp_path / "ds", progress=False, skip_bad=True)
    assert len(Dataset(tmp_path / "ds").trials) == 1
    assert "skipped" in str(s) and "b_bad" in str(s)


def test_truncated_in_the_middle_of_the_data(tmp_path):
    # Keep the footer but cut a chunk: the error surfaces while reading messages.
    bad = tmp_path / "b"
    write_synthetic_bag(bad, duration_s=3.0)
    mcap = bad / "b.mcap"
    data = bytearray(mcap.read_bytes())
    data[200:len(data) // 2] = b"\0" * (len(data) // 2 - 200)
    mcap.write_bytes(bytes(data))
    with pytest.raises(bags.BagError, match="cannot read bag"):
        export([bad], tmp_path / "ds", progress=False)
    assert leftovers(tmp_path) == ["b"]


def test_inconsistent_sample_rate_or_channels(tmp_path):
    write_synthetic_bag(tmp_path / "a", duration_s=0.5)
    write_synthetic_bag(tmp_path / "b", duration_s=0.5, sample_rate=44100.0, block_frames=441)
    write_synthetic_bag(tmp_path / "c", duration_s=0.5, channel_names=["w", "x", "y", "z"])
    with pytest.raises(ValueError, match="sample rate 44100 Hz differs"):
        export([tmp_path / "a", tmp_path / "b"], tmp_path / "ds", progress=False)
    with pytest.raises(ValueError, match="channel names"):
        export([tmp_path / "a", tmp_path / "c"], tmp_path / "ds", progress=False)
    write_synthetic_bag(tmp_path / "d", duration_s=0.5, layout="2mic_x")
    with pytest.raises(ValueError, match="layouts differ"):
        export([tmp_path / "a", tmp_path / "d"], tmp_path / "ds", progress=False)
    assert not (tmp_path / "ds").exists()


def test_bad_parameters_and_existing_output(tmp_path):
    write_synthetic_bag(tmp_path / "a", duration_s=0.5)
    for kw in ({"window_s": 0}, {"hop_s": -1}, {"epsilon_m_s": -0.1},
               {"label_source": "vision"}, {"label_smoothing_s": -0.1},
               {"label_smoothing_s": float("nan")}):
        with pytest.raises(ValueError):
            export([tmp_path / "a"], tmp_path / "ds", progress=False, **kw)
    export([tmp_path / "a"], tmp_path / "ds", progress=False)
    with pytest.raises(FileExistsError):
        export([tmp_path / "a"], tmp_path / "ds", progress=False)
    export([tmp_path / "a"], tmp_path / "ds", ExportConfig(overwrite=True, progress=False))
    with pytest.raises(ValueError, match="no rosbag2 bags"):
        export([tmp_path / "ds"], tmp_path / "ds2", progress=False)


def test_duplicate_trial_ids_are_renamed(tmp_path):
    write_synthetic_bag(tmp_path / "a", duration_s=0.5)
    write_synthetic_bag(tmp_path / "b", duration_s=0.5)       # same metadata trial id
    s = export([tmp_path / "a", tmp_path / "b"], tmp_path / "ds", progress=False)
    ids = [t["id"] for t in Dataset(tmp_path / "ds").trials]
    assert len(set(ids)) == 2 and s.warnings


def test_cli(tmp_path, capsys):
    write_synthetic_bag(tmp_path / "a", duration_s=1.0)
    rc = cli.main(["export", str(tmp_path / "a"), "-o", str(tmp_path / "ds"), "--window",
                   "0.3", "--hop", "0.15", "--no-progress", "--summary-json",
                   str(tmp_path / "s.json")])
    assert rc == 0
    assert "windows kept" in capsys.readouterr().out
    assert json.loads((tmp_path / "s.json").read_text())["kept"] == len(
        Dataset(tmp_path / "ds"))
    assert Dataset(tmp_path / "ds").window_s == 0.3
    rc = cli.main(["export", str(tmp_path / "a"), "-o", str(tmp_path / "ds2"),
                   "--audio-topic", "/nothing", "--no-progress"])
    assert rc == 1 and "/nothing" in capsys.readouterr().err


def test_export_benchmark_reports_the_childs_own_peak_memory(tmp_path):
    """Regression: the peak RSS came from RUSAGE_CHILDREN, the largest child ever waited
    for, so an earlier big child (a training job) showed up as the export's memory."""
    import subprocess
    import sys

    from aslip_ros.data.export import measure_export_speed
    big = "bytearray(600 * 2**20)"              # a 600 MiB child, waited for first
    subprocess.run([sys.executable, "-c", f"b = {big}; b[::4096] = b'x' * len(b[::4096])"],
                   check=True)
    res = measure_export_speed(duration_s=2.0, workdir=tmp_path)
    assert 20.0 < res["peak_rss_mib"] < 500.0


def test_export_benchmark_memory_is_not_its_big_parents(tmp_path):
    """Regression: a child started by vfork reported its parent's peak (ru_maxrss survives
    the exec), so the benchmark run after training showed the test process's memory."""
    from aslip_ros.data.export import measure_export_speed
    ballast = bytearray(700 * 2**20)
    ballast[::4096] = b"x" * len(ballast[::4096])       # resident in this process
    res = measure_export_speed(duration_s=2.0, workdir=tmp_path)
    del ballast
    assert 20.0 < res["peak_rss_mib"] < 500.0
    assert res["windows"] > 0 and res["realtime_factor"] > 0


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_full_disk_is_one_error_line_naming_the_dataset(tmp_path, monkeypatch, capsys):
    """Regression: a full disk gave two chained OSError tracebacks without the path."""
    from aslip_ros.data import dataset as dataset_mod
    write_synthetic_bag(tmp_path / "bags" / "a", duration_s=1.0)

    def full_disk_open(path, mode="r", *a, **kw):
        # Audio goes to a device that refuses every byte with ENOSPC, as a full disk does;
        # closing the file then fails again when it flushes its buffer.
        if str(path).endswith(".part"):
            return open("/dev/full", mode, *a, **kw)
        return open(path, mode, *a, **kw)

    monkeypatch.setattr(dataset_mod, "open", full_disk_open, raising=False)
    out = tmp_path / "ds"
    rc = cli.main(["export", str(tmp_path / "bags"), "-o", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1 and str(out) in err[0] and "No space left" in err[0], err
    assert leftovers(tmp_path) == []


def test_unwritable_output_is_one_error_line(tmp_path, capsys):
    write_synthetic_bag(tmp_path / "bags" / "a", duration_s=0.5)
    blocker = tmp_path / "file"
    blocker.write_text("a file where the dataset's parent directory should be")
    rc = cli.main(["export", str(tmp_path / "bags"), "-o", str(blocker / "ds"),
                   "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and str(blocker / "ds") in err[0], err


@pytest.mark.parametrize("bad, reason", [(np.nan, "non_finite"), (7.0, "out_of_range")])
def test_a_block_the_node_refuses_is_refused_offline_too(tmp_path, monkeypatch, bad, reason):
    """A corrupt AudioFrame (NaN, or beyond full scale) in a bag: the exporter refuses that
    block with the live node's own check, exactly as if it had not been recorded (its
    windows are audio gaps), and says so; it never reaches the dataset."""
    from aslip_ros.audio_frame import AudioFrameError, decode_audio_frame
    original = bags.BagWriter.write_audio
    corrupt = {"mode": "corrupt"}

    def write_audio(self, t, first_sample_index, block, *args, **kwargs):
        if first_sample_index == 48000:
            if corrupt["mode"] == "skip":
                return
            block = np.array(block, copy=True)
            block[10, 1] = bad
        return original(self, t, first_sample_index, block, *args, **kwargs)

    monkeypatch.setattr(bags.BagWriter, "write_audio", write_audio)
    write_synthetic_bag(tmp_path / "bad", duration_s=2.0)
    corrupt["mode"] = "skip"
    write_synthetic_bag(tmp_path / "missing", duration_s=2.0)
    with bags.BagReader(tmp_path / "bad") as r:
        msg = next(m.msg for m in r.messages(["/aslip/audio"])
                   if m.msg.first_sample_index == 48000)
    with pytest.raises(AudioFrameError) as info:       # what the node's decode says
        decode_audio_frame(msg)
    assert info.value.reason == reason
    s_bad = export([tmp_path / "bad"], tmp_path / "ds_bad", progress=False)
    s_ref = export([tmp_path / "missing"], tmp_path / "ds_ref", progress=False)
    assert s_bad.dropped == s_ref.dropped and s_bad.dropped["audio_gap"] > 0
    assert s_bad.bags[0].refused_blocks == {reason: 1}
    assert any(reason in w and "refused" in w for w in s_bad.warnings), s_bad.warnings
    bad, ref = Dataset(tmp_path / "ds_bad"), Dataset(tmp_path / "ds_ref")
    np.testing.assert_array_equal(np.asarray(bad.windows), np.asarray(ref.windows))
    audio = np.load(tmp_path / "ds_bad" / "audio" / "0.npy")
    assert np.isfinite(audio).all() and np.abs(audio).max() <= 1.0


def test_a_calibration_with_a_near_zero_quaternion_is_refused(tmp_path):
    """The bag's calibration is checked by the one pose algebra: a 1e-8 quaternion is noise,
    not a rotation to normalise."""
    write_synthetic_bag(tmp_path / "b", duration_s=1.0,
                        metadata={"induced": "external",
                                  "grasp_plane_in_finger": [0, 0, 0, 0, 0, 0, 1e-8]})
    with pytest.raises(ValueError, match="grasp_plane_in_finger must be a pose"):
        export([tmp_path / "b"], tmp_path / "ds", progress=False)
    assert not (tmp_path / "ds").exists()


def test_pose_topics_named_in_the_metadata_need_no_flags(tmp_path, capsys):
    """A cell whose mocap driver publishes on its own names: the recording's metadata
    names them (data_collection.launch.py writes it) and export follows it, from the CLI
    too; a flag given still wins."""
    topics = bags.Topics(finger="/natnet/finger/pose", object="/natnet/object/pose")
    write_synthetic_bag(tmp_path / "bags" / "hw", duration_s=1.5, topics=topics,
                        extra_metadata={"topics": {"finger": topics.finger,
                                                   "object": topics.object,
                                                   "tcp": "/aslip/robot/tcp_pose"}})
    rc = cli.main(["export", str(tmp_path / "bags"), "-o", str(tmp_path / "ds"),
                   "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    assert len(Dataset(tmp_path / "ds")) > 0
    rc = cli.main(["export", str(tmp_path / "bags"), "-o", str(tmp_path / "ds2"),
                   "--finger-topic", "/elsewhere", "--no-progress"])
    assert rc == 1 and "/elsewhere" in capsys.readouterr().err
