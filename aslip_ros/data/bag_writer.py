"""Writing rosbag2 (mcap) bags of the project's topics, without ROS (``bags.BagWriter``).

Bags get the project's typestore and offered-QoS records (``aslip_ros.data.bag_format``) and
the MCAP CRCs that rosbags leaves at zero (``aslip_ros.data.mcap_crc``).
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from aslip_ros import frames
from aslip_ros.data.bag_errors import BagError
from aslip_ros.data.bag_format import (AUDIO_TYPE, CUSTOM_DATA_KEY, DEFAULT_TOPICS,
                                       METADATA_FORMAT, METADATA_VERSION, POSE_FRAMES, POSE_TYPE,
                                       SLIP_TYPE, STRING_TYPE, Topics, offered_qos, time_msg,
                                       typestore)
from aslip_ros.slip import DEFAULT_THRESHOLD
from aslip_ros.util import atomic_path


class BagWriter:
    """Write a rosbag2 (mcap, version 9) bag of the project's topics, atomically.

    Use as a context manager. The bag directory appears at ``path`` only when the block
    exits without an exception. Times are seconds relative to ``start_ns`` (ROS time of
    t = 0); the log time of each message equals its header stamp. ``store``: a ``rosbags``
    typestore whose definitions the bag records instead of the project's (``bag_format.
    typestore()``).
    """

    def __init__(self, path: str | os.PathLike, *, metadata: Mapping | None = None,
                 topics: Topics = DEFAULT_TOPICS, start_ns: int = 0,
                 overwrite: bool = False, audio_frame_id: str = frames.GRIPPER,
                 store=None):
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise BagError(f"{self.path} exists already (pass overwrite=True to replace it)")
        if start_ns < 0:
            raise ValueError(f"start_ns must be >= 0, got {start_ns}")
        self.topics = topics
        self.start_ns = int(start_ns)
        self.audio_frame_id = audio_frame_id
        self._metadata = dict(metadata) if metadata is not None else None
        # The message definitions recorded with each topic: the project's own, or another
        # typestore's (a recording of an older definition, e.g. in tests).
        self._store = typestore() if store is None else store
        self._writer = None
        self._conns: dict[str, Any] = {}
        self._stack: contextlib.ExitStack | None = None
        self._T = self._store.types

    # context management -----------------------------------------------------------------
    def __enter__(self) -> "BagWriter":
        from rosbags.rosbag2 import StoragePlugin, Writer

        from aslip_ros.data.mcap_crc import CrcMcapWriter

        class _Writer(Writer):
            STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: CrcMcapWriter}

        self._stack = contextlib.ExitStack()
        tmp = self._tmp = self._stack.enter_context(atomic_path(self.path))
        self._writer = _Writer(tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        if self._metadata is not None:
            self.write_metadata(self._metadata)
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        stack, self._stack = self._stack, None
        try:
            if exc_type is None:
                self._writer.close()        # CrcMcapWriter seals the file as it closes
            else:
                with contextlib.suppress(Exception):
                    self._writer.abort()
                # Make atomic_path discard the temporary bag instead of renaming it.
                stack.__exit__(exc_type, exc, tb)
                return False
        except BaseException as err:
            stack.__exit__(type(err), err, err.__traceback__)
            raise
        stack.close()
        return False

    # low level ----------------------------------------------------------------------------
    def _ns(self, t: float) -> int:
        ns = self.start_ns + int(round(float(t) * 1e9))
        if ns < 0:
            raise ValueError(f"time {t} s lies before the bag's start")
        return ns

    def _header(self, ns: int, frame_id: str):
        return self._T["std_msgs/msg/Header"](stamp=time_msg(self._store, ns),
                                              frame_id=frame_id)

    def write(self, topic: str, msgtype: str, msg: Any, log_ns: int,
              qos: str = "reliable") -> None:
        """Serialize ``msg`` (a rosbags message object) onto ``topic`` at ``log_ns``.

        ``qos`` ("sensor", "latched" or "reliable") is recorded as the topic's offered QoS
        when the topic first appears, so ``ros2 bag play`` republishes it the same way.
        """
        if self._writer is None:
            raise BagError("BagWriter used outside its `with` block")
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self._store,
                                               offered_qos_profiles=offered_qos(qos))
            self._conns[topic] = conn
        elif conn.msgtype != msgtype:
            raise BagError(f"topic {topic} already holds {conn.msgtype}, not {msgtype}")
        self._writer.write(conn, int(log_ns), self._store.serialize_cdr(msg, msgtype))

    # typed helpers --------------------------------------------------------------------------
    def write_metadata(self, metadata: Mapping, t: float = 0.0) -> None:
        """Store metadata as the bag's ``custom_data['aslip']`` and on the metadata topic."""
        meta = dict(metadata)
        meta.setdefault("format", METADATA_FORMAT)
        meta.setdefault("version", METADATA_VERSION)
        text = json.dumps(meta, sort_keys=True)
        self._writer.set_custom_data(CUSTOM_DATA_KEY, text)
        self.write(self.topics.metadata, STRING_TYPE, self._T[STRING_TYPE](data=text),
                   self._ns(t), qos="latched")

    def write_audio(self, t: float, first_sample_index: int, block: np.ndarray,
                    sample_rate: float, channel_names: Sequence[str],
                    layout: str = "") -> None:
        """One ``AudioFrame``: ``block`` is (frames, channels) float32, ``t`` its first sample."""
        block = np.asarray(block)
        if block.ndim != 2 or block.shape[1] != len(channel_names):
            raise ValueError(f"audio block shape {block.shape} does not match "
                             f"{len(channel_names)} channel names")
        ns = self._ns(t)
        msg = self._T[AUDIO_TYPE](
            header=self._header(ns, self.audio_frame_id), sample_rate=float(sample_rate),
            channel_names=list(channel_names), layout=str(layout),
            first_sample_index=int(first_sample_index),
            data=np.ascontiguousarray(block, dtype=np.float32).reshape(-1))
        self.write(self.topics.audio, AUDIO_TYPE, msg, ns, qos="sensor")

    def write_pose(self, which: str, t: float, pose: Sequence[float],
                   frame_id: str | None = None) -> None:
        """PoseStamped on the ``finger``, ``object`` or ``tcp`` topic; pose = x y z qx qy qz qw."""
        if which not in POSE_FRAMES:
            raise ValueError(f"unknown pose stream {which!r}; expected one of "
                             f"{sorted(POSE_FRAMES)}")
        p = np.asarray(pose, dtype=np.float64).reshape(-1)
        if p.size != 7:
            raise ValueError(f"pose must have 7 numbers (x y z qx qy qz qw), got {p.size}")
        T = self._T
        ns = self._ns(t)
        msg = T[POSE_TYPE](
            header=self._header(ns, frame_id or POSE_FRAMES[which]),
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                orientation=T["geometry_msgs/msg/Quaternion"](x=p[3], y=p[4], z=p[5],
                                                              w=p[6])))
        self.write(getattr(self.topics, which), POSE_TYPE, msg, ns, qos="sensor")

    def write_slip_truth(self, t_end: float, vx: float, vz: float, window_s: float,
                         threshold_m_s: float, frame_id: str = frames.GRASP_PLANE,
                         wy: float = 0.0) -> None:
        """A ``SlipVector`` from ground truth (source ``mocap_truth``) ending at ``t_end``;
        ``wy`` [rad/s] is its ``angular_velocity`` (not gated by the planar decision)."""
        T = self._T
        speed = float(np.hypot(vx, vz))
        slipping = speed > threshold_m_s
        ns = self._ns(t_end)
        msg = T[SLIP_TYPE](
            header=self._header(ns, frame_id), probability=1.0 if slipping else 0.0,
            slipping=bool(slipping), threshold=DEFAULT_THRESHOLD,
            velocity=T["geometry_msgs/msg/Vector3"](
                x=float(vx) if slipping else 0.0, y=0.0, z=float(vz) if slipping else 0.0),
            speed=speed if slipping else 0.0,
            direction=float(np.arctan2(vz, vx)) if slipping else 0.0,
            direction_sigma=-1.0, angular_velocity=float(wy), angular_velocity_sigma=-1.0,
            window_length=float(window_s), source="mocap_truth")
        self.write(self.topics.slip_truth, SLIP_TYPE, msg, ns)
