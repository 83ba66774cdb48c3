"""rosbag2 (mcap) input and output for the project's topics, without ROS.

Reading is here (:class:`BagReader`, :func:`read_messages`, :func:`find_bags`); writing is
:class:`~aslip_ros.data.bag_writer.BagWriter`, and what both hold to (message types, topic
names, metadata, the typestore) is :mod:`aslip_ros.data.bag_format`. This module is the one
name for all of it: the writer and the format's names are importable from here too.
"""

from __future__ import annotations

import contextlib
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from aslip_ros.audio_frame import stamp_to_ns
from aslip_ros.data.bag_errors import BagDamaged, BagError
from aslip_ros.data.bag_format import (AUDIO_TYPE, CUSTOM_DATA_KEY, DEFAULT_TOPICS,
                                       METADATA_FORMAT, METADATA_VERSION, PACKAGE, POSE_FRAMES,
                                       POSE_TOPICS, POSE_TYPE, SLIP_TYPE, STRING_TYPE, Topics,
                                       base_store, find_msg_dir, make_metadata, offered_qos,
                                       parse_metadata, project_msg_texts, time_msg, typestore)
from aslip_ros.data.bag_writer import BagWriter
from aslip_ros.data.pose_cdr import StampedPose, decode_pose_stamped


__all__ = [
    # reading (this module)
    "BagInfo", "BagMessage", "BagReader", "find_bags", "is_bag", "pose_from_msg",
    "read_messages",
    # writing (bag_writer), the errors (bag_errors), pose decoding (pose_cdr)
    "BagWriter", "BagDamaged", "BagError", "StampedPose", "decode_pose_stamped",
    "stamp_to_ns",
    # the format (bag_format)
    "AUDIO_TYPE", "CUSTOM_DATA_KEY", "DEFAULT_TOPICS", "METADATA_FORMAT", "METADATA_VERSION",
    "PACKAGE", "POSE_FRAMES", "POSE_TOPICS", "POSE_TYPE", "SLIP_TYPE", "STRING_TYPE",
    "Topics", "base_store", "find_msg_dir", "make_metadata", "offered_qos", "parse_metadata",
    "project_msg_texts", "time_msg", "typestore",
]


def pose_from_msg(msg: Any) -> np.ndarray:
    """``geometry_msgs/Pose`` (or PoseStamped) -> ``(x, y, z, qx, qy, qz, qw)`` float64."""
    if isinstance(msg, StampedPose):
        return msg.pose.copy()
    pose = getattr(msg, "pose", msg)
    p, q = pose.position, pose.orientation
    return np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=np.float64)


# ---------------------------------------------------------------------------------------
# Reading


@dataclass(frozen=True)
class BagMessage:
    """One deserialized message; ``log_ns`` is the recording (receive) time."""

    topic: str
    msgtype: str
    log_ns: int
    msg: Any


@dataclass
class BagInfo:
    """What a bag holds: topic -> type, topic -> message count, custom data, time span."""

    path: Path
    topics: dict[str, str] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    custom_data: dict[str, str] = field(default_factory=dict)
    start_ns: int = 0
    duration_ns: int = 0


@contextlib.contextmanager
def _wrap_errors(path: Path) -> Iterator[None]:
    """Turn the many exception types of a damaged bag into one BagError naming the bag."""
    from rosbags.rosbag2 import ReaderError
    from rosbags.serde import SerdeError
    try:
        yield
    except BagError:
        raise
    except (ReaderError, SerdeError, OSError, EOFError, KeyError, IndexError, TypeError,
            AssertionError, struct.error, UnicodeDecodeError, ValueError) as exc:
        # rosbags reports some truncations as plain asserts or struct errors.
        raise BagDamaged(f"cannot read bag {path}: {type(exc).__name__}: {exc} "
                         "(corrupt or truncated?)") from exc


