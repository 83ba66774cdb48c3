"""``make scale`` end to end at a tiny size (plumbing, not speed): the scene records the
hours, export runs at 1 and 2 jobs and training in children that report their own peak
memory, a smaller set is the start of a larger one, and the tables merge across calls."""

from __future__ import annotations

import json

import pytest

from benchmarks import scale

pytestmark = pytest.mark.slow


def test_a_tiny_scale_run_writes_its_rows_table_and_chart(tmp_path):
    out, work = tmp_path / "out", tmp_path / "work"
    out.mkdir()
    # A row of an earlier call (another rate) stays; this call's row joins it.
    earlier = {"rate": 48000.0, "hours": 1.0, "trials": 6, "export": {}, "train": None}
    (out / "scale.json").write_text(json.dumps({"rows": [earlier]}))
    assert scale.main(["--out", str(out), "--work", str(work), "--rate", "16000",
                       "--trial-s", "10", "--epochs", "1", "--keep", "--hours", "0.015"]) == 0
    rows = json.loads((out / "scale.json").read_text())["rows"]
    assert rows[0] == earlier and len(rows) == 2
    r = rows[1]
    assert (r["rate"], r["hours"], r["trials"]) == (16000.0, 0.015, 6)
    e1, e2 = r["export"]["1"], r["export"]["2"]
    assert e1["windows"] == e2["windows"] > 0
    assert e1["audio_s"] == pytest.approx(r["trials"] * 10.0, rel=0.01)
    assert 0 < e1["peak_anon_mib"] <= e1["peak_rss_mib"]
    assert e2["worker_peak_rss_mib"] > 0
    assert r["train"]["epochs"] == 1 and r["train"]["feature_cache_gib"] >= 0
    # A smaller set is the first trials of a larger one: recorded once.
    bags = scale.record(work / "bags_16000_10", 0.02, 16000.0, 2, lambda m: None, 10.0)
    assert len(bags) == 8 and bags[:6] == scale.record(
        work / "bags_16000_10", 0.015, 16000.0, 2, lambda m: None, 10.0)
    md = (out / "scale.md").read_text()
    assert md.count("| 16 kHz |") == 1 and md.count("| 48 kHz |") == 1
    assert (out / "scale.png").stat().st_size > 0


def test_a_run_that_does_not_fit_on_the_disk_is_refused_before_it_starts(tmp_path, capsys):
    assert scale.main(["--out", str(tmp_path / "o"), "--work", str(tmp_path / "w"),
                       "--hours", "100000"]) == 1
    assert "pass --work on a larger disk" in capsys.readouterr().err
    assert not (tmp_path / "w" / "bags_48000_600").exists()


def test_the_recording_workers_are_spawned_not_forked(tmp_path, monkeypatch):
    """A fork of a process that already runs threads (torch's, rclpy's: a test worker, or
    make scale after its imports) can crash the child: a fresh-clone CI run lost a worker to
    a segmentation fault in its garbage collection. The workers are spawned, as
    ``aslip export --jobs`` spawns its own."""
    seen = []

    class Pool:
        def __init__(self, n, mp_context=None):
            seen.append(None if mp_context is None else mp_context.get_start_method())

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def map(self, fn, *args):
            return [0.0 for _ in args[0]]

    monkeypatch.setattr(scale, "ProcessPoolExecutor", Pool)
    scale.record(tmp_path / "bags", hours=0.01, rate=16000.0, jobs=2, log=lambda m: None,
                 trial_s=10.0)
    assert seen == ["spawn"]
