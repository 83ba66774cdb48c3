"""Slip-track: move the gripper with the object while it slips in the grasp.

The model predicts the slip vector: the velocity of the object relative to the finger, in
the grasp plane (``vx`` along the fingers, ``vz`` vertical; design.md). Moving the gripper
by the same velocity cancels the relative motion, so the command is a proportional map

    v_grasp = gain * slip           (zero inside the deadband, magnitude-saturated,
                                     optionally low-pass filtered)
    v_base  = R_base_tcp * R_tcp_grasp * v_grasp

with the grasp plane's orientation from the newest TCP pose and the TCP calibration.

When the slip ends the controller commands zero velocity for ``hold_s`` (so the arm is held
still and a brief dropout of the slip decision does not make it lurch), then sends nothing
and waits for the next slip; with ``stop_on_slip_end`` it instead ends the task. Stale
slip estimates or TCP poses, a fault or shutdown stop the arm and latch until
:meth:`SlipTrack.reset`.
"""

from __future__ import annotations

import enum
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from aslip_ros.control.command import VelocityCommand
from aslip_ros.control.frames import IDENTITY_POSE, as_pose, grasp_to_base, planar_slip
from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S, Watchdog


class TrackState(enum.Enum):
    """Phases of slip tracking."""

    IDLE = 'idle'          # not started
    WAITING = 'waiting'    # started, no slip: nothing to send
    TRACKING = 'tracking'  # slipping: following the object
    HOLDING = 'holding'    # slip just ended: commanding zero velocity for hold_s
    STOPPED = 'stopped'    # latched: stale input, fault, shutdown or slip ended (one-shot)


def _finite(name: str, value: float, minimum: float, strict: bool) -> float:
    value = float(value)
    bad = not math.isfinite(value) or (value <= minimum if strict else value < minimum)
    if bad:
        op = '>' if strict else '>='
        raise ValueError(f'{name} must be finite and {op} {minimum}, got {value}')
    return value


@dataclass(frozen=True)
class SlipTrackConfig:
    """Parameters of slip tracking (SI units).

    :param gain: gripper velocity per unit of slip velocity (1 = match the estimated slip).
    :param deadband_m_s: slip speeds below this count as no slip (model noise floor).
    :param max_speed_m_s: saturation of the commanded speed; the direction is kept.
    :param lowpass_tau_s: time constant of a first-order low-pass on the command; 0 = off.
    :param hold_s: how long zero velocity is held after slip ends.
    :param stop_on_slip_end: end the task (latched stop) after the hold instead of waiting
        for the next slip.
    :param grasp_plane_in_tcp: calibration pose of ``aslip_grasp_plane`` in the TCP frame.
    :param slip_timeout_s: slip estimates older than this are stale (watchdog).
    :param pose_timeout_s: TCP poses older than this are stale (watchdog).
    :param command_duration_s: validity of each velocity command on the arm.
    """

    gain: float = 1.0
    deadband_m_s: float = 0.002
    max_speed_m_s: float = 0.05
    lowpass_tau_s: float = 0.0
    hold_s: float = 0.2
    stop_on_slip_end: bool = False
    grasp_plane_in_tcp: Sequence[float] = tuple(IDENTITY_POSE)
    slip_timeout_s: float = DEFAULT_TIMEOUT_S
    pose_timeout_s: float = DEFAULT_TIMEOUT_S
    command_duration_s: float = 0.1

    def __post_init__(self) -> None:
        _finite('gain', self.gain, 0.0, strict=True)
        _finite('deadband_m_s', self.deadband_m_s, 0.0, strict=False)
        _finite('max_speed_m_s', self.max_speed_m_s, 0.0, strict=True)
        _finite('lowpass_tau_s', self.lowpass_tau_s, 0.0, strict=False)
        _finite('hold_s', self.hold_s, 0.0, strict=False)
        _finite('slip_timeout_s', self.slip_timeout_s, 0.0, strict=True)
        _finite('pose_timeout_s', self.pose_timeout_s, 0.0, strict=True)
        _finite('command_duration_s', self.command_duration_s, 0.0, strict=True)
        object.__setattr__(self, 'grasp_plane_in_tcp',
                           tuple(as_pose(self.grasp_plane_in_tcp, 'grasp_plane_in_tcp')))


