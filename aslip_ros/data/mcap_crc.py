"""MCAP checksums: write them into the bags the package records, verify them on read.

The MCAP format carries three CRC-32 fields: one per chunk (over its uncompressed
records), one for the data section (in the DataEnd record) and one for the summary section
(in the footer). A zero means "not computed". ``rosbags`` 0.11 writes zeros in all three and
offers no option to compute them, so a bag with flipped bits would export silently. This
module fills them in:

- :class:`CrcMcapWriter` is rosbags' MCAP storage writer with all three filled in as the
  file is written: each chunk's CRC before its bytes reach the file, and the data
  section's CRC kept up to date with every byte written (``_CrcFile``), so that closing a
  recording reads back only its summary section (about 100 bytes per 1 MB chunk), never
  the data: an hour-long bag closes inside a node's shutdown grace (#38);
- :func:`seal` fills in the data-section and summary CRCs of a finished file from another
  writer (a pass over the whole file).

Reading side: ``rosbags`` already verifies a non-zero chunk CRC when it decodes a chunk;
:func:`check` verifies the other two, and recognises a file cut short (no end magic).
"""

from __future__ import annotations

import os
import struct
import zlib
from io import BytesIO
from pathlib import Path

from rosbags.rosbag2.storage_mcap import McapWriter

MAGIC = b"\x89MCAP0\r\n"
_FOOTER_LEN = 1 + 8 + 8 + 8 + 4          # opcode, record length, two offsets, summary CRC
_DATA_END_LEN = 1 + 8 + 4                # opcode, record length, data-section CRC
_CHUNK_CRC_AT = 1 + 8 + 8 + 8 + 8        # opcode, length, start/end time, uncompressed size
_OP_FOOTER, _OP_DATA_END = 0x02, 0x0F
_BLOCK = 8 * 2**20


class _CrcFile:
    """The MCAP file as the writer writes it, front to back, with the CRC-32 of every byte
    so far (``crc``). While ``held`` is a buffer (a chunk being closed), writes wait there
    so that the chunk's own CRC can be put in before its bytes count; ``crc_at``, where it
    is a dict, records the CRC of the bytes before each write's offset."""

    def __init__(self, f, crc: int, pos: int) -> None:
        self._f, self.crc, self.pos = f, crc, pos
        self.held: BytesIO | None = None
        self.crc_at: dict[int, int] | None = None

    def write(self, data) -> int:
        if self.held is not None:
            return self.held.write(data)
        return self.commit(data)

    def commit(self, data) -> int:
        """Write ``data`` to the file, counting it in the CRC."""
        if self.crc_at is not None:
            self.crc_at[self.pos] = self.crc
        n = self._f.write(data)
        self.crc = zlib.crc32(data, self.crc)
        self.pos += memoryview(data).nbytes
        return n

    def tell(self) -> int:
        return self.pos + (self.held.tell() if self.held is not None else 0)

    def close(self) -> None:
        self._f.close()


class CrcMcapWriter(McapWriter):
    """rosbags' MCAP writer, with the chunk, data-section and summary CRCs filled in, at a
    cost at close that does not grow with the recording's length."""

    def __init__(self, path: Path, compression) -> None:
        super().__init__(path, compression)
        self.bio.flush()            # the header rosbags has written: counted from the file
        head = self.path.read_bytes()
        self.bio = _CrcFile(self.bio, zlib.crc32(head), len(head))

    def close_chunk(self) -> None:
        crc = zlib.crc32(self.chunk.bio.getbuffer())
        self.bio.held = BytesIO()
        try:
            super().close_chunk()
        finally:
            held, self.bio.held = self.bio.held, None
        record = bytearray(held.getbuffer())
        record[_CHUNK_CRC_AT:_CHUNK_CRC_AT + 4] = struct.pack("<I", crc)
        self.bio.commit(record)

    def close(self, version: int, metadata: str) -> None:
        self.bio.crc_at = {}
        super().close(version, metadata)
        seal(self.path, data_crc_at=self.bio.crc_at)


