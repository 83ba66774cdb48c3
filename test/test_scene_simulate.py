"""Scene -> bags (aslip_ros.scene.simulate) and the dataset presets."""

import json
from dataclasses import dataclass

import numpy as np
import pytest

from aslip_ros import cli
from aslip_ros.data import bags
from aslip_ros.data.dataset import Dataset
from aslip_ros.data.labels import DEFAULT_LABEL_SMOOTHING_S
from aslip_ros.data.export import export
from aslip_ros.scene.presets import SCALES, build_default_datasets
from aslip_ros.scene.simulate import plan_trials, record_world, trial_seed


@dataclass
class Sample:
    t: float
    finger_pose: np.ndarray
    object_pose: np.ndarray


@dataclass
class Chunk:
    first_sample_index: int
    t0: float
    audio: np.ndarray
    mocap: list
    tcp: list


class FakeWorld:
    """Streaming API of docs/design.md with a known +x slip of 0.02 m/s."""

    def __init__(self, fs=16000.0, seconds=1.0, names=("l", "r")):
        self.fs, self.seconds, self.names = fs, seconds, list(names)

    def metadata(self):
        return bags.make_metadata(sample_rate=self.fs, channel_names=self.names,
                                  layout="2mic", object="box", induced="external",
                                  condition="robot_off", trial_id="fake-0")

    def stream(self, block_frames=480):
        n = int(self.fs * self.seconds)
        q = np.array([0, 0, 0, 1.0])
        k = 0
        for first in range(0, n, block_frames):
            t0 = first / self.fs
            mocap = []
            while k / 100.0 < (first + block_frames) / self.fs:
                t = k / 100.0
                mocap.append(Sample(t, np.r_[0, 0, 0, q], np.r_[0.02 * t, 0, 0, q]))
                k += 1
            yield Chunk(first, t0, np.zeros((min(block_frames, n - first), 2), np.float32),
                        mocap, [(t0, np.r_[0, 0, 0.1, q])])


def test_record_world_streams_into_a_bag(tmp_path):
    counts = record_world(FakeWorld(), tmp_path / "bag", block_frames=400)
    assert counts["audio"] == 40 and counts["tcp"] == 40 and counts["mocap"] == 100
    with bags.BagReader(tmp_path / "bag") as r:
        assert r.metadata["trial_id"] == "fake-0"
        assert r.info.counts["/aslip/mocap/finger"] == 100
    s = export([tmp_path / "bag"], tmp_path / "ds", progress=False)
    w = np.asarray(Dataset(tmp_path / "ds").windows)
    assert s.kept > 0
    np.testing.assert_allclose(w["vx"], 0.02, atol=1e-6)


def test_plan_and_seeds_are_stable_and_layout_independent():
    a = plan_trials("external", ["chips_can"], ["robot_off", "robot_moving"], 2, 7, "4mic",
                    "textured", 5.0)
    b = plan_trials("external", ["chips_can"], ["robot_off", "robot_moving"], 2, 7, "1mic",
                    "smooth", 5.0)
    assert [p["seed"] for p in a] == [p["seed"] for p in b]
    assert len({p["seed"] for p in a}) == 4
    assert a[0]["trial_id"] == "ext-chips_can-robot_off-0000"
    assert trial_seed(7, "external", "chips_can", "robot_off", 0) == a[0]["seed"]
    with pytest.raises(ValueError):
        plan_trials("robots", [None], [None], 1, 0, None, None, 1.0)
    with pytest.raises(ValueError):
        plan_trials("robot", [None], [None], 0, 0, None, None, 1.0)


def _scene_ready():
    try:
        from aslip_ros.scene import World, scenarios  # noqa: F401
    except ImportError as exc:
        return str(exc)
    return None


@pytest.mark.skipif(_scene_ready() is not None, reason="scene not available")
def test_simulate_cli_and_export_match_scene_truth(tmp_path):
    rc = cli.main(["simulate", "--kind", "robot", "--trials", "1", "--duration", "1.5",
                   "--layout", "2mic_corners", "-o", str(tmp_path / "bags"), "--no-progress"])
    assert rc == 0
    (bag,) = bags.find_bags([tmp_path / "bags"])
    with bags.BagReader(bag) as r:
        assert {"/aslip/audio", "/aslip/robot/tcp_pose", "/aslip/metadata"} <= set(
            r.info.topics)
        assert r.metadata["layout"] == "2mic_corners"
    s = export([tmp_path / "bags"], tmp_path / "ds", progress=False)
    ds = Dataset(tmp_path / "ds")
    assert ds.trials[0]["label_source"] == "robot" and len(ds.channel_names) == 2
    assert s.kept >= 10


