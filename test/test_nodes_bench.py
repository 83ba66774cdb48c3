"""Block-continuity counting used by the node benchmarks."""

from benchmarks.node_bench import _dropped_blocks


def test_no_gap_no_drop():
    assert _dropped_blocks([(i * 480, 480) for i in range(100)]) == 0


def test_missing_blocks_are_counted_in_any_arrival_order():
    idx = [(i * 480, 480) for i in range(100) if i not in (10, 11, 50)]
    assert _dropped_blocks(list(reversed(idx))) == 3


def test_empty_stream():
    assert _dropped_blocks([]) == 0