def _crc_of(f, start: int, stop: int) -> int:
    f.seek(start)
    crc, left = 0, stop - start
    while left > 0:
        block = f.read(min(_BLOCK, left))
        if not block:
            break
        crc = zlib.crc32(block, crc)
        left -= len(block)
    return crc


def _layout(f, size: int) -> tuple[int, int, int, int]:
    """(footer offset, summary start, data-end offset or -1, stored summary CRC)."""
    footer = size - len(MAGIC) - _FOOTER_LEN
    f.seek(footer)
    op, length, summary_start, _, summary_crc = struct.unpack("<BQQQI", f.read(_FOOTER_LEN))
    if op != _OP_FOOTER or length != _FOOTER_LEN - 9 or summary_start > footer:
        raise ValueError("the footer record is damaged")
    data_end = (summary_start or footer) - _DATA_END_LEN
    f.seek(data_end)
    op, length = struct.unpack("<BQ", f.read(9))
    if op != _OP_DATA_END or length != 4:
        data_end = -1
    return footer, summary_start, data_end, summary_crc


def seal(path: str | os.PathLike, data_crc_at: dict[int, int] | None = None) -> None:
    """Write the data-section and summary CRCs of the finished MCAP file at ``path``.
    ``data_crc_at``: the CRC of the bytes before each of some offsets, as its writer kept it
    (``_CrcFile.crc_at``); where the data section's end is among them, the data is not
    read again."""
    path = Path(path)
    with open(path, "r+b") as f:
        size = f.seek(0, os.SEEK_END)
        footer, summary_start, data_end, _ = _layout(f, size)
        if data_end > 0:
            crc = (data_crc_at or {}).get(data_end)
            if crc is None:
                crc = _crc_of(f, 0, data_end)
            f.seek(data_end + 9)
            f.write(struct.pack("<I", crc))
        if summary_start:
            crc = _crc_of(f, summary_start, footer + _FOOTER_LEN - 4)
            f.seek(footer + _FOOTER_LEN - 4)
            f.write(struct.pack("<I", crc))


def check(path: str | os.PathLike) -> str | None:
    """What is wrong with the MCAP file at ``path`` (None when nothing is found).

    Checks the end magic (a recording cut short has none), the footer, and the data-section
    and summary CRCs where the writer stored them. Chunk CRCs are checked as chunks are read.
    """
    path = Path(path)
    with open(path, "rb") as f:
        size = f.seek(0, os.SEEK_END)
        if size < 2 * len(MAGIC) + _FOOTER_LEN:
            return f"truncated: {size} bytes is less than an MCAP header and footer"
        f.seek(0)
        if f.read(len(MAGIC)) != MAGIC:
            return "not an MCAP file (no MCAP magic at its start)"
        f.seek(size - len(MAGIC))
        if f.read(len(MAGIC)) != MAGIC:
            return ("truncated: the file does not end with the MCAP end magic (a recording "
                    "cut short?)")
        try:
            footer, summary_start, data_end, summary_crc = _layout(f, size)
        except (ValueError, struct.error) as exc:
            return str(exc)
        if summary_start and summary_crc:
            got = _crc_of(f, summary_start, footer + _FOOTER_LEN - 4)
            if got != summary_crc:
                return (f"summary section CRC mismatch (stored {summary_crc:#010x}, computed "
                        f"{got:#010x}): the file is damaged (flipped bits?)")
        if data_end > 0:
            f.seek(data_end + 9)
            (stored,) = struct.unpack("<I", f.read(4))
            if stored:
                got = _crc_of(f, 0, data_end)
                if got != stored:
                    return (f"data section CRC mismatch (stored {stored:#010x}, computed "
                            f"{got:#010x}): the file is damaged (flipped bits?)")
    return None
