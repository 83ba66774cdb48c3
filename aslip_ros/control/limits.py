"""Speed, acceleration, workspace and rate limits around any :class:`~aslip_ros.arm.Arm`.

A driver only has to move its arm; :class:`LimitedArm` makes every command safe first, the
same way for every arm (the xArm adapter is a ``LimitedArm`` around its SDK driver):

- a request that is not a finite 3-vector with a finite duration > 0 stops the arm and
  raises (a zero or negative duration means "never stop" to some drivers);
- the duration is capped at ``max_duration_s``, so the arm stops by itself soon after the
  commands stop;
- commands are sent no faster than ``max_rate_hz``: a faster one waits (counted in
  ``commands_delayed``) rather than being dropped, as it could be the one that slows down;
- the speed is clipped to ``max_speed_m_s`` (direction kept), then the change from the
  previous command to ``max_acc_m_s2`` (a zero command, a stop, is never delayed), then each
  component so that the TCP at most reaches the workspace box within the command's
  duration; a TCP already outside the box stops the arm and raises.

SI units in the arm's base frame (``link_base``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence, Tuple, Type

import numpy as np

from aslip_ros.arm import Arm, ArmError
from aslip_ros.control.frames import as_vector3

_LOG = logging.getLogger(__name__)


def _tuple3(name: str, value: Sequence[float]) -> Tuple[float, float, float]:
    return tuple(float(x) for x in as_vector3(value, name))  # type: ignore[return-value]


def checked_command(v_xyz_m_s: Any, duration_s: Any) -> Tuple[np.ndarray, float]:
    """A velocity command's vector and duration, validated: three finite components and a
    finite duration above zero (to an arm SDK, 0 or less often means "never stop").
    ValueError otherwise."""
    v = as_vector3(v_xyz_m_s, 'velocity')
    duration = float(duration_s)
    if not math.isfinite(duration) or duration <= 0.0:
        raise ValueError(f'duration must be finite and > 0 s, got {duration_s}')
    return v, duration


@dataclass(frozen=True)
class ArmLimits:
    """The limits every command obeys (SI units, ``link_base``); the defaults are every
    arm's (the xArm's config, the sweeps and the nodes' ``arm_*`` parameters take them from
    here). The workspace default is a conservative box in front of an arm on a table.

    :param max_speed_m_s: TCP speed limit; faster commands are scaled down (direction kept).
    :param max_acc_m_s2: limit on the change of commanded velocity per second; a zero
        command (a stop) is never delayed by it.
    :param workspace_min_m: lower corner of the allowed TCP box.
    :param workspace_max_m: upper corner of the allowed TCP box.
    :param max_rate_hz: command rate limit.
    :param max_duration_s: longest ``duration`` ever sent; longer requests are shortened.
    """

    max_speed_m_s: float = 0.1
    max_acc_m_s2: float = 1.0
    workspace_min_m: Sequence[float] = (0.15, -0.45, 0.02)
    workspace_max_m: Sequence[float] = (0.70, 0.45, 0.60)
    max_rate_hz: float = 200.0
    max_duration_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ('max_speed_m_s', 'max_acc_m_s2', 'max_rate_hz', 'max_duration_s'):
            value = getattr(self, name)
            if not math.isfinite(float(value)) or float(value) <= 0.0:
                raise ValueError(f'{name} must be finite and > 0, got {value}')
        lo = _tuple3('workspace_min_m', self.workspace_min_m)
        hi = _tuple3('workspace_max_m', self.workspace_max_m)
        if not all(a < b for a, b in zip(lo, hi)):
            raise ValueError(f'workspace_min_m {lo} must be below workspace_max_m {hi} on '
                             'every axis')
        object.__setattr__(self, 'workspace_min_m', lo)
        object.__setattr__(self, 'workspace_max_m', hi)


class LimitedArm:
    """An :class:`~aslip_ros.arm.Arm` whose commands obey :class:`ArmLimits`.

    Every other attribute is the wrapped arm's (``wrapped.set_pose_listener`` etc.).
    Thread-safe: commands are serialised.

    :param arm: the arm to protect.
    :param limits: the limits.
    :param clock: monotonic time source for the rate and acceleration limits.
    :param sleep: used by the rate limit.
    :param error: the :class:`ArmError` subclass raised on a refused command.
    """

    #: The rate limit waits: callers keep this arm off threads that must not block.
    blocking = True

    def __init__(self, arm: Arm, limits: ArmLimits,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep,
                 error: Type[ArmError] = ArmError) -> None:
        self.wrapped = arm
        self.limits = limits
        self._clock = clock
        self._sleep = sleep
        self._error = error
        self._lock = threading.RLock()
        self._lo = np.array(limits.workspace_min_m)
        self._hi = np.array(limits.workspace_max_m)
        self._last_send_t: Optional[float] = None
        self._last_v = np.zeros(3)
        self._last_duration = 0.0
        self.commands_delayed = 0
        self.commands_clipped = 0

    def __getattr__(self, name: str) -> Any:
        # Only reached for names this class lacks: the wrapped arm's extras.
        if name == 'wrapped':
            raise AttributeError(name)
        return getattr(self.wrapped, name)

    # -- Arm protocol -----------------------------------------------------------------------

    def connect(self) -> None:
        """Connect the wrapped arm."""
        self.wrapped.connect()

    def enable_velocity_mode(self) -> None:
        """Enable the wrapped arm's velocity mode; the next command starts from rest."""
        with self._lock:
            self.wrapped.enable_velocity_mode()
            self._last_send_t = None
            self._last_v = np.zeros(3)

    def send_velocity(self, v_xyz_m_s: np.ndarray, duration_s: float) -> None:
        """Command a TCP velocity [m/s, ``link_base``] for ``duration_s``, within the limits.

        Raises (after stopping the arm) on an invalid request or a TCP outside the
        workspace; the wrapped arm's own errors pass through.
        """
        with self._lock:
            try:
                v, duration = checked_command(v_xyz_m_s, duration_s)
            except ValueError as exc:
                self._stop_quietly()
                raise self._error(f'refused command: {exc}') from exc
            duration = min(duration, self.limits.max_duration_s)
            self._respect_rate_limit()
            position = np.asarray(self.wrapped.tcp_pose(), dtype=np.float64)[:3]
            if np.any(position < self._lo) or np.any(position > self._hi):
                self._stop_quietly()
                raise self._error(f'TCP {np.round(position, 4).tolist()} m is outside the '
                                  f'workspace {self._lo.tolist()}..{self._hi.tolist()}; '
                                  'stopped')
            now = self._clock()
            cmd = self.clip(v, position, duration, now)
            if not np.array_equal(cmd, v):
                self.commands_clipped += 1
            self.wrapped.send_velocity(cmd, duration)
            self._last_send_t = now
            self._last_v = cmd
            self._last_duration = duration

    def stop(self) -> None:
        """Stop the wrapped arm now (never limited)."""
        with self._lock:
            self._last_v = np.zeros(3)
        self.wrapped.stop()

    def tcp_pose(self) -> np.ndarray:
        """The wrapped arm's TCP pose."""
        return self.wrapped.tcp_pose()

    def close(self) -> None:
        """Stop and release the wrapped arm."""
        self.wrapped.close()

    # -- the limits -------------------------------------------------------------------------

    def clip(self, v: np.ndarray, position: np.ndarray, duration: float,
             now: float) -> np.ndarray:
        """Speed, then acceleration, then workspace limits (the last one wins)."""
        lim = self.limits
        speed = float(np.linalg.norm(v))
        if speed > lim.max_speed_m_s:
            v = v * (lim.max_speed_m_s / speed)
        if np.any(v != 0.0):
            previous = np.zeros(3)
            dt = 1.0 / lim.max_rate_hz
            if self._last_send_t is not None:
                elapsed = now - self._last_send_t
                # After its duration the previous command has expired: the arm is at rest.
                if elapsed <= self._last_duration:
                    previous = self._last_v
                dt = max(dt, elapsed)
            dv = v - previous
            max_dv = lim.max_acc_m_s2 * dt
            n = float(np.linalg.norm(dv))
            if n > max_dv:
                v = previous + dv * (max_dv / n)
        # Aim each component at most at the box wall within this command's duration.
        reach_hi = (self._hi - position) / duration
        reach_lo = (self._lo - position) / duration
        return np.minimum(np.maximum(np.array(v, dtype=np.float64), reach_lo), reach_hi)

    def _respect_rate_limit(self) -> None:
        if self._last_send_t is None:
            return
        wait = 1.0 / self.limits.max_rate_hz - (self._clock() - self._last_send_t)
        if wait > 0.0:
            self.commands_delayed += 1
            self._sleep(wait)

    def _stop_quietly(self) -> None:
        try:
            self.stop()
        except Exception as exc:  # noqa: BLE001 - already raising the reason for the stop
            _LOG.error('stop after a refused command failed too: %s', exc)
