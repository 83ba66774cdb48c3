"""What a controller asks of the arm each control cycle, and how that reaches an :class:`Arm`.

The controllers are pure logic: they return a :class:`VelocityCommand` (or ``None``) and the
caller (an rclpy node, the scene's closed loop, a test) hands it to :func:`apply_command`.
Keeping the arm out of the controllers keeps them testable without an arm and lets the
node decide which thread talks to hardware.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from aslip_ros.arm import Arm

#: Validity of a velocity command on the arm [s]: it stops by itself this long after the
#: newest command (every controller's ``command_duration_s`` default).
DEFAULT_DURATION_S = 0.1


# eq=False: field-wise == on numpy arrays is ambiguous; compare fields explicitly.
@dataclass(frozen=True, eq=False)
class VelocityCommand:
    """One control-cycle output.

    ``stop=True`` means "call :meth:`Arm.stop` now" (a fault, a finished task, shutdown);
    otherwise send ``velocity`` [m/s, ``link_base``] valid for ``duration_s`` seconds, after
    which the arm stops by itself unless a newer command arrives.
    """

    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    duration_s: float = DEFAULT_DURATION_S
    stop: bool = False
    reason: str = ''

    @staticmethod
    def halt(reason: str) -> 'VelocityCommand':
        """A stop command carrying why the controller stopped."""
        return VelocityCommand(np.zeros(3), 0.0, True, reason)


def apply_command(arm: Arm, command: Optional[VelocityCommand]) -> None:
    """Send a controller output to an arm; ``None`` sends nothing.

    :raises ArmError: from the arm; the caller must then treat the controller as faulted.
    """
    if command is None:
        return
    if command.stop:
        arm.stop()
    else:
        arm.send_velocity(command.velocity, command.duration_s)