class BagReader:
    """Open a rosbag2 bag (directory, or a bare ``.mcap``/``.db3`` file) for typed reading.

    Errors of any kind while opening or reading raise :class:`BagError` naming the bag.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"bag {self.path} does not exist")
        self._reader = None
        self._store = None
        self.info = BagInfo(path=self.path)

    def __enter__(self) -> "BagReader":
        self.open()
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    def open(self) -> None:
        """Open the bag and register any message types it defines that the store lacks."""
        from rosbags.rosbag2 import Reader
        self.verify()
        with _wrap_errors(self.path):
            self._reader = Reader(self.path)
            self._reader.open()
            conns = self._reader.connections
            self.info.topics = {c.topic: c.msgtype for c in conns}
            counts: dict[str, int] = {}
            for c in conns:
                counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
            self.info.counts = counts
            custom = getattr(self._reader.storage.metadata, "custom", None) or {}
            self.info.custom_data = {str(k): str(v) for k, v in custom.items()}
            if self._reader.message_count:
                self.info.start_ns = self._reader.start_time
                self.info.duration_ns = self._reader.duration
            self._store = self._typestore_for(conns)

    def verify(self) -> None:
        """Raise BagDamaged naming the bag when an MCAP file of it is cut short or fails a CRC.

        Chunk CRCs are checked while reading; this checks the end magic and the data-section
        and summary CRCs (where the writer stored them) before anything is read.
        """
        from aslip_ros.data.mcap_crc import check
        files = [self.path] if self.path.is_file() else sorted(self.path.glob("*.mcap"))
        for f in files:
            if f.suffix != ".mcap":
                continue
            try:
                problem = check(f)
            except OSError as exc:
                problem = f"cannot read: {exc.strerror or exc}"
            if problem:
                where = self.path if f == self.path else f"{self.path} ({f.name})"
                raise BagDamaged(f"cannot read bag {where}: {problem}")

    def close(self) -> None:
        """Close the bag (idempotent)."""
        reader, self._reader = self._reader, None
        if reader is not None:
            with contextlib.suppress(Exception):
                reader.close()

    def _typestore_for(self, conns):
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.typesys import get_types_from_idl, get_types_from_msg
        store = base_store()
        missing = {c.msgtype: c for c in conns if c.msgtype not in store.types}
        if not missing:
            return store
        types: dict = {}
        project: dict[str, str] | None = None
        for name, conn in missing.items():
            fmt, text = conn.msgdef.format, conn.msgdef.data
            if fmt == MessageDefinitionFormat.MSG and text:
                types.update(get_types_from_msg(text, name))
            elif fmt == MessageDefinitionFormat.IDL and text:
                types.update(get_types_from_idl(text))
            else:
                # Bags without stored definitions (older sqlite3): use the project's own.
                if project is None:
                    try:
                        project = project_msg_texts()
                    except FileNotFoundError:
                        project = {}
                if name in project:
                    types.update(get_types_from_msg(project[name], name))
        store.register(types)
        return store

    @property
    def metadata(self) -> dict | None:
        """Scenario metadata: ``custom_data['aslip']`` or else the first metadata message."""
        return self.read_metadata()

    def read_metadata(self, topic: str = DEFAULT_TOPICS.metadata) -> dict | None:
        """Scenario metadata dict, or None when the bag carries none."""
        text = self.info.custom_data.get(CUSTOM_DATA_KEY)
        if text:
            return parse_metadata(text, f"{self.path} custom_data[{CUSTOM_DATA_KEY!r}]")
        if topic in self.info.topics:
            for m in self.messages([topic]):
                return parse_metadata(m.msg.data, f"{self.path} topic {topic}")
        return None

    def require(self, topics: Iterable[str], why: str = "") -> None:
        """Raise BagError naming every topic of ``topics`` that the bag lacks."""
        missing = [t for t in topics if t not in self.info.topics]
        if missing:
            have = ", ".join(sorted(self.info.topics)) or "none"
            raise BagError(f"bag {self.path} has no topic {', '.join(missing)}"
                           f"{' (' + why + ')' if why else ''}; topics present: {have}")

    def messages(self, topics: Iterable[str] | None = None,
                 fast_poses: bool = False) -> Iterator[BagMessage]:
        """Yield deserialized messages of ``topics`` (all when None) in log-time order.

        With ``fast_poses``, PoseStamped messages come as :class:`StampedPose` from a
        direct CDR decode (several times faster than the generic deserializer).
        """
        if self._reader is None:
            raise BagError("BagReader is not open")
        wanted = None if topics is None else set(topics)
        conns = [c for c in self._reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        store = self._store
        seen: dict[int, int] = {}
        with _wrap_errors(self.path):
            for conn, log_ns, raw in self._reader.messages(connections=conns):
                k = seen[conn.id] = seen.get(conn.id, 0) + 1
                try:
                    if fast_poses and conn.msgtype == POSE_TYPE:
                        msg = decode_pose_stamped(raw)
                    else:
                        msg = store.deserialize_cdr(raw, conn.msgtype)
                except Exception as exc:    # the decoders raise many types on bad bytes
                    raise self._message_error(conn.topic, k, log_ns, exc) from None
                yield BagMessage(conn.topic, conn.msgtype, log_ns, msg)

    def _message_error(self, topic: str, k: int, log_ns: int, exc: Exception) -> BagError:
        after = (log_ns - self.info.start_ns) * 1e-9
        what = str(exc) if isinstance(exc, BagError) else f"{type(exc).__name__}: {exc}"
        return BagError(f"bag {self.path}: message {k} on {topic} (log time {log_ns} ns, "
                        f"{after:.3f} s into the bag) cannot be decoded: {what}")


def read_messages(path: str | os.PathLike,
                  topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Convenience: open ``path`` and yield its typed messages in log-time order."""
    with BagReader(path) as reader:
        yield from reader.messages(topics)


def is_bag(path: str | os.PathLike) -> bool:
    """True for a rosbag2 directory (has metadata.yaml) or a bare .mcap/.db3 file."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.is_file() and p.suffix in (".mcap", ".db3")


def find_bags(paths: Iterable[str | os.PathLike]) -> list[Path]:
    """Expand files and directories into a sorted, de-duplicated list of bags.

    A directory that is not itself a bag is searched recursively; storage files inside a bag
    directory are not listed separately.
    """
    found: dict[Path, None] = {}
    for raw in paths:
        p = Path(raw)
        if not p.exists():
            raise BagError(f"{p} does not exist")
        if is_bag(p):
            found[p.resolve()] = None
            continue
        if not p.is_dir():
            raise BagError(f"{p} is not a rosbag2 bag (directory with metadata.yaml, "
                           ".mcap or .db3 file)")
        inner: list[Path] = []
        for dirpath, dirnames, filenames in os.walk(p):
            d = Path(dirpath)
            if "metadata.yaml" in filenames:
                inner.append(d)
                dirnames[:] = []
                continue
            dirnames[:] = [n for n in dirnames if not n.startswith(".")]
            inner.extend(d / f for f in filenames
                         if f.endswith((".mcap", ".db3")) and not f.startswith("."))
        for q in sorted(inner):
            found[q.resolve()] = None
    return sorted(found)
