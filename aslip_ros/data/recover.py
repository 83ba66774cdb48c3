"""The readable part of a damaged MCAP bag: a recording cut short, or a chunk that fails its CRC.

A recorder that crashes leaves an MCAP file without its summary and end magic, which the
indexed reader (``rosbags``) refuses as a whole. Its chunks up to the cut are intact, and
the ``mcap`` package's stream reader reads them in file order. :class:`RecoveredBagReader`
offers the :class:`~aslip_ros.data.bags.BagReader` interface over those records:

- a chunk whose CRC fails, or that cannot be decoded, is skipped and counted; reading goes
  on with the next record;
- reading stops at the first record that cannot be read (the cut);
- messages come in file order, sorted by log time within each chunk (a recorder writes in
  receive order, so this is log-time order for the bags a lab records).

:attr:`RecoveredBagReader.report` says what was read and what was lost. Recovery is never
silent: ``aslip export`` uses it only with ``--recover`` and prints that report.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator

import yaml

from aslip_ros.data.bag_format import base_store as _base_store
from aslip_ros.data.bags import (POSE_TYPE, BagError, BagMessage, BagReader, decode_pose_stamped,
                                 project_msg_texts)


@dataclass
class RecoveryReport:
    """What the stream reader got out of a damaged bag."""

    files: list = field(default_factory=list)
    counts: dict = field(default_factory=dict)       # topic -> messages read
    first_ns: int | None = None
    last_ns: int | None = None
    bad_chunks: list = field(default_factory=list)   # (start_ns, end_ns, reason)
    cut: str = ""                                    # where and why reading stopped
    unread_bytes: int = 0
    expected: int | None = None                      # messages the bag's metadata announces
    expected_end_ns: int | None = None

    @property
    def n_messages(self) -> int:
        return sum(self.counts.values())

    def describe(self, path: Path) -> str:
        """One paragraph for a warning: what was read, and what was lost."""
        if self.first_ns is None:
            span = "no messages"
        else:
            span = (f"{self.n_messages} messages over "
                    f"{(self.last_ns - self.first_ns) * 1e-9:.2f} s")
        lost = []
        if self.cut:
            lost.append(f"everything after log time {self._rel(self.last_ns)} ({self.cut}; "
                        f"{self.unread_bytes} bytes unread)")
        for start, end, why in self.bad_chunks:
            lost.append(f"a damaged chunk from {self._rel(start)} to {self._rel(end)} ({why})")
        if self.expected is not None:
            lost.append(f"{max(0, self.expected - self.n_messages)} of the {self.expected} "
                        "messages that its metadata.yaml lists")
        if self.expected_end_ns is not None and self.last_ns is not None:
            lost.append(f"{max(0.0, (self.expected_end_ns - self.last_ns) * 1e-9):.2f} s at "
                        "the end of the recording")
        return (f"bag {path} is damaged; recovered its readable part: {span} "
                f"({', '.join(f'{t} {n}' for t, n in sorted(self.counts.items()))}); "
                f"lost: {'; '.join(lost) or 'nothing that can be counted'}")

    def _rel(self, ns: int | None) -> str:
        if ns is None or self.first_ns is None:
            return "the start"
        return f"{(ns - self.first_ns) * 1e-9:.2f} s"


def _mcap_files(path: Path) -> list[Path]:
    files = [path] if path.is_file() else sorted(path.glob("*.mcap"))
    if not files or any(f.suffix != ".mcap" for f in files):
        raise BagError(f"bag {path}: recovery reads MCAP files only, found "
                       f"{[f.name for f in files] or 'none'}")
    return files


def _announced(path: Path, report: RecoveryReport) -> None:
    """Message count and end time from metadata.yaml, where the recorder left one."""
    meta = path / "metadata.yaml" if path.is_dir() else None
    if meta is None or not meta.is_file():
        return
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        report.expected = int(info["message_count"])
        start = int(info["starting_time"]["nanoseconds_since_epoch"])
        report.expected_end_ns = start + int(info["duration"]["nanoseconds"])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError):
        pass


class RecoveredBagReader(BagReader):
    """:class:`BagReader` over the readable records of a damaged MCAP bag (see module doc)."""

    def __init__(self, path: str | os.PathLike):
        super().__init__(path)
        self.report = RecoveryReport()
        self._channels: dict[int, tuple[str, str]] = {}     # id -> (topic, msgtype)

    def open(self) -> None:
        """One pass over the file: channels, message counts and the time span."""
        self.report = rep = RecoveryReport(files=_mcap_files(self.path))
        _announced(self.path, rep)
        schemas: dict[int, tuple[str, str, bytes]] = {}
        for _, rec in self._records(schemas, rep):
            topic = self._channels[rec.channel_id][0]
            rep.counts[topic] = rep.counts.get(topic, 0) + 1
            rep.first_ns = rec.log_time if rep.first_ns is None else min(rep.first_ns,
                                                                         rec.log_time)
            rep.last_ns = rec.log_time if rep.last_ns is None else max(rep.last_ns,
                                                                       rec.log_time)
        if not rep.n_messages:
            raise BagError(f"bag {self.path}: nothing readable ({rep.cut or 'no messages'})")
        self.info.topics = {t: m for t, m in self._channels.values()}
        self.info.counts = dict(rep.counts)
        self.info.start_ns = rep.first_ns
        self.info.duration_ns = rep.last_ns - rep.first_ns
        self._store = self._typestore(schemas)
        self._reader = self            # marks the reader open for BagReader's methods

    def close(self) -> None:
        self._reader = None

    def _typestore(self, schemas: dict[int, tuple[str, str, bytes]]):
        from rosbags.typesys import get_types_from_idl, get_types_from_msg
        store = _base_store()
        types: dict = {}
        project = None
        for name, encoding, data in schemas.values():
            if name in store.types or name in types:
                continue
            text = data.decode("utf-8", errors="replace")
            if encoding == "ros2msg" and text:
                types.update(get_types_from_msg(text, name))
            elif encoding == "ros2idl" and text:
                types.update(get_types_from_idl(text))
            else:
                project = project_msg_texts() if project is None else project
                if name in project:
                    types.update(get_types_from_msg(project[name], name))
        store.register(types)
        return store

    def _records(self, schemas: dict, rep: RecoveryReport | None) -> Iterator[tuple[int, object]]:
        """(file index, Message record) of every readable message, chunks time-sorted."""
        from mcap.records import Channel, Chunk, DataEnd, Message, Schema
        from mcap.stream_reader import StreamReader, breakup_chunk
        for k, file in enumerate(_mcap_files(self.path)):
            size = file.stat().st_size
            with open(file, "rb") as f:
                good = 0
                try:
                    for rec in StreamReader(f, emit_chunks=True).records:
                        if isinstance(rec, DataEnd):
                            break       # the summary repeats what was read, maybe damaged
                        inner = [rec]
                        if isinstance(rec, Chunk):
                            try:
                                inner = breakup_chunk(rec, validate_crc=True)
                            except Exception as exc:    # CRC, decompression, bad records
                                if rep is not None:
                                    rep.bad_chunks.append((rec.message_start_time,
                                                           rec.message_end_time, str(exc)))
                                inner = []
                            inner.sort(key=lambda r: getattr(r, "log_time", -1))
                        for r in inner:
                            if isinstance(r, Schema):
                                schemas[r.id] = (r.name, r.encoding, r.data)
                            elif isinstance(r, Channel):
                                msgtype = schemas.get(r.schema_id, ("",))[0]
                                self._channels[r.id] = (r.topic, msgtype)
                            elif isinstance(r, Message) and r.channel_id in self._channels:
                                yield k, r
                        good = f.tell()
                except Exception as exc:    # the stream reader's many ways to meet the cut
                    if rep is not None:
                        name = type(exc).__name__
                        rep.cut = (f"{file.name} unreadable from byte {good} of {size}: "
                                   f"{name}{': ' + str(exc) if str(exc) else ''}")
                        rep.unread_bytes += size - good

    def messages(self, topics: Iterable[str] | None = None,
                 fast_poses: bool = False) -> Iterator[BagMessage]:
        """Yield the readable messages of ``topics`` (all when None); see the module doc."""
        if self._reader is None:
            raise BagError("RecoveredBagReader is not open")
        wanted = None if topics is None else set(topics)
        seen: dict[int, int] = {}
        for _, rec in self._records({}, None):
            topic, msgtype = self._channels[rec.channel_id]
            if wanted is not None and topic not in wanted:
                continue
            n = seen[rec.channel_id] = seen.get(rec.channel_id, 0) + 1
            try:
                if fast_poses and msgtype == POSE_TYPE:
                    msg = decode_pose_stamped(rec.data)
                else:
                    msg = self._store.deserialize_cdr(rec.data, msgtype)
            except Exception as exc:    # the decoders raise many types on bad bytes
                raise self._message_error(topic, n, rec.log_time, exc) from None
            yield BagMessage(topic, msgtype, rec.log_time, msg)
