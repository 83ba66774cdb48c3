"""An hour-long recording closes whole (#38): closing a bag reads back its summary only.

bag_recorder closes its bag in ``before_shutdown``, inside the launch's forced-exit grace.
Its seal used to pass over the whole file to compute the data section's CRC, so the time to
close grew with the recording (an hour of 4 channels at 48 kHz is 2.8 GB) and a long bag
could be cut. The CRC is now kept as the file is written (``mcap_crc._CrcFile``).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from aslip_ros.data import mcap_crc

pytestmark = pytest.mark.slow

#: The recording's size: at least 1 GB, as #38 asks.
GIB = 2 ** 30


def _read_counter(monkeypatch) -> list:
    """Every ``(start, stop)`` range the CRC code reads from a file."""
    ranges = []
    real = mcap_crc._crc_of

    def counted(f, start, stop):
        ranges.append((start, stop))
        return real(f, start, stop)
    monkeypatch.setattr(mcap_crc, "_crc_of", counted)
    return ranges


def _mcap(bag):
    (path,) = bag.glob("*.mcap")
    return path


def test_a_written_bag_carries_the_crcs_of_a_full_pass(tmp_path, monkeypatch):
    """The CRCs kept while writing equal a pass over the finished file (``seal``'s)."""
    from aslip_ros.data.synthetic import write_synthetic_bag
    reads = _read_counter(monkeypatch)
    write_synthetic_bag(tmp_path / "b", duration_s=3.0)
    path = _mcap(tmp_path / "b")
    size = path.stat().st_size
    assert sum(b - a for a, b in reads) < size / 20, (reads, size)
    kept = path.read_bytes()
    mcap_crc.seal(path)                         # a full pass, as for another writer's file
    assert path.read_bytes() == kept
    assert mcap_crc.check(path) is None


def test_a_recording_of_a_gigabyte_closes_reading_only_its_summary(tmp_path, monkeypatch):
    pytest.importorskip("rclpy")
    from aslip_ros.data import bags
    from aslip_ros.nodes.bag_recorder import RawBagWriter
    block = np.random.default_rng(0).bytes(4 * 480 * 4)   # 10 ms of 4 channels, float32
    n = GIB // len(block) + 1
    out = tmp_path / "hour"
    writer = RawBagWriter(out)
    writer.__enter__()
    for k in range(n):
        writer.write_raw("/aslip/audio", bags.AUDIO_TYPE, block, k * 10_000_000, "sensor")
    reads = _read_counter(monkeypatch)
    t = time.perf_counter()
    writer.__exit__(None, None, None)
    close_s = time.perf_counter() - t
    path = _mcap(out)
    size = path.stat().st_size
    read = sum(b - a for a, b in reads)
    print(f"closed a {size / 2**30:.2f} GiB bag in {close_s:.2f} s, reading {read} bytes")
    assert size >= GIB
    assert read < 2 ** 20, reads                # the summary: about 100 bytes per chunk
    assert mcap_crc.check(path) is None         # every CRC agrees with a full pass
    path.unlink()