@pytest.mark.skipif(_scene_ready() is not None, reason="scene not available")
def test_presets_tiny(tmp_path, monkeypatch):
    monkeypatch.setitem(SCALES, "tiny", dict(SCALES["tiny"], duration_s=0.6,
                                             objects=("chips_can",),
                                             external={"robot_off": 1}, robot_trials=1))
    s = build_default_datasets(tmp_path, "tiny", layouts=("1mic",), progress=False)
    assert set(s["datasets"]) == {"1mic/pretrain", "1mic/finetune"}
    ft = Dataset(tmp_path / "datasets" / "1mic" / "finetune")
    assert ft.trials[0]["induced"] == "external" and ft.channel_names == ["left_center"]
    assert (tmp_path / "datasets" / "summary.json").is_file()
    # Built again: a dataset with the export's labels is kept; one exported before the
    # labels were smoothed (no label_smoothing_s: raw poses) is exported again.
    man = tmp_path / "datasets" / "1mic" / "finetune" / "manifest.json"
    old = json.loads(man.read_text())
    del old["label_smoothing_s"]
    man.write_text(json.dumps(old))
    s = build_default_datasets(tmp_path, "tiny", layouts=("1mic",), progress=False)
    assert s["datasets"]["1mic/pretrain"]["export"] == "kept existing"
    assert "export" not in s["datasets"]["1mic/finetune"]
    assert json.loads(man.read_text())["label_smoothing_s"] == DEFAULT_LABEL_SMOOTHING_S


@pytest.mark.skipif(_scene_ready() is not None, reason="scene not available")
def test_simulate_refuses_bags_recorded_with_other_parameters(tmp_path, capsys):
    """Regression: simulate into a folder holding bags of another duration or layout kept
    them silently, so one set mixed two recordings."""
    out = tmp_path / "bags"
    base = ["simulate", "--kind", "external", "--trials", "1", "-o", str(out),
            "--no-progress"]
    assert cli.main(base + ["--duration", "0.6", "--layout", "2mic_corners"]) == 0
    (bag,) = bags.find_bags([out])
    stamp = bag.stat().st_mtime_ns
    # The same call resumes: the bag is kept.
    assert cli.main(base + ["--duration", "0.6", "--layout", "2mic_corners"]) == 0
    assert "1 existing kept" in capsys.readouterr().out
    for other, what in ((["--duration", "0.8", "--layout", "2mic_corners"], "duration"),
                        (["--duration", "0.6", "--layout", "4mic"], "layout"),
                        (["--duration", "0.6", "--layout", "2mic_corners", "--seed", "3"],
                         "seed")):
        assert cli.main(base + other) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(bag) in err[0] and what in err[0], err
        assert "--overwrite" in err[0]
        assert bag.stat().st_mtime_ns == stamp
    # --overwrite replaces it with the new parameters.
    assert cli.main(base + ["--duration", "0.8", "--layout", "4mic", "--overwrite"]) == 0
    with bags.BagReader(bag) as r:
        assert r.metadata["layout"] == "4mic" and r.metadata["duration_s"] == 0.8


def test_even_headings_spread_a_one_sided_draw_round_the_circle(tmp_path):
    """``--headings even``: the trials' preferred directions 360/n degrees apart, each world
    slipping mostly that way, recorded in the metadata; a random draw (the default) leaves
    them to the seeds, and the option is refused without the one_sided variant."""
    from aslip_ros.scene.simulate import _trials, even_headings
    h = even_headings(6, seed=4)
    gaps = np.diff(np.sort(np.degrees(h)))
    assert np.allclose(gaps, 60.0) and np.all(np.abs(h) <= np.pi)
    assert np.array_equal(h, even_headings(6, seed=4))
    assert not np.allclose(np.sort(h), np.sort(even_headings(6, seed=5)))
    plan = plan_trials("external", ["chips_can", "cracker_box"], ["robot_off", "robot_moving"],
                       1, 4, None, None, 1.0)
    worlds, extras = _trials("external", plan, 1.0, "one_sided", 0.0, None, None, "even", 4)
    got = [w.scenario.one_sided_direction_rad for w in worlds]
    assert np.allclose(got, even_headings(len(plan), 4))
    assert [ex["one_sided_heading_deg"] for ex in extras] == pytest.approx(np.degrees(got),
                                                                           abs=1e-3)
    drawn, extras = _trials("external", plan, 1.0, "one_sided", 0.0, None, None, "random", 4)
    assert all("one_sided_heading_deg" not in ex for ex in extras)
    assert [w.scenario.one_sided_direction_rad for w in drawn] != pytest.approx(got)
    with pytest.raises(ValueError, match="one_sided variant only"):
        _trials("external", plan, 1.0, None, 0.0, None, None, "even", 4)
    with pytest.raises(ValueError, match="one_sided_heading_rad"):
        worlds[0].scenario.with_(one_sided_heading_rad=4.0)
