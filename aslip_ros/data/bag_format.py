"""What a bag of the project holds: the contract that the writer and the reader share.

Message type names, topic names (:class:`Topics`), the frame of each pose stream, the
offered QoS recorded with each topic, the metadata document (key, format, version), and the
project's message types registered with a ``rosbags`` typestore built on the Jazzy standard
types, so bags written here hold the same definitions, type hashes and CDR bytes that
rosbag2 records from live publishers. :mod:`.bag_writer` and :mod:`.bags` (the reader) both
build on this module; neither imports the other's internals.

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

import json
import os
import sys
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

from aslip_ros import frames, topics
from aslip_ros.data.bag_errors import BagError

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


def offered_qos(kind: str):
    """Offered QoS recorded with each topic, as docs/design.md specifies for its publisher:
    ``kind`` is "sensor", "latched" or "reliable"."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                    QosTime)
    zero = QosTime(0, 0)
    reliability, durability, depth = {
        "sensor": (QosReliability.BEST_EFFORT, QosDurability.VOLATILE, 10),
        "latched": (QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, 1),
        "reliable": (QosReliability.RELIABLE, QosDurability.VOLATILE, 10),
    }[kind]
    return [Qos(QosHistory.KEEP_LAST, depth, reliability, durability, zero, zero,
                QosLiveliness.AUTOMATIC, zero, False)]


# ---------------------------------------------------------------------------------------
# The metadata document


def make_metadata(**fields: Any) -> dict:
    """Scenario metadata dict with the format header of docs/design.md."""
    meta = {"format": METADATA_FORMAT, "version": METADATA_VERSION}
    meta.update(fields)
    return meta


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


def base_store():
    """A fresh Jazzy typestore without the project's types (a reader adds a bag's own)."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def project_store():
    """A fresh Jazzy typestore with the project's message types registered (one of its own,
    for a writer that registers more types: a driver's, :func:`add_installed_types`)."""
    from rosbags.typesys import get_types_from_msg
    store = base_store()
    types: dict = {}
    for name, text in project_msg_texts().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


@lru_cache(maxsize=1)
def typestore():
    """Jazzy typestore with the project's message types registered (cached, shared).

    Treat it as read-only: readers that need a bag's own definitions build their own store.
    """
    return project_store()


def installed_msg_texts(package: str) -> dict[str, str]:
    """``<package>/msg/<Name>`` -> ``.msg`` text of every message of an installed interface
    package: ``share/<package>/msg`` under the first ``AMENT_PREFIX_PATH`` entry that has it
    (where colcon and the ROS distribution install them, and where rosbag2 reads them); {}
    when the package is not installed."""
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        folder = Path(prefix) / "share" / package / "msg"
        if prefix and folder.is_dir():
            texts = {f"{package}/msg/{p.stem}": p.read_text()
                     for p in sorted(folder.glob("*.msg"))}
            if texts:
                return texts
    return {}


def add_installed_types(store, type_name: str) -> bool:
    """Register the messages of ``type_name``'s installed package in ``store`` (a driver's
    type, e.g. ``mocap4r2_msgs/msg/RigidBodies``) unless the store has the type already;
    False when it has no definition of it afterwards (the package is not installed).
    Their own dependencies (``geometry_msgs``, ``std_msgs``) are Jazzy's, in every store."""
    if type_name in store.types:
        return True
    from rosbags.typesys import get_types_from_msg
    texts = installed_msg_texts(type_name.split("/")[0])
    if type_name not in texts:
        return False
    types: dict = {}
    for name, text in texts.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return True


def time_msg(store, ns: int):
    """``builtin_interfaces/Time`` of ``store`` for ``ns`` nanoseconds."""
    Time = store.types["builtin_interfaces/msg/Time"]
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))
