"""The xArm's connection and safety settings, its error type and the SDK's constants."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

from aslip_ros.arm import ArmError
from aslip_ros.control.limits import ArmLimits

#: Cartesian velocity control mode (``set_mode(5)``).
MODE_CARTESIAN_VELOCITY = 5
#: Motion state (``set_state(0)``) and stop state (``set_state(4)``).
STATE_MOTION = 0
STATE_STOP = 4
#: The controller discards Cartesian velocity commands arriving faster than this.
CONTROLLER_MAX_RATE_HZ = 250.0
#: First firmware that honours ``duration`` in ``vc_set_cartesian_velocity``; older
#: firmware silently treats every command as "forever".
MIN_FIRMWARE_FOR_DURATION = (1, 8, 0)


class XArmError(ArmError):
    """An SDK call returned a non-zero code (``code``), or the adapter refused to go on."""

    def __init__(self, message: str, code: Optional[int] = None,
                 controller_error: Optional[int] = None,
                 controller_warning: Optional[int] = None) -> None:
        super().__init__(message)
        self.code = code
        self.controller_error = controller_error
        self.controller_warning = controller_warning


def _check_positive(name: str, value: float) -> None:
    if not math.isfinite(float(value)) or float(value) <= 0.0:
        raise ValueError(f'{name} must be finite and > 0, got {value}')


@dataclass(frozen=True)
class XArmConfig:
    """xArm connection and safety limits (SI units, ``link_base``).

    The limits default to :class:`~aslip_ros.control.limits.ArmLimits`' (every arm's); the
    workspace default is a conservative box in front of an arm on a table: measure your
    cell and set it (docs/hardware.md).

    :param ip: controller IP address.
    :param max_speed_m_s: TCP speed limit; faster commands are scaled down (direction kept).
    :param max_acc_m_s2: limit on the change of commanded velocity per second; a zero
        command (a stop) is never delayed by it.
    :param workspace_min_m: lower corner of the allowed TCP box.
    :param workspace_max_m: upper corner of the allowed TCP box.
    :param max_rate_hz: command rate limit, at most 250 Hz (the controller's own limit).
    :param max_duration_s: longest ``duration`` ever sent; longer requests are shortened.
    :param connect_timeout_s: deadline for connecting before the arm counts as unreachable.
    :param mode_settle_s: wait after switching mode/state, before the first command.
    :param report_max_age_s: a pose from the SDK's report stream counts as current this
        long; an older one (or none) is queried with a round trip instead.
    :param status_period_s: while streaming, the controller's error and warning codes are
        queried this often (velocity commands do not return them: the SDK maps a warning
        to success).
    """

    ip: str
    max_speed_m_s: float = ArmLimits.max_speed_m_s
    max_acc_m_s2: float = ArmLimits.max_acc_m_s2
    workspace_min_m: Sequence[float] = ArmLimits.workspace_min_m
    workspace_max_m: Sequence[float] = ArmLimits.workspace_max_m
    max_rate_hz: float = ArmLimits.max_rate_hz
    max_duration_s: float = ArmLimits.max_duration_s
    connect_timeout_s: float = 5.0
    mode_settle_s: float = 0.5
    report_max_age_s: float = 0.05
    status_period_s: float = 0.1

    def __post_init__(self) -> None:
        if not isinstance(self.ip, str) or not self.ip.strip():
            raise ValueError('ip must be a non-empty string')
        for name in ('max_speed_m_s', 'max_acc_m_s2', 'max_rate_hz', 'max_duration_s',
                     'connect_timeout_s', 'report_max_age_s', 'status_period_s'):
            _check_positive(name, getattr(self, name))
        if self.max_rate_hz > CONTROLLER_MAX_RATE_HZ:
            raise ValueError(f'max_rate_hz must be <= {CONTROLLER_MAX_RATE_HZ:g} (the xArm '
                             f'drops faster commands), got {self.max_rate_hz}')
        if not math.isfinite(self.mode_settle_s) or self.mode_settle_s < 0.0:
            raise ValueError(f'mode_settle_s must be finite and >= 0, got {self.mode_settle_s}')
        limits = self.limits
        object.__setattr__(self, 'workspace_min_m', limits.workspace_min_m)
        object.__setattr__(self, 'workspace_max_m', limits.workspace_max_m)

    @property
    def limits(self) -> ArmLimits:
        """The limits every command obeys (validated)."""
        return ArmLimits(max_speed_m_s=self.max_speed_m_s, max_acc_m_s2=self.max_acc_m_s2,
                         workspace_min_m=self.workspace_min_m,
                         workspace_max_m=self.workspace_max_m, max_rate_hz=self.max_rate_hz,
                         max_duration_s=self.max_duration_s)
