"""``aslip export --jobs N`` (#38): bags read in N processes give the dataset one job gives,
byte for byte, with a bad bag skipped or refused the same way."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from aslip_ros import cli
from aslip_ros.data import bags
from aslip_ros.data.export import export
from aslip_ros.data.synthetic import write_synthetic_bag

pytestmark = pytest.mark.slow


def _bags(root: Path, bad: str | None = None) -> list:
    """Five short trials, each its own slip and dropouts; ``bad``: the third is damaged
    (``rate``: another sample rate, ``cut``: its file cut short)."""
    out = []
    for k in range(5):
        path = root / f"t{k}"
        rate = 32000.0 if bad == "rate" and k == 2 else 48000.0
        write_synthetic_bag(path, duration_s=1.5 + 0.25 * k, seed=k, sample_rate=rate,
                            slip_velocity=(0.01 * (k + 1), 0.0, 0.005 * k),
                            pose_dropouts=[(0.4, 0.47)] if k == 1 else (),
                            audio_dropouts=[(0.9, 0.95)] if k == 3 else (),
                            metadata={"trial_id": f"trial{k}", "object": f"obj{k % 2}"})
        if bad == "cut" and k == 2:
            (mcap,) = path.glob("*.mcap")
            data = mcap.read_bytes()
            mcap.write_bytes(data[:len(data) // 2])
        out.append(path)
    return out


def _contents(ds: Path) -> dict:
    """Every file of a dataset: arrays as arrays, the manifest as JSON."""
    got = {}
    for f in sorted(ds.rglob("*")):
        if f.is_file():
            rel = str(f.relative_to(ds))
            got[rel] = json.loads(f.read_text()) if f.suffix == ".json" else f.read_bytes()
    return got


def test_two_jobs_export_the_dataset_one_job_does(tmp_path):
    paths = _bags(tmp_path / "bags")
    one = export(paths, tmp_path / "one", progress=False)
    two = export(paths, tmp_path / "two", progress=False, jobs=2)
    a, b = _contents(tmp_path / "one"), _contents(tmp_path / "two")
    assert sorted(a) == sorted(b) and len([k for k in a if k.startswith("audio/")]) == 5
    for name in a:
        assert a[name] == b[name], name
    assert (one.kept, one.dropped, one.warnings) == (two.kept, two.dropped, two.warnings)
    assert one.dropped["audio_gap"] > 0 and one.dropped["label_gap"] > 0
    windows = np.load(tmp_path / "two" / "windows.npy")
    assert sorted(set(windows["trial"].tolist())) == [0, 1, 2, 3, 4]
    assert not list((tmp_path / "two" / "audio").glob(".*"))       # no part file left


@pytest.mark.parametrize("bad", ["rate", "cut"])
def test_a_bad_bag_is_skipped_or_refused_as_with_one_job(tmp_path, bad):
    paths = _bags(tmp_path / "bags", bad)
    one = export(paths, tmp_path / "one", progress=False, skip_bad=True)
    two = export(paths, tmp_path / "two", progress=False, skip_bad=True, jobs=3)
    assert [(r.bag, r.error) for r in one.bags] == [(r.bag, r.error) for r in two.bags]
    assert sum(bool(r.error) for r in two.bags) == 1
    assert _contents(tmp_path / "one") == _contents(tmp_path / "two")
    with pytest.raises(bags.BagError, match="t2") as err:
        export(paths, tmp_path / "refused", progress=False, jobs=2)
    with pytest.raises(bags.BagError) as err_one:
        export(paths, tmp_path / "refused", progress=False)
    assert str(err.value) == str(err_one.value)
    assert not (tmp_path / "refused").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".refused")]


def test_the_command_takes_jobs_and_refuses_a_bad_count(tmp_path, capsys):
    paths = _bags(tmp_path / "bags")[:2]
    assert cli.main(["export", *map(str, paths), "-o", str(tmp_path / "ds"), "--jobs", "2",
                     "--no-progress"]) == 0
    assert (tmp_path / "ds" / "manifest.json").is_file()
    assert cli.main(["export", *map(str, paths), "-o", str(tmp_path / "ds0"), "--jobs",
                     "0", "--no-progress"]) == 1
    assert "jobs must be a whole number >= 1" in capsys.readouterr().err
