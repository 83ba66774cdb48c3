"""Capture-latency summary of the node benchmark."""

import pytest

from benchmarks.node_bench import _capture_latency


def test_capture_latency_summary_in_milliseconds():
    got = _capture_latency([0.001] * 98 + [0.004, 0.010])
    assert got["capture_latency_p50_ms"] == pytest.approx(1.0)
    assert got["capture_latency_max_ms"] == pytest.approx(10.0)
    assert 1.0 <= got["capture_latency_p99_ms"] <= 10.0


def test_no_blocks_no_numbers():
    assert set(_capture_latency([]).values()) == {None}
