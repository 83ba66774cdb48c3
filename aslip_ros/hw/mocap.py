"""Motion capture through NatNet (OptiTrack Motive), behind a small ROS-free interface.

This is one option for the mocap bridge; any ROS driver publishing ``PoseStamped`` works as
well (docs/hardware.md). The client's data thread only converts the rigid bodies of each
frame into ``world`` poses and puts them in a bounded queue; the consumer reads frames or
asks for the newest pose of a body.

Motive streams Y-up by default while ``world`` is Z-up (REP 103); ``up_axis='y'`` rotates
every pose by +90 degrees about x, which maps Motive's +y onto +z. Only the world frame
changes: each rigid body keeps its own local axes as defined in Motive (a body created
level in Motive has its local +y pointing up), so a grasp-plane calibration measured
against the body frame stays valid whichever ``up_axis`` is streamed.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Mapping, Optional

import numpy as np
from scipy.spatial.transform import Rotation


class MocapError(RuntimeError):
    """The motion-capture server could not be reached."""


@dataclass(frozen=True)
class RigidBodyPose:
    """One rigid body in one frame: ``pose`` is ``(x, y, z, qx, qy, qz, qw)`` in ``world``."""

    name: str
    pose: np.ndarray
    tracking_valid: bool


@dataclass(frozen=True)
class MocapFrame:
    """The configured rigid bodies of one capture frame.

    :ivar host_time: ``time.time()`` when the frame arrived [s].
    :ivar server_time: the server's timestamp of the frame [s] (Motive's clock).
    """

    frame_number: int
    host_time: float
    server_time: float
    bodies: Dict[str, RigidBodyPose] = field(default_factory=dict)


_Y_UP_TO_Z_UP = Rotation.from_euler('x', math.pi / 2.0)


def default_client_factory(server_ip: str, local_ip: str, use_multicast: bool) -> Any:
    """A ``natnet.NatNetClient`` (imported lazily: the package is optional)."""
    from natnet import NatNetClient
    return NatNetClient(server_ip_address=server_ip, local_ip_address=local_ip,
                        use_multicast=use_multicast)


class NatNetMocap:
    """Rigid-body poses from a NatNet server.

    :param server_ip: Motive's address; ``local_ip``: this machine's address on that network.
    :param rigid_bodies: ``name -> streaming id`` of the bodies to report (Motive's
        "Streaming ID"); other bodies are ignored.
    :param up_axis: ``'y'`` (Motive's default) or ``'z'``: the server's vertical axis.
    :param queue_frames: frames kept for :meth:`read`; older ones are dropped and counted.
    :param client_factory: ``(server_ip, local_ip, use_multicast) -> client``; tests inject
        a fake with the NatNetClient interface.
    """

    def __init__(self, server_ip: str, local_ip: str, rigid_bodies: Mapping[str, int],
                 up_axis: str = 'y', use_multicast: bool = True, queue_frames: int = 64,
                 connect_timeout_s: float = 5.0,
                 client_factory: Optional[Callable[[str, str, bool], Any]] = None,
                 host_clock: Callable[[], float] = time.time) -> None:
        """Validate the configuration; nothing is contacted until :meth:`start`."""
        if up_axis not in ('y', 'z'):
            raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
        if not rigid_bodies:
            raise ValueError('rigid_bodies must name at least one body')
        ids = [int(i) for i in rigid_bodies.values()]
        if len(set(ids)) != len(ids):
            raise ValueError(f'rigid body ids must be unique: {dict(rigid_bodies)}')
        if int(queue_frames) < 1:
            raise ValueError('queue_frames must be >= 1')
        if not math.isfinite(connect_timeout_s) or connect_timeout_s <= 0.0:
            raise ValueError('connect_timeout_s must be finite and > 0')
        self._server_ip = server_ip
        self._local_ip = local_ip
        self._by_id = {int(i): str(n) for n, i in rigid_bodies.items()}
        self._to_world = _Y_UP_TO_Z_UP if up_axis == 'y' else Rotation.identity()
        self._use_multicast = bool(use_multicast)
        self._timeout = float(connect_timeout_s)
        self._factory = client_factory or default_client_factory
        self._host_clock = host_clock
        self._queue: 'queue.Queue[MocapFrame]' = queue.Queue(maxsize=int(queue_frames))
        self._lock = threading.Lock()
        self._latest: Dict[str, RigidBodyPose] = {}
        self._latest_time: Dict[str, float] = {}
        self._client: Any = None
        self.frames_received = 0
        self.frames_dropped = 0
        self.frames_rejected = 0

    def start(self) -> None:
        """Connect and start receiving on the client's threads; :class:`MocapError` if not."""
        if self._client is not None:
            return
        try:
            client = self._factory(self._server_ip, self._local_ip, self._use_multicast)
            client.on_data_frame_received_event.handlers.append(self._on_frame)
            client.connect(timeout=self._timeout)
            client.run_async()
        except Exception as exc:  # noqa: BLE001 - TimeoutError, socket errors, NatNetError
            raise MocapError(f'cannot reach NatNet server {self._server_ip}: {exc!r}') from exc
        self._client = client

    def stop(self) -> None:
        """Stop receiving and close the client's sockets."""
        client, self._client = self._client, None
        if client is not None:
            client.shutdown()

    close = stop

    def read(self, timeout_s: Optional[float] = None) -> Optional[MocapFrame]:
        """Next frame, waiting up to ``timeout_s``; ``None`` on timeout."""
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def latest(self, name: str) -> Optional[RigidBodyPose]:
        """The newest tracked pose of a body, or ``None`` if never seen."""
        with self._lock:
            return self._latest.get(name)

    def latest_host_time(self, name: str) -> float:
        """``time.time()`` of the newest pose of a body (``-inf`` if never seen)."""
        with self._lock:
            return self._latest_time.get(name, -math.inf)

    def to_world(self, position: Any, quat_xyzw: Any) -> np.ndarray:
        """Convert a server-frame position and quaternion to a ``world`` pose."""
        p = self._to_world.apply(np.asarray(position, dtype=np.float64))
        q = (self._to_world * Rotation.from_quat(np.asarray(quat_xyzw, dtype=np.float64)))
        return np.concatenate([p, q.as_quat()])

    def _on_frame(self, frame: Any) -> None:
        # Runs on the client's data thread: convert, store, enqueue; never raise into it.
        try:
            host_time = self._host_clock()
            bodies: Dict[str, RigidBodyPose] = {}
            for rb in getattr(frame, 'rigid_bodies', ()):
                name = self._by_id.get(int(rb.id_num))
                if name is None:
                    continue
                pos = np.asarray(rb.pos, dtype=np.float64)
                rot = np.asarray(rb.rot, dtype=np.float64)
                valid = rb.tracking_valid is not False
                if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(rot))
                        and np.linalg.norm(rot) > 1e-6):
                    valid = False
                    pose = np.full(7, np.nan)
                else:
                    pose = self.to_world(pos, rot)
                bodies[name] = RigidBodyPose(name, pose, valid)
            suffix = getattr(frame, 'suffix', None)
            prefix = getattr(frame, 'prefix', None)
            mocap_frame = MocapFrame(
                frame_number=int(getattr(prefix, 'frame_number', -1)),
                host_time=host_time,
                server_time=float(getattr(suffix, 'timestamp', math.nan)),
                bodies=bodies)
            with self._lock:
                self.frames_received += 1
                for name, body in bodies.items():
                    # Lost tracking must not overwrite the last good pose with garbage; the
                    # consumer sees the body go stale instead.
                    if body.tracking_valid:
                        self._latest[name] = body
                        self._latest_time[name] = host_time
            try:
                self._queue.put_nowait(mocap_frame)
            except queue.Full:
                with self._lock:
                    self.frames_dropped += 1
        except Exception:  # noqa: BLE001 - a malformed frame must not kill the data thread
            with self._lock:
                self.frames_rejected += 1
