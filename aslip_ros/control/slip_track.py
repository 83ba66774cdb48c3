"""Slip-track: move the gripper with the object while it slips in the grasp.

The model predicts the slip vector: the velocity of the object RELATIVE to the finger, in
the grasp plane (``vx`` along the fingers, ``vz`` vertical; design.md). Commanding the slip
itself (``v = gain * slip``) is a proportional loop on the relative velocity: as soon as the
arm follows, slip shrinks and so does the command, and the arm settles at ``g / (1 + g)`` of
the object's speed while the relative pose drifts at the rest. The object's own velocity is
what the arm has to match, and it is observable:

    v_obj  = v_arm + slip                       (grasp plane)

so the law is a feed-forward of the estimated object velocity

    target   = v_arm + gain * shape(slip)       (deadband, gain 1 = full correction)
    v_grasp  = lowpass(target) + k_p * d        (d: integrated slip, leaky, clipped)
    v_grasp  = saturate(v_grasp)                (magnitude; direction kept)
    v_base   = R_base_tcp * R_tcp_grasp * v_grasp

With ``gain`` 1 and an exact slip estimate the arm velocity cancels out of the loop (the
command is the object's velocity, whatever the arm does): no feedback through the arm's lag,
hence no stability limit from it. A slip estimate scaled by ``k`` leaves a loop gain of
``1 - gain * k`` per update, stable for ``0 < gain * k < 2`` and still with zero
steady-state relative drift, because any remaining relative velocity shows up as slip.

Arm velocity ``v_arm``: the TCP displacement over the model's window (``velocity_window_s``,
200 ms), differentiated from the TCP pose stream, projected into the grasp plane. Why the
measured pose and not the commanded velocity: the slip estimate is an average over the
model's window of the relative velocity, so the arm velocity has to be averaged over the
same window for the sum to be the object velocity; and only the measured pose contains what
the arm really did (its ~20 ms lag, its own speed limit, workspace clipping on the xArm, a
stop by the pendant). A commanded velocity that was not executed would be counted as object
motion and the arm would run away with it. A 200 ms difference is also far less noisy than
a per-sample derivative.

``d`` is the relative displacement accumulated since the start (the integral of the
shaped slip): an optional position term ``k_p * d`` (``position_gain_1_s``, off by default)
would remove what slipped during the detection delay instead of keeping that offset; it
leaks with ``position_leak_s`` (model errors integrate too) and is clipped to
``max_offset_m``. It fails its ablation on the scene: the integral also holds the
estimate's own errors, and the arm driven by it makes the object slip the other way, which
the model then hears backwards (docs/results.md, "Where slip-track loses its
millimetres": 2/s costs 1.1 mm of RMSE over 100 paired slip-tracks).

When slip ends (the relative pose is stable again) the arm keeps the last object-velocity
estimate for ``hold_s`` (a stable relative pose while the arm moves means the object moves
with it; it also bridges dropouts of the slip decision), then decays it to zero with
``decay_s`` and waits for the next slip; with ``stop_on_slip_end`` it instead ends the task.
If the object really stopped, the moving arm makes it slip backwards, which the estimate
picks up at once (``v_arm + slip`` = 0). Stale slip estimates or TCP poses, a fault or
shutdown stop the arm and latch until :meth:`SlipTrack.reset`.
"""

from __future__ import annotations

import collections
import enum
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from aslip_ros.control.command import DEFAULT_DURATION_S, VelocityCommand
from aslip_ros.control.frames import (IDENTITY_POSE, as_pose, base_to_grasp, grasp_to_base,
                                      planar_slip)
from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S, Watchdog

#: Below this commanded speed a decaying hold counts as finished [m/s].
_REST_M_S = 1e-4


