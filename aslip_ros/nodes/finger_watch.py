"""The finger rigid body's poses for a bring-up check (``aslip check grasp-axes``): one
PoseStamped topic, or the finger's body of a mocap4r2 RigidBodies topic (picked by
:func:`aslip_ros.rigid_bodies.select_bodies`), in a context and thread of its own, averaged
on request."""

from __future__ import annotations

import threading
import time
from typing import Optional

import numpy as np
from scipy.spatial.transform import Rotation

from aslip_ros.poses import as_pose
from aslip_ros.rigid_bodies import BodyTally


class FingerWatch:
    """Subscribes to ``topic`` (sensor QoS, as mocap_bridge) until :meth:`close`: a
    PoseStamped topic, or with ``body`` (its name or numeric ID) a RigidBodies topic."""

    def __init__(self, topic: str, body: Optional[str] = None) -> None:
        import rclpy
        from geometry_msgs.msg import PoseStamped
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from aslip_ros.runtime.qos import SENSOR_QOS
        from aslip_ros.nodes import convert
        self.topic = topic
        self._convert = convert
        self._got: list = []
        self._lock = threading.Lock()
        self._messages = 0
        self._bodies = {'finger': str(body)} if body is not None else {}
        self._tally = BodyTally(self._bodies)
        msg_type = convert.rigid_bodies_class() if body is not None else PoseStamped
        self._ctx = Context()
        rclpy.init(context=self._ctx)
        self._node = rclpy.create_node('aslip_check_grasp_axes', context=self._ctx)
        self._node.create_subscription(msg_type, topic, self._on_rigid_bodies if body
                                       is not None else self._on_pose, SENSOR_QOS)
        self._ex = SingleThreadedExecutor(context=self._ctx)
        self._ex.add_node(self._node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on_pose(self, msg) -> None:
        with self._lock:
            self._messages += 1
        try:
            _, _, pose = self._convert.pose_from_msg(msg)
        except ValueError:
            return                      # a damaged pose is a dropped frame here
        with self._lock:
            self._got.append((time.monotonic(), pose))
            del self._got[:-2000]

    def _on_rigid_bodies(self, msg) -> None:
        sel = self._convert.select_bodies(msg, self._bodies)
        with self._lock:
            self._messages += 1
            self._tally.add(sel)
        if 'finger' not in sel.poses:
            return
        try:
            pose = as_pose(sel.poses['finger'], 'finger pose')
        except ValueError:
            return                      # a damaged pose is a dropped frame here
        with self._lock:
            self._got.append((time.monotonic(), pose))
            del self._got[:-2000]

    def _spin(self) -> None:
        import rclpy
        while rclpy.ok(context=self._ctx):
            try:
                self._ex.spin_once(timeout_sec=0.1)
            except Exception:  # noqa: BLE001 - the context went down under us
                return

    @property
    def messages(self) -> int:
        """Messages received so far (with a pose of the finger or not)."""
        with self._lock:
            return self._messages

    def mean_pose(self, seconds: float) -> np.ndarray:
        """The finger pose averaged over the next ``seconds``.

        :raises ValueError: no pose arrived meanwhile.
        """
        with self._lock:
            self._tally = BodyTally(self._bodies)
        t0 = time.monotonic()
        time.sleep(seconds)
        with self._lock:
            got = np.array([p for t, p in self._got if t >= t0])
            missing = self._tally.text(f'RigidBodies messages on {self.topic} in '
                                       f'{seconds:g} s')
        if not len(got) and missing:
            raise ValueError(f'{missing}: is the body named as the driver names it '
                             '(OptiTrack: the Motive ID)?')
        if not len(got):
            what = f'RigidBodies on {self.topic} with the finger\'s body ' \
                f'{self._bodies["finger"]!r}' if self._bodies else f'finger pose on {self.topic}'
            raise ValueError(f'no {what} in {seconds:g} s: is the motion capture running and '
                             'the rigid body tracked (aslip check mocap)?')
        return np.concatenate([got[:, :3].mean(axis=0),
                               Rotation.from_quat(got[:, 3:]).mean().as_quat()])

    def close(self) -> None:
        """Stop and release the context."""
        import rclpy
        self._node.destroy_node()
        rclpy.try_shutdown(context=self._ctx)
        self._thread.join(timeout=5.0)
