"""The finger rigid body's poses for a bring-up check (``aslip check grasp-axes``): one
PoseStamped topic, in a context and thread of its own, averaged on request."""

from __future__ import annotations

import threading
import time

import numpy as np
from scipy.spatial.transform import Rotation


class FingerWatch:
    """Subscribes to ``topic`` (sensor QoS, as mocap_bridge) until :meth:`close`."""

    def __init__(self, topic: str) -> None:
        import rclpy
        from geometry_msgs.msg import PoseStamped
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from aslip_ros.nodes import common as c
        from aslip_ros.nodes import convert
        self.topic = topic
        self._convert = convert
        self._got: list = []
        self._lock = threading.Lock()
        self._ctx = Context()
        rclpy.init(context=self._ctx)
        self._node = rclpy.create_node('aslip_check_grasp_axes', context=self._ctx)
        self._node.create_subscription(PoseStamped, topic, self._on_pose, c.SENSOR_QOS)
        self._ex = SingleThreadedExecutor(context=self._ctx)
        self._ex.add_node(self._node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on_pose(self, msg) -> None:
        try:
            _, _, pose = self._convert.pose_from_msg(msg)
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

    def mean_pose(self, seconds: float) -> np.ndarray:
        """The finger pose averaged over the next ``seconds``.

        :raises ValueError: no pose arrived meanwhile.
        """
        t0 = time.monotonic()
        time.sleep(seconds)
        with self._lock:
            got = np.array([p for t, p in self._got if t >= t0])
        if not len(got):
            raise ValueError(f'no finger pose on {self.topic} in {seconds:g} s: is the motion '
                             'capture running and the rigid body tracked (aslip check mocap)?')
        return np.concatenate([got[:, :3].mean(axis=0),
                               Rotation.from_quat(got[:, 3:]).mean().as_quat()])

    def close(self) -> None:
        """Stop and release the context."""
        import rclpy
        self._node.destroy_node()
        rclpy.try_shutdown(context=self._ctx)
        self._thread.join(timeout=5.0)