def shape_slip(slip_xz: Sequence[float], gain: float, deadband_m_s: float,
               max_speed_m_s: float) -> np.ndarray:
    """Map a planar slip ``(vx, vz)`` to a grasp-plane velocity ``(vx, 0, vz)``.

    Deadband and saturation act on the vector's magnitude so the direction is preserved
    (clipping each axis separately would bend diagonal slip towards 45 degrees).
    """
    s = planar_slip(slip_xz[0], slip_xz[1])
    speed = float(np.linalg.norm(s))
    if speed <= deadband_m_s:
        return np.zeros(3)
    v = gain * s
    v_speed = gain * speed
    if v_speed > max_speed_m_s:
        v *= max_speed_m_s / v_speed
    return v


class SlipTrack:
    """Slip-tracking controller. Thread-safe; every method takes an optional ``now``.

    Typical use from a node::

        ctl = SlipTrack(SlipTrackConfig(gain=1.0))
        # subscriptions:          ctl.on_slip((vx, vz), msg_is_slipping); ctl.on_tcp_pose(p7)
        # when activated:         ctl.start()
        # control timer (100 Hz): apply_command(arm, ctl.step())
        # on shutdown:            ctl.shutdown(); apply_command(arm, ctl.step())
    """

    def __init__(self, config: SlipTrackConfig,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Create an idle controller; ``clock`` is the monotonic time source."""
        self._cfg = config
        self._calib = np.array(config.grasp_plane_in_tcp)
        self._clock = clock
        self._lock = threading.RLock()
        self._slip_wd = Watchdog(config.slip_timeout_s, clock)
        self._pose_wd = Watchdog(config.pose_timeout_s, clock)
        self._pose: Optional[np.ndarray] = None
        self._slip = np.zeros(2)
        self._slipping = False
        self.rejected_inputs = 0
        self._reset_state()

    # -- inputs -------------------------------------------------------------------------

    def on_slip(self, slip_xz: Sequence[float], slipping: Optional[bool] = None,
                now: Optional[float] = None) -> bool:
        """Feed one slip estimate: grasp-plane ``(vx, vz)`` [m/s] and the slip decision.

        ``slipping=None`` derives the decision from the deadband. A non-finite vector is
        rejected (returns False, counted) and does not refresh the watchdog.
        """
        v = np.asarray(slip_xz, dtype=np.float64).reshape(-1)
        if v.shape != (2,) or not np.all(np.isfinite(v)):
            with self._lock:
                self.rejected_inputs += 1
            return False
        with self._lock:
            self._slip_wd.feed(self._now(now))
            self._slip = v
            if slipping is None:
                slipping = float(np.linalg.norm(v)) > self._cfg.deadband_m_s
            self._slipping = bool(slipping)
        return True

    def on_tcp_pose(self, pose: Sequence[float], now: Optional[float] = None) -> bool:
        """Feed the TCP pose in ``link_base``. Returns False (and counts it) if invalid."""
        try:
            p = as_pose(pose, 'tcp_pose')
        except ValueError:
            with self._lock:
                self.rejected_inputs += 1
            return False
        with self._lock:
            self._pose = p
            self._pose_wd.feed(self._now(now))
        return True

    # -- commands -------------------------------------------------------------------------

    def start(self, now: Optional[float] = None) -> None:
        """Start (or restart after :meth:`reset`) tracking.

        :raises RuntimeError: when stopped (call :meth:`reset` first).
        """
        with self._lock:
            if self._state is TrackState.STOPPED:
                raise RuntimeError(f'stopped ({self._reason}); reset() before start()')
            if self._state is TrackState.IDLE:
                self._state = TrackState.WAITING
                self._entered = self._now(now)

    def step(self, now: Optional[float] = None) -> Optional[VelocityCommand]:
        """Advance and return this cycle's command (``None``: nothing to send)."""
        with self._lock:
            t = self._now(now)
            if self._state is TrackState.STOPPED:
                if not self._halt_sent:
                    self._halt_sent = True
                    return VelocityCommand.halt(self._reason)
                return None
            if self._state is TrackState.IDLE:
                return None
            # Only a moving (or about-to-move) arm needs fresh inputs; while waiting, a
            # stale stream must still prevent the next slip from starting a motion, and
            # latching here makes the fault visible instead of silently never tracking.
            if self._slip_wd.is_stale(t):
                return self._latch(f'stale slip: none for {self._slip_wd.age(t):.3f} s')
            if self._pose_wd.is_stale(t):
                return self._latch(f'stale pose: none for {self._pose_wd.age(t):.3f} s')
            dt = 0.0 if self._last_step is None else max(0.0, t - self._last_step)
            self._last_step = t
            if self._slipping:
                target = shape_slip(self._slip, self._cfg.gain, self._cfg.deadband_m_s,
                                    self._cfg.max_speed_m_s)
                self._state = TrackState.TRACKING
                self._entered = t
                v = self._filter(target, dt)
                return self._send(v)
            if self._state is TrackState.TRACKING:
                self._state = TrackState.HOLDING
                self._entered = t
            if self._state is TrackState.HOLDING:
                if t - self._entered >= self._cfg.hold_s:
                    self._v_filt = np.zeros(3)
                    if self._cfg.stop_on_slip_end:
                        return self._latch('slip ended')
                    self._state = TrackState.WAITING
                    self._entered = t
                    return None
                # Holding is a hard zero: a filter tail would keep the gripper drifting
                # after the object has stopped.
                self._v_filt = np.zeros(3)
                return self._send(np.zeros(3))
            return None

    def fault(self, detail: str = '', now: Optional[float] = None) -> None:
        """Latch a stop on an external error; the next step returns a stop command."""
        with self._lock:
            self._latch_state(f'error: {detail}' if detail else 'error')

    def shutdown(self, now: Optional[float] = None) -> None:
        """Latch a stop because the process is shutting down."""
        with self._lock:
            self._latch_state('shutdown')

    def reset(self) -> None:
        """Return to IDLE and clear the filter (inputs and watchdogs are kept)."""
        with self._lock:
            self._reset_state()

    # -- status ---------------------------------------------------------------------------

    @property
    def config(self) -> SlipTrackConfig:
        """The controller's configuration."""
        return self._cfg

    @property
    def state(self) -> TrackState:
        """Current phase."""
        with self._lock:
            return self._state

    @property
    def reason(self) -> str:
        """Why the controller latched a stop ('' when not stopped)."""
        with self._lock:
            return self._reason

    @property
    def last_velocity(self) -> np.ndarray:
        """The newest commanded velocity in ``link_base`` [m/s]."""
        with self._lock:
            return self._v_base.copy()

    # -- internals ------------------------------------------------------------------------

    def _now(self, now: Optional[float]) -> float:
        return self._clock() if now is None else float(now)

    def _reset_state(self) -> None:
        self._state = TrackState.IDLE
        self._entered = 0.0
        self._reason = ''
        self._halt_sent = True
        self._last_step: Optional[float] = None
        self._v_filt = np.zeros(3)
        self._v_base = np.zeros(3)

    def _latch_state(self, reason: str) -> None:
        if self._state is TrackState.STOPPED:
            return
        self._state = TrackState.STOPPED
        self._reason = reason
        self._halt_sent = False
        self._v_filt = np.zeros(3)
        self._v_base = np.zeros(3)

    def _latch(self, reason: str) -> Optional[VelocityCommand]:
        self._latch_state(reason)
        self._halt_sent = True
        return VelocityCommand.halt(reason)

    def _filter(self, target: np.ndarray, dt: float) -> np.ndarray:
        tau = self._cfg.lowpass_tau_s
        if tau <= 0.0:
            self._v_filt = target
        else:
            # Exact discretisation of a first-order lag, so the response does not depend on
            # the control rate or on jitter in the timer.
            alpha = 1.0 - math.exp(-dt / tau)
            self._v_filt = self._v_filt + alpha * (target - self._v_filt)
        return self._v_filt

    def _send(self, v_grasp: np.ndarray) -> VelocityCommand:
        self._v_base = grasp_to_base(v_grasp, self._pose, self._calib)
        return VelocityCommand(self._v_base.copy(), self._cfg.command_duration_s)
