"""Damaged bags: flipped bits, undecodable messages, recordings cut short.

Each case must end in one clear error naming the bag (never a silent export of damaged
data), and an export that fails leaves nothing behind.
"""

import struct

import numpy as np
import pytest

from aslip_ros import cli
from aslip_ros.data import bags
from aslip_ros.data.export import export
from aslip_ros.data.synthetic import write_synthetic_bag


def _mcap(bag):
    return bag / f"{bag.name}.mcap"


def _flip(path, positions):
    data = bytearray(path.read_bytes())
    for pos in positions:
        data[pos // 8] ^= 1 << (pos % 8)
    path.write_bytes(bytes(data))


def test_written_bags_carry_crcs_that_the_mcap_library_accepts(tmp_path):
    from mcap.records import Chunk, DataEnd, Footer
    from mcap.stream_reader import StreamReader
    bag = tmp_path / "b"
    write_synthetic_bag(bag, duration_s=2.0)
    with open(_mcap(bag), "rb") as f:
        records = list(StreamReader(f, emit_chunks=True, validate_crcs=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert len(chunks) >= 2 and all(c.uncompressed_crc != 0 for c in chunks)
    assert next(r for r in records if isinstance(r, DataEnd)).data_section_crc != 0
    assert next(r for r in records if isinstance(r, Footer)).summary_crc != 0
    with open(_mcap(bag), "rb") as f:      # every chunk's records check out against its CRC
        n_msgs = sum(1 for _ in StreamReader(f, validate_crcs=True).records)
    assert n_msgs > 100


@pytest.mark.parametrize("where,n_bits", [("audio", 1), ("audio", 10), ("start", 1),
                                          ("summary", 1), ("anywhere", 10)])
def test_flipped_bits_are_refused_naming_the_bag(tmp_path, where, n_bits):
    """Regression: bags with 1 or 10 flipped bits exported silently (CRCs were all 0)."""
    bag = tmp_path / "bags" / "flipped"
    write_synthetic_bag(bag, duration_s=2.0)
    path = _mcap(bag)
    size = path.stat().st_size
    rng = np.random.default_rng(n_bits)
    lo, hi = {"audio": (size // 4, size // 2), "start": (8, 400),
              "summary": (size - 600, size - 60), "anywhere": (0, size)}[where]
    _flip(path, rng.integers(lo * 8, hi * 8, n_bits))
    with pytest.raises(bags.BagError, match="cannot read bag .*flipped") as err:
        export([bag], tmp_path / "ds", progress=False)
    assert "CRC mismatch" in str(err.value) or "truncated" in str(err.value)
    assert not (tmp_path / "ds").exists()


def test_bags_without_crcs_still_export(tmp_path, monkeypatch):
    """Other writers may leave the CRCs at zero ("not computed"): nothing to verify."""
    from rosbags.rosbag2.storage_mcap import McapWriter

    from aslip_ros.data import mcap_crc
    monkeypatch.setattr(mcap_crc, "CrcMcapWriter", McapWriter)
    bag = tmp_path / "plain"
    write_synthetic_bag(bag, duration_s=1.0)
    data = _mcap(bag).read_bytes()
    assert data[-8 - 4:-8] == b"\0\0\0\0"          # the footer's summary CRC: not computed
    assert export([bag], tmp_path / "ds", progress=False).kept > 0


def _bag_with_a_bad_pose(path, k_bad=3):
    with bags.BagWriter(path, metadata=bags.make_metadata(trial_id="t")) as w:
        for k in range(20):
            w.write_audio(k * 0.01, k * 480, np.zeros((480, 2), np.float32), 48000.0,
                          ["a", "b"])
            if k == k_bad:
                conn = w._conns["/aslip/mocap/finger"]
                # A PoseStamped cut after its header: what a damaged driver might send.
                raw = b"\x00\x01\x00\x00" + struct.pack("<iII", 0, 0, 6) + b"world\x00"
                w._writer.write(conn, w._ns(k * 0.01), raw)
            else:
                w.write_pose("finger", k * 0.01, [0, 0, 0, 0, 0, 0, 1])
            w.write_pose("object", k * 0.01, [0, 0, 0, 0, 0, 0, 1])


def test_undecodable_pose_names_bag_topic_and_message(tmp_path, capsys):
    """Regression: the error was "not a CDR PoseStamped (...)" with no bag named."""
    bag = tmp_path / "damaged_pose"
    _bag_with_a_bad_pose(bag)
    with pytest.raises(bags.BagError) as err:
        export([bag], tmp_path / "ds", progress=False)
    text = str(err.value)
    assert str(bag) in text and "/aslip/mocap/finger" in text and "message 4 " in text
    assert "0.030 s into the bag" in text and "not a CDR PoseStamped" in text
    rc = cli.main(["export", str(bag), "-o", str(tmp_path / "ds"), "--no-progress"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(lines) == 1 and str(bag) in lines[0]
    assert not (tmp_path / "ds").exists()


@pytest.fixture(scope="module")
def full_bag(tmp_path_factory):
    root = tmp_path_factory.mktemp("full")
    write_synthetic_bag(root / "rec", duration_s=6.0)
    kept = export([root / "rec"], root / "ds", progress=False).kept
    return root / "rec", kept


def _cut_copy(full, dest, fraction, keep_yaml=True):
    """A copy of ``full`` cut at ``fraction`` of its MCAP file, as a crash leaves it."""
    dest.mkdir(parents=True)
    data = _mcap(full).read_bytes()
    (dest / f"{dest.name}.mcap").write_bytes(data[:int(len(data) * fraction)])
    if keep_yaml:
        text = (full / "metadata.yaml").read_text().replace(full.name, dest.name)
        (dest / "metadata.yaml").write_text(text)
    return dest


@pytest.mark.parametrize("fraction", [0.3, 0.5, 0.77, 0.95])
def test_truncated_recording_is_refused_then_recovered(tmp_path, full_bag, fraction):
    """Regression: a recording cut short was refused as a whole ("File end magic is
    invalid") although its chunks up to the cut are readable."""
    from aslip_ros.data.dataset import Dataset
    full, full_kept = full_bag
    bag = _cut_copy(full, tmp_path / "bags" / "crashed", fraction)
    with pytest.raises(bags.BagError, match="crashed.*truncated.*--recover"):
        export([bag], tmp_path / "ds", progress=False)
    assert not (tmp_path / "ds").exists()
    s = export([bag], tmp_path / "ds", progress=False, recover=True)
    assert 0 < s.kept < full_kept
    assert s.kept >= int(full_kept * fraction) - 15      # about what the cut leaves
    (note,) = s.warnings
    assert str(bag) in note and "lost" in note and "unread" in note
    assert "of the 2043 messages that its metadata.yaml lists" in note
    trial = Dataset(tmp_path / "ds").trials[0]
    assert trial["recovered"] == note and trial["object"] == "synthetic"


def test_recovery_without_metadata_yaml_and_nothing_readable(tmp_path, full_bag, capsys):
    full, _ = full_bag
    # A crashed recorder may leave no metadata.yaml: the bare .mcap is found and recovered.
    bag = _cut_copy(full, tmp_path / "bags" / "noyaml", 0.6, keep_yaml=False)
    rc = cli.main(["export", str(tmp_path / "bags"), "-o", str(tmp_path / "ds"),
                   "--no-progress", "--recover"])
    out = capsys.readouterr().out
    assert rc == 0 and "warning: bag" in out and "noyaml" in out and "lost" in out
    # A file cut inside its first chunk has nothing to recover: one error line.
    _cut_copy(full, tmp_path / "b2" / "early", 0.05)
    rc = cli.main(["export", str(tmp_path / "b2"), "-o", str(tmp_path / "ds2"),
                   "--no-progress", "--recover"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "early" in err[0] and "nothing readable" in err[0]
    assert not (tmp_path / "ds2").exists()
    assert bag.exists()


def test_a_chunk_failing_its_crc_is_skipped_by_recovery(tmp_path, full_bag):
    full, full_kept = full_bag
    bag = tmp_path / "flipped"
    bag.mkdir()
    data = bytearray(_mcap(full).read_bytes())
    data[len(data) // 3] ^= 0x10                  # inside the second of five chunks
    (bag / "flipped.mcap").write_bytes(bytes(data))
    with pytest.raises(bags.BagError, match="flipped.*CRC mismatch"):
        export([bag], tmp_path / "ds", progress=False)
    s = export([bag], tmp_path / "ds", progress=False, recover=True)
    (note,) = s.warnings
    assert "a damaged chunk from" in note and "crc validation failed" in note
    assert 0 < s.kept < full_kept and s.dropped["audio_gap"] > 0


def test_a_damaged_summary_loses_nothing_with_recover(tmp_path, full_bag):
    full, full_kept = full_bag
    bag = tmp_path / "summary"
    bag.mkdir()
    data = bytearray(_mcap(full).read_bytes())
    data[-200] ^= 0x01                            # inside the summary section
    (bag / "summary.mcap").write_bytes(bytes(data))
    with pytest.raises(bags.BagError, match="summary section CRC mismatch"):
        export([bag], tmp_path / "ds", progress=False)
    s = export([bag], tmp_path / "ds", progress=False, recover=True)
    assert s.kept == full_kept and "damaged" in s.warnings[0]
