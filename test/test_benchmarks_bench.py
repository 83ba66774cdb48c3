"""The benchmark pipeline on tiny synthetic data, and its Pareto selection logic."""

from __future__ import annotations

import json

import pytest

from benchmarks import bench
from benchmarks.common import DataPlan, Recipe


def _pt(name, n, lat, d, det=80.0, cost=100.0):
    return {"name": name, "n_params": n, "latency_p50_ms": lat, "latency_p99_ms": lat,
            "dir_mae_deg": d, "det_pct": det, "feature_cost": cost}


def test_smallest_within_one_degree():
    pts = [_pt("xs", 1_000, 0.5, 20.0), _pt("s", 5_000, 0.8, 12.9),
           _pt("m", 20_000, 1.0, 12.4), _pt("l", 100_000, 2.0, 12.0)]
    # best 12.0; within 1 deg: s (12.9), m, l -> the smallest is s
    assert bench.smallest_within(pts, 1.0) == "s"
    assert bench.smallest_within(pts, 0.5) == "m"
    assert bench.smallest_within([], 1.0) is None


def test_pareto_front():
    pts = [_pt("a", 1, 1.0, 20.0, det=70), _pt("b", 1, 2.0, 10.0, det=90),
           _pt("c", 1, 3.0, 15.0, det=80), _pt("d", 1, 0.5, 30.0, det=60)]
    assert sorted(bench.pareto_front(pts, "latency_p99_ms", "dir_mae_deg")) == ["a", "b", "d"]
    # c is slower than b and detects worse: dominated; the others trade off
    assert sorted(bench.pareto_front(pts, "latency_p99_ms", "det_pct", maximize_y=True)) == [
        "a", "b", "d"]


def test_lossless_features():
    pts = [_pt("ref", 1, 1.0, 12.0, det=85, cost=680),
           _pt("small", 1, 0.8, 12.5, det=84.5, cost=340),
           _pt("tiny", 1, 0.6, 15.0, det=85, cost=100), _pt("big", 1, 1.5, 11.0, cost=1000)]
    assert bench.lossless_features(pts, "ref") == "small"


def test_bench_end_to_end(tmp_path):
    cfg = bench.BenchConfig(
        out=tmp_path / "out",
        data=DataPlan(root=tmp_path / "data", synthetic=True, progress=False, synthetic_s=2.0),
        recipe=Recipe(epochs=1, patience=1, threads=1, progress=False, svm_max_train=300),
        ablation_cache=None, sizes=("cnn_xs", "cnn_default"), features=("mels20",),
        n_iter=20, n_warmup=3, system=False)
    bench.Bench(cfg).run()
    pareto = json.loads((cfg.out / "pareto.json").read_text())
    names = [p["name"] for p in pareto["points"]]
    assert names == ["svm", "cnn_xs", "cnn_default", "feat_mels20"]
    for p in pareto["points"]:
        assert p["latency_p99_ms"] >= p["latency_p50_ms"] > 0
    assert pareto["smallest_within_1deg"] in ("cnn_xs", "cnn_default")
    assert (cfg.out / "pareto.png").stat().st_size > 1000
    assert "methods" in json.loads((cfg.out / "bench.json").read_text())


def test_node_latency_without_a_checkpoint_reports_why_and_no_number():
    res = bench.node_latency(None)
    assert set(res) == {"error"} and "checkpoint" in res["error"]


@pytest.mark.ros
def test_node_latency_reports_a_failing_node_benchmark(monkeypatch, tmp_path):
    from benchmarks import node_bench

    def broken(checkpoint):
        raise RuntimeError("node did not start")
    monkeypatch.setattr(node_bench, "measure", broken)
    res = bench.node_latency(tmp_path / "m.pt")
    assert "result" not in res and "node did not start" in res["error"]


@pytest.mark.ros
def test_node_latency_passes_the_checkpoint_to_the_node_benchmark(monkeypatch, tmp_path):
    from benchmarks import node_bench
    seen = []
    monkeypatch.setattr(node_bench, "measure", lambda checkpoint: seen.append(checkpoint) or
                        {"slip_inference": {"p99_ms": 1.0}})
    res = bench.node_latency(tmp_path / "m.pt")
    assert seen == [str(tmp_path / "m.pt")]
    assert res["result"] == {"slip_inference": {"p99_ms": 1.0}}
