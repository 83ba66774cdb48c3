"""A test-only arm, loaded by a controller node as ``arm:=fake_arm:make_arm`` (test/helpers
is on the node processes' path).

It shows everything a new arm needs: the six methods of
:class:`aslip_ros.arm.Arm` and a factory ``(node, params) -> Arm``. The controller
wraps it in the configured speed and workspace limits, polls its TCP on the arm thread and
republishes it. Every call is appended as one JSON line to the file named by the
``FAKE_ARM_LOG`` environment variable, so the test can read what reached the arm.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

from aslip_ros.arm import ArmError


class FakeArm:
    """A point TCP that moves at the commanded velocity until the command expires."""

    def __init__(self, log_path: str) -> None:
        self._log = open(log_path, "a", buffering=1)
        self._pose = np.array([0.4, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0])
        self._v = np.zeros(3)
        self._until = 0.0
        self._t = time.monotonic()
        self._enabled = False

    def _record(self, call: str, **values) -> None:
        self._log.write(json.dumps(dict(call=call, t=time.monotonic(), **values)) + "\n")

    def _advance(self) -> None:
        now = time.monotonic()
        moving = max(0.0, min(now, self._until) - self._t)
        self._pose[:3] += self._v * moving
        self._t = now

    def connect(self) -> None:
        self._record("connect")

    def enable_velocity_mode(self) -> None:
        self._enabled = True
        self._record("enable")

    def send_velocity(self, v_xyz_m_s, duration_s: float) -> None:
        if not self._enabled:
            raise ArmError("fake arm: velocity mode is not enabled")
        self._advance()
        self._v = np.asarray(v_xyz_m_s, dtype=float).copy()
        self._until = self._t + float(duration_s)
        self._record("velocity", v=self._v.tolist(), duration=float(duration_s))

    def stop(self) -> None:
        self._advance()
        self._v = np.zeros(3)
        self._enabled = False
        self._record("stop")

    def tcp_pose(self) -> np.ndarray:
        self._advance()
        return self._pose.copy()

    def close(self) -> None:
        self.stop()
        self._record("close")
        self._log.close()


def make_arm(node, params):
    """The factory the controller node calls with itself and its parameter values."""
    return FakeArm(os.environ["FAKE_ARM_LOG"])
