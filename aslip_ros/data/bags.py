"""rosbag2 (mcap) input and output for the project's topics, without ROS.

The project's own message types (``msg/*.msg``) are registered with a ``rosbags`` typestore
built on the Jazzy standard types, so bags written here hold the same definitions, type
hashes and CDR bytes that rosbag2 records from live publishers.

Where the ``.msg`` text comes from, first match wins:

1. the environment variable ``ASLIP_MSG_DIR``;
2. the source tree (``<repo>/msg`` beside the ``aslip_ros`` package);
3. ``share/aslip_ros/msg`` under every ``AMENT_PREFIX_PATH`` entry (colcon install);
4. ``share/aslip_ros/msg`` under ``sys.prefix`` (``pip install .`` ships them there as
   ``data_files``).

Reading does not depend on that search when the bag carries its own message definitions
(mcap always does): types unknown to the Jazzy store are registered from the bag itself.
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
import sys
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from aslip_ros import frames, topics
from aslip_ros.audio_frame import stamp_to_ns  # noqa: F401 - part of this API
from aslip_ros.data.bag_errors import BagDamaged, BagError
from aslip_ros.data.pose_cdr import StampedPose, decode_pose_stamped

PACKAGE = "aslip_ros"
AUDIO_TYPE = "aslip_ros/msg/AudioFrame"
SLIP_TYPE = "aslip_ros/msg/SlipVector"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
STRING_TYPE = "std_msgs/msg/String"
CUSTOM_DATA_KEY = "aslip"
METADATA_FORMAT = "aslip-metadata"
METADATA_VERSION = 1


#: The pose topics of :class:`Topics` (a recording's metadata may name its own).
POSE_TOPICS = ("finger", "object", "tcp")


@dataclass(frozen=True)
class Topics:
    """Topic names of the recording contract (aslip_ros/topics.py); override per deployment."""

    audio: str = topics.AUDIO
    finger: str = topics.FINGER
    object: str = topics.OBJECT
    tcp: str = topics.TCP
    metadata: str = topics.METADATA
    slip_truth: str = topics.SLIP_TRUTH

    def named_in(self, meta: dict, keep: tuple = ()) -> "Topics":
        """These names, with the pose topics a recording's metadata names (``topics``:
        finger, object, tcp: a motion-capture driver's own) except those in ``keep``."""
        named = meta.get("topics") if isinstance(meta, dict) else None
        if not isinstance(named, dict):
            return self
        return replace(self, **{k: named[k] for k in POSE_TOPICS
                                if isinstance(named.get(k), str) and named[k]
                                and k not in keep})


DEFAULT_TOPICS = Topics()

# Frames each pose topic is expressed in (aslip_ros/frames.py).
POSE_FRAMES = {"finger": frames.WORLD, "object": frames.WORLD, "tcp": frames.BASE}


def _qos(kind: str):
    """Offered QoS recorded with each topic, as docs/design.md specifies for its publisher."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)
    zero = QosTime(0, 0)
    reliability, durability, depth = {
        "sensor": (QosReliability.BEST_EFFORT, QosDurability.VOLATILE, 10),
        "latched": (QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, 1),
        "reliable": (QosReliability.RELIABLE, QosDurability.VOLATILE, 10),
    }[kind]
    return [Qos(QosHistory.KEEP_LAST, depth, reliability, durability, zero, zero,
                QosLiveliness.AUTOMATIC, zero, False)]


# ---------------------------------------------------------------------------------------
# Message definitions and typestore


def _msg_dir_candidates() -> list[Path]:
    out: list[Path] = []
    env = os.environ.get("ASLIP_MSG_DIR")
    if env:
        out.append(Path(env))
    out.append(Path(__file__).resolve().parents[2] / "msg")
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            out.append(Path(prefix) / "share" / PACKAGE / "msg")
    for prefix in dict.fromkeys([sys.prefix, sys.base_prefix]):
        out.append(Path(prefix) / "share" / PACKAGE / "msg")
    return out


def find_msg_dir() -> Path:
    """Return the directory holding the project's ``.msg`` files (see module docstring)."""
    tried = _msg_dir_candidates()
    for cand in tried:
        if (cand / "AudioFrame.msg").is_file():
            return cand
    raise FileNotFoundError(
        "aslip_ros message definitions (AudioFrame.msg) not found; looked in: "
        + ", ".join(str(p) for p in tried)
        + ". Set ASLIP_MSG_DIR to the package's msg/ directory.")


def project_msg_texts(msg_dir: str | os.PathLike | None = None) -> dict[str, str]:
    """Map ROS 2 type name (``aslip_ros/msg/<Name>``) to its ``.msg`` text."""
    root = Path(msg_dir) if msg_dir is not None else find_msg_dir()
    texts = {f"{PACKAGE}/msg/{p.stem}": p.read_text()
             for p in sorted(root.glob("*.msg"))}
    if not texts:
        raise FileNotFoundError(f"no .msg files in {root}")
    return texts


def _base_store():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


@lru_cache(maxsize=1)
def typestore():
    """Jazzy typestore with the project's message types registered (cached, shared).

    Treat it as read-only: readers that need a bag's own definitions build their own store.
    """
    from rosbags.typesys import get_types_from_msg
    store = _base_store()
    types: dict = {}
    for name, text in project_msg_texts().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def _time_msg(store, ns: int):
    Time = store.types["builtin_interfaces/msg/Time"]
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def pose_from_msg(msg: Any) -> np.ndarray:
    """``geometry_msgs/Pose`` (or PoseStamped) -> ``(x, y, z, qx, qy, qz, qw)`` float64."""
    if isinstance(msg, StampedPose):
        return msg.pose.copy()
    pose = getattr(msg, "pose", msg)
    p, q = pose.position, pose.orientation
    return np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=np.float64)


def make_metadata(**fields: Any) -> dict:
    """Scenario metadata dict with the format header of docs/design.md."""
    meta = {"format": METADATA_FORMAT, "version": METADATA_VERSION}
    meta.update(fields)
    return meta


def __getattr__(name: str):
    # The writer lives in its own module; ``bags.BagWriter`` stays its public name.
    if name == "BagWriter":
        from aslip_ros.data.bag_writer import BagWriter
        return BagWriter
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def parse_metadata(text: str, where: str = "metadata") -> dict:
    """Parse the JSON metadata document; a clear ValueError when it is not one."""
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise BagError(f"{where}: not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise BagError(f"{where}: expected a JSON object, got {type(meta).__name__}")
    fmt = meta.get("format", METADATA_FORMAT)
    if fmt != METADATA_FORMAT:
        raise BagError(f"{where}: format {fmt!r} is not {METADATA_FORMAT!r}")
    return meta


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
        store = _base_store()
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
