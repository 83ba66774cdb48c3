"""The one interface every arm satisfies: the xArm adapter and the scene's simulated arm.

Controllers only ever talk to an :class:`Arm`; they never import a driver. All values are
SI (metres, seconds, m/s) in the arm's base frame (``link_base``, REP 103). On floor 0
(docs/design.md): control/, the scene's arm and hw/ take it from here, none from another.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


class ArmError(RuntimeError):
    """The arm refused a command, reported an error, or could not be reached."""


@runtime_checkable
class Arm(Protocol):
    """A Cartesian-velocity-controlled arm."""

    def connect(self) -> None:
        """Open the connection; raise :class:`ArmError` if the arm cannot be reached."""

    def enable_velocity_mode(self) -> None:
        """Prepare the arm to accept Cartesian velocity commands."""

    def send_velocity(self, v_xyz_m_s: np.ndarray, duration_s: float) -> None:
        """Command a TCP linear velocity [m/s] in ``link_base``.

        The arm must stop by itself if no new command arrives within ``duration_s`` seconds
        (the controller-side timeout), so a crashed caller never leaves it moving.
        """

    def stop(self) -> None:
        """Stop now. Must be safe to call at any time, also after an error."""

    def tcp_pose(self) -> np.ndarray:
        """Current TCP pose ``(x, y, z, qx, qy, qz, qw)`` in ``link_base`` [m]."""

    def close(self) -> None:
        """Stop and release the connection."""
