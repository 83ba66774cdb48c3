"""On-disk dataset format and trial splits (aslip_ros.data.dataset)."""

import json

import numpy as np
import pytest

from aslip_ros.data.dataset import (WINDOW_DTYPE, Dataset, DatasetWriter, split_trials)

OBJECTS = ["pla_rod", "chips_can", "cracker_box"]
CONDS = ["robot_off", "robot_stationary", "robot_moving"]


def make_dataset(path, n_per=4, n_samples=2000, channels=2):
    rng = np.random.default_rng(0)
    with DatasetWriter(path) as w:
        for obj in OBJECTS:
            for cond in CONDS:
                for i in range(n_per):
                    a = w.begin_trial(channels)
                    data = rng.standard_normal((n_samples, channels)).astype(np.float32)
                    a.append(data[:700])
                    a.append(data[700:])
                    rows = np.zeros(5, WINDOW_DTYPE)
                    rows["start"] = np.arange(5) * 200
                    rows["vx"] = 0.01 * i
                    w.end_trial({"id": f"{obj}-{cond}-{i}", "object": obj, "condition": cond,
                                 "induced": "external", "pad": "textured"}, rows)
        w.finish(sample_rate=1000.0, channel_names=["l", "r"][:channels], layout="2mic",
                 window_s=0.4, hop_s=0.2, epsilon_m_s=0.005)
    return Dataset(path)


def test_write_read_memory_mapped(tmp_path):
    ds = make_dataset(tmp_path / "ds")
    assert len(ds.trials) == 36 and len(ds) == 180 and ds.n_window_samples == 400
    m = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert m["format"] == "aslip-dataset" and m["version"] == 2 and m["n_windows"] == 180
    assert m["trials"][0]["file"] == "audio/0.npy" and m["trials"][0]["n_samples"] == 2000
    assert isinstance(ds.windows, np.memmap)
    a = ds.audio(5)
    assert isinstance(a, np.memmap) and a.shape == (2000, 2) and a.dtype == np.float32
    v = ds.window_audio(5, 400)
    assert v.shape == (400, 2) and np.shares_memory(v, a)
    audio, row = ds.window(7)
    assert row["trial"] == 1 and row["start"] == 400
    with pytest.raises(IndexError):
        ds.window_audio(0, 1900)
    assert not list(tmp_path.glob(".*")) and not list((tmp_path / "ds" / "audio").glob(".*"))


def test_failed_write_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with DatasetWriter(tmp_path / "ds") as w:
            w.begin_trial(2).append(np.zeros((10, 2), np.float32))
            raise RuntimeError("bag broke")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError, match="finish"):
        with DatasetWriter(tmp_path / "ds"):
            pass
    assert list(tmp_path.iterdir()) == []


def test_filters(tmp_path):
    ds = make_dataset(tmp_path / "ds")
    idx = ds.select(object="chips_can", condition=["robot_off", "robot_moving"])
    assert len(idx) == 2 * 4 * 5
    assert set(ds.trial_field("object")[idx]) == {"chips_can"}
    assert len(ds.select(induced="robot")) == 0
    assert len(ds.select(trials=[0, 1], object="pla_rod")) == 10


def test_split_never_leaks_and_is_deterministic(tmp_path):
    from aslip_ros.data.dataset import split_trials
    ds = make_dataset(tmp_path / "ds")
    fr = {"train": 0.5, "val": 0.25, "test": 0.25}
    parts = split_trials(ds.trials, fr, seed=3)
    trials = {k: set(v.tolist()) for k, v in parts.items()}
    assert not (trials["train"] & trials["val"]) and not (trials["train"] & trials["test"])
    assert not (trials["val"] & trials["test"])
    assert sum(len(v) for v in trials.values()) == len(ds.trials)
    assert [len(v) for v in trials.values()] == [18, 9, 9]
    again = split_trials(ds.trials, fr, seed=3)
    assert all(np.array_equal(parts[k], again[k]) for k in parts)
    other = split_trials(ds.trials, fr, seed=4)
    assert any(not np.array_equal(parts[k], other[k]) for k in parts)
    # Stratified: every (object, condition) stratum of 4 trials lands in every split.
    for k, tset in trials.items():
        strata = {(ds.trials[t]["object"], ds.trials[t]["condition"]) for t in tset}
        assert len(strata) == 9, k


def test_select_by_split_keeps_each_trial_in_its_split_whatever_the_filter(tmp_path):
    ds = make_dataset(tmp_path / "ds")
    names = ds.trial_splits(seed=3)
    win_trial = np.asarray(ds.windows["trial"])
    parts = {k: ds.select(k, seed=3) for k in ("train", "val", "test")}
    assert sum(len(v) for v in parts.values()) == len(ds) == len(ds.select("all"))
    for k, idx in parts.items():
        assert {names[t] for t in win_trial[idx]} == {k}
    # A filter selects within the split made over all trials, never a split of its own.
    sub = ds.select("test", seed=3, object="chips_can")
    assert set(sub) <= set(parts["test"])
    assert set(ds.trial_field("object")[sub]) <= {"chips_can"}
    with pytest.raises(ValueError, match="split must be one of"):
        ds.select("validation")


def test_split_groups_repeated_ids_and_validates():
    trials = [{"id": "a"}, {"id": "a"}, {"id": "b"}, {"id": "c"}]
    parts = split_trials(trials, {"x": 0.5, "y": 0.5}, seed=0, stratify=())
    where = {p: k for k, v in parts.items() for p in v}
    assert where[0] == where[1]
    with pytest.raises(ValueError):
        split_trials(trials, {"x": -1.0})
    with pytest.raises(ValueError):
        split_trials(trials, {"x": 0.0})


def test_rejects_non_datasets(tmp_path):
    with pytest.raises(ValueError, match="manifest"):
        Dataset(tmp_path)
    (tmp_path / "manifest.json").write_text('{"format": "other"}')
    with pytest.raises(ValueError, match="format"):
        Dataset(tmp_path)


@pytest.mark.parametrize("damage", ["windows_truncated", "audio_truncated", "audio_missing",
                                    "audio_garbage", "manifest_keys", "manifest_types"])
def test_damaged_dataset_files_are_named(tmp_path, damage):
    """A truncated, missing or garbled file of a dataset is a ValueError naming that file
    (a KeyError or a bare numpy/mmap error before)."""
    import json
    make_dataset(tmp_path / "ds")
    root = tmp_path / "ds"
    target = {"windows_truncated": root / "windows.npy",
              "audio_truncated": root / "audio" / "1.npy",
              "audio_missing": root / "audio" / "1.npy",
              "audio_garbage": root / "audio" / "1.npy",
              "manifest_keys": root / "manifest.json",
              "manifest_types": root / "manifest.json"}[damage]
    if damage.endswith("truncated"):
        data = target.read_bytes()
        target.write_bytes(data[:len(data) // 2])
    elif damage == "audio_missing":
        target.unlink()
    elif damage == "audio_garbage":
        target.write_bytes(b"\x93NUMPY\x01\x00" + b"garbage" * 40)
    else:
        doc = json.loads(target.read_text())
        if damage == "manifest_keys":
            del doc["trials"]
        else:
            doc["trials"] = [3, 4]
        target.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=str(target.relative_to(tmp_path))):
        ds = Dataset(root)
        for k in range(len(ds.trials)):
            ds.audio(k)