class TrackState(enum.Enum):
    """Phases of slip tracking."""

    IDLE = 'idle'          # not started
    WAITING = 'waiting'    # started, no slip: nothing to send
    TRACKING = 'tracking'  # slipping: following the object
    HOLDING = 'holding'    # slip just ended: keeping, then decaying, the object velocity
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
    """Parameters of slip tracking (SI units). The defaults are the tuned law the node, its
    config file and the demo run (a 50 ms low-pass, a 0.3 s hold decaying over 0.2 s, the
    position term off: module docstring); each ``0`` below switches its part off.

    :param gain: fraction of the estimated slip corrected (1 = command the estimated object
        velocity; the steady state matches the object for any gain in (0, 2)).
    :param deadband_m_s: slip speeds below this count as no slip (model noise floor).
    :param max_speed_m_s: saturation of the commanded speed; the direction is kept.
    :param lowpass_tau_s: time constant of a first-order low-pass on the velocity target;
        0 = off.
    :param hold_s: how long the last object-velocity estimate is kept after slip ends.
    :param decay_s: time constant of its decay to zero after the hold; 0 = stop at once.
    :param velocity_window_s: span of TCP poses the arm velocity is measured over (the
        model's window).
    :param position_gain_1_s: gain of the integrated-slip position term [1/s]; 0 = off.
    :param position_leak_s: leak time constant of the integrated slip [s]; 0 = no leak.
    :param max_offset_m: clip of the integrated slip's magnitude [m].
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
    lowpass_tau_s: float = 0.05
    hold_s: float = 0.3
    decay_s: float = 0.2
    velocity_window_s: float = 0.2
    position_gain_1_s: float = 0.0
    position_leak_s: float = 3.0
    max_offset_m: float = 0.03
    stop_on_slip_end: bool = False
    grasp_plane_in_tcp: Sequence[float] = tuple(IDENTITY_POSE)
    slip_timeout_s: float = DEFAULT_TIMEOUT_S
    pose_timeout_s: float = DEFAULT_TIMEOUT_S
    command_duration_s: float = DEFAULT_DURATION_S

    def __post_init__(self) -> None:
        _finite('gain', self.gain, 0.0, strict=True)
        if self.gain >= 2.0:
            raise ValueError(f'gain must be < 2 (the correction loop is unstable beyond), '
                             f'got {self.gain}')
        _finite('deadband_m_s', self.deadband_m_s, 0.0, strict=False)
        _finite('max_speed_m_s', self.max_speed_m_s, 0.0, strict=True)
        _finite('lowpass_tau_s', self.lowpass_tau_s, 0.0, strict=False)
        _finite('hold_s', self.hold_s, 0.0, strict=False)
        _finite('decay_s', self.decay_s, 0.0, strict=False)
        _finite('velocity_window_s', self.velocity_window_s, 0.0, strict=True)
        _finite('position_gain_1_s', self.position_gain_1_s, 0.0, strict=False)
        _finite('position_leak_s', self.position_leak_s, 0.0, strict=False)
        _finite('max_offset_m', self.max_offset_m, 0.0, strict=False)
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


def _saturate(v: np.ndarray, limit: float) -> np.ndarray:
    speed = float(np.linalg.norm(v))
    return v * (limit / speed) if speed > limit else v


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
        # (time, position) of recent TCP poses: the arm velocity over the model's window.
        self._poses: collections.deque = collections.deque()
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

    def on_tcp_pose(self, pose: Sequence[float], now: Optional[float] = None,
                    stamp: Optional[float] = None) -> bool:
        """Feed the TCP pose in ``link_base``. Returns False (and counts it) if invalid.

        ``stamp`` [s] is when the pose was measured (the message stamp); the arm velocity
        uses it, so delivery jitter on a loaded machine does not distort it. Without it the
        arrival time ``now`` stands in. The watchdog always uses the arrival time.
        """
        try:
            p = as_pose(pose, 'tcp_pose')
        except ValueError:
            with self._lock:
                self.rejected_inputs += 1
            return False
        with self._lock:
            self._pose_wd.feed(self._now(now))
            self._pose = p
            t = self._now(now) if stamp is None else float(stamp)
            if self._poses and t < self._poses[-1][0] - 1.0:
                self._poses.clear()     # the pose clock went back: start a new history
            if self._poses and t <= self._poses[-1][0]:
                self._poses[-1] = (self._poses[-1][0], p[:3].copy())
            else:
                self._poses.append((t, p[:3].copy()))
            # Keep one sample older than the window so the span always covers it.
            while len(self._poses) > 2 and \
                    self._poses[1][0] <= t - self._cfg.velocity_window_s:
                self._poses.popleft()
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
            cfg = self._cfg
            dt = 0.0 if self._last_step is None else max(0.0, t - self._last_step)
            self._last_step = t
            slip_g = shape_slip(self._slip, 1.0, cfg.deadband_m_s, math.inf) \
                if self._slipping else np.zeros(3)
            self._integrate(slip_g, dt)
            if np.any(slip_g):
                v_arm = self.arm_velocity_grasp()
                target = _saturate(v_arm + cfg.gain * slip_g, cfg.max_speed_m_s)
                self._state = TrackState.TRACKING
                self._entered = t
                self._v_ref = self._filter(target, dt)
                return self._send(self._v_ref + self._position_term())
            if self._state is TrackState.TRACKING:
                self._state = TrackState.HOLDING
                self._entered = t
            if self._state is TrackState.HOLDING:
                age = t - self._entered
                if age < cfg.hold_s:
                    scale = 1.0
                elif cfg.decay_s > 0.0:
                    scale = math.exp(-(age - cfg.hold_s) / cfg.decay_s)
                else:
                    scale = 0.0
                v = self._v_ref * scale
                if scale < 1.0 and float(np.linalg.norm(v)) < _REST_M_S:
                    self._v_filt = np.zeros(3)
                    self._v_ref = np.zeros(3)
                    if cfg.stop_on_slip_end:
                        return self._latch('slip ended')
                    self._state = TrackState.WAITING
                    self._entered = t
                    # One hard zero so the arm does not coast on the last command.
                    return self._send(np.zeros(3))
                self._v_filt = v
                return self._send(v + self._position_term() * scale)
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

    @property
    def offset(self) -> np.ndarray:
        """Integrated slip (relative displacement estimate) in the grasp plane [m]."""
        with self._lock:
            return self._offset.copy()

    def arm_velocity_grasp(self) -> np.ndarray:
        """Measured TCP velocity over ``velocity_window_s``, in the grasp plane (y = 0)."""
        with self._lock:
            if len(self._poses) < 2 or self._pose is None:
                return np.zeros(3)
            (t0, p0), (t1, p1) = self._poses[0], self._poses[-1]
            if t1 - t0 < 1e-3:
                return np.zeros(3)
            v = base_to_grasp((p1 - p0) / (t1 - t0), self._pose, self._calib)
            v[1] = 0.0
            # Never commanded faster than max_speed_m_s: a faster TCP is a jump in the pose
            # stream (or someone else moving the arm), not motion to feed forward.
            return _saturate(v, self._cfg.max_speed_m_s)

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
        self._v_ref = np.zeros(3)
        self._v_base = np.zeros(3)
        self._offset = np.zeros(3)

    def _latch_state(self, reason: str) -> None:
        if self._state is TrackState.STOPPED:
            return
        self._state = TrackState.STOPPED
        self._reason = reason
        self._halt_sent = False
        self._v_filt = np.zeros(3)
        self._v_ref = np.zeros(3)
        self._v_base = np.zeros(3)

    def _latch(self, reason: str) -> Optional[VelocityCommand]:
        self._latch_state(reason)
        self._halt_sent = True
        return VelocityCommand.halt(reason)

    def _integrate(self, slip_g: np.ndarray, dt: float) -> None:
        cfg = self._cfg
        if cfg.position_gain_1_s <= 0.0:
            return
        if cfg.position_leak_s > 0.0:
            self._offset *= math.exp(-dt / cfg.position_leak_s)
        self._offset = _saturate(self._offset + slip_g * dt, cfg.max_offset_m)

    def _position_term(self) -> np.ndarray:
        return self._cfg.position_gain_1_s * self._offset

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
        v_grasp = _saturate(np.asarray(v_grasp, dtype=float), self._cfg.max_speed_m_s)
        self._v_base = grasp_to_base(v_grasp, self._pose, self._calib)
        return VelocityCommand(self._v_base.copy(), self._cfg.command_duration_s)
