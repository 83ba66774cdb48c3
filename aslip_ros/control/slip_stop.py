"""Slip-stop: the paper's wall-push task as a ROS-free state machine.

The grasped object starts in contact with a wall. The arm retracts (10 cm by default) away
from the wall, settles, then re-approaches along the configured direction at a constant
speed; when the object hits the wall it starts slipping in the grasp, and the arm stops as
soon as slip is detected. The figure of merit is the stopping distance: how far past the
initial contact pose the arm came to rest, along the approach direction (the paper's
``Delta x``).

Rotational slip (issue #21): an object held off its centre, or pushed off its axis, may turn
between the pads about the pad normal (+y of ``aslip_grasp_plane``) while it hardly slides.
The estimate's ``slipping`` decision stays planar (``aslip_ros.slip``), so the task also reads
the estimated angular velocity: with ``stop_on_rotation`` an estimate whose
``|angular_velocity|`` reaches ``rotation_threshold_rad_s`` counts as a slipping estimate in
the same debounce, and a stop that planar slip alone would not have made is reported as
:attr:`StopReason.ROTATION`.

The class only computes commands. The caller feeds it slip estimates and TCP poses (from
any thread), calls :meth:`SlipStop.step` at the control rate and hands the returned
:class:`~aslip_ros.control.command.VelocityCommand` to the arm with
:func:`~aslip_ros.control.command.apply_command`.

Safety: every moving state needs fresh slip estimates and fresh TCP poses (watchdogs);
stale input, a fault, shutdown, too much travel or too much time all end the task with a
stop command, and a stopped task stays stopped until :meth:`SlipStop.reset`.
"""

from __future__ import annotations

import enum
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from aslip_ros.control.command import DEFAULT_DURATION_S, VelocityCommand
from aslip_ros.control.frames import as_pose, as_vector3
from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S, Watchdog


class State(enum.Enum):
    """Phases of the wall-push task."""

    IDLE = 'idle'
    RETRACTING = 'retracting'
    SETTLING = 'settling'
    APPROACHING = 'approaching'
    STOPPED = 'stopped'


class StopReason(str, enum.Enum):
    """Why the task ended. :attr:`SLIP` and :attr:`ROTATION` are successful trials (the
    object met the wall and the arm stopped on what the estimator heard); the rest are not.
    """

    SLIP = 'slip'
    ROTATION = 'rotation'
    MAX_TRAVEL = 'max_travel'
    TIMEOUT = 'timeout'
    STALE_SLIP = 'stale_slip'
    STALE_POSE = 'stale_pose'
    ERROR = 'error'
    SHUTDOWN = 'shutdown'


#: The stop reasons of a successful trial.
SUCCESS_REASONS = frozenset({StopReason.SLIP, StopReason.ROTATION})
#: The estimated rotation rate that counts as a slipping estimate by default [rad/s]. Chosen
#: as the streaming model's p(slip) threshold is, for a false-alarm rate: the lowest rate at
#: which two consecutive estimates turning that fast (the default debounce) stop the arm at
#: most 2 times a minute where nothing slips or turns, on fresh draws of the demo's
#: streaming training set (``benchmarks.stream_false_alarms``; the label's own 0.5 rad/s,
#: ``slip.ROTATION_EPSILON_RAD_S``, gave 2.4-3.6 such stops a minute, 0.7 gave 1.2-1.8:
#: docs/results.md, "What stops the arm where nothing slips").
ROTATION_STOP_RAD_S = 0.7


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f'{name} must be finite and > 0, got {value}')
    return value


@dataclass(frozen=True)
class SlipStopConfig:
    """Parameters of the wall-push task (SI units, ``link_base``).

    :param direction: approach direction, towards the wall, in ``link_base`` (normalised).
    :param approach_speed_m_s: constant re-approach speed.
    :param retract_distance_m: how far to back off from the contact pose (paper: 10 cm).
    :param retract_speed_m_s: speed while backing off.
    :param settle_s: pause between retract and approach, so the arm is at rest and the
        audio of the retract motion has left the model's window before slip is judged.
    :param max_approach_distance_m: hard bound on approach travel; must exceed the retract
        distance, otherwise the object could never reach the wall.
    :param debounce_count: consecutive slipping estimates needed to stop (1 = no debounce).
    :param slip_timeout_s: slip estimates older than this are stale (watchdog).
    :param pose_timeout_s: TCP poses older than this are stale (watchdog).
    :param command_duration_s: validity of each velocity command; the arm stops by itself
        when no newer command arrives in this time.
    :param time_margin: each moving phase may take at most ``margin * distance / speed + 1 s``.
    :param stop_on_rotation: an estimate with ``|angular_velocity|`` at or above
        ``rotation_threshold_rad_s`` counts as a slipping estimate (False: only the planar
        decision counts, the task ignores rotation).
    :param rotation_threshold_rad_s: the rotation rate that counts as slip [rad/s]; default
        :data:`ROTATION_STOP_RAD_S`.
    """

    direction: Sequence[float] = (1.0, 0.0, 0.0)
    approach_speed_m_s: float = 0.01
    retract_distance_m: float = 0.10
    retract_speed_m_s: float = 0.02
    settle_s: float = 0.5
    max_approach_distance_m: float = 0.15
    debounce_count: int = 2    # 2 x 10 ms hops: onset to stop 38 ms median in make demo, 3 gave 50
    slip_timeout_s: float = DEFAULT_TIMEOUT_S
    pose_timeout_s: float = DEFAULT_TIMEOUT_S
    command_duration_s: float = DEFAULT_DURATION_S
    time_margin: float = 2.0
    stop_on_rotation: bool = True
    rotation_threshold_rad_s: float = ROTATION_STOP_RAD_S

    def __post_init__(self) -> None:
        d = as_vector3(self.direction, 'direction')
        n = float(np.linalg.norm(d))
        if n < 1e-9:
            raise ValueError('direction must be a non-zero vector')
        # Frozen dataclass: store the normalised direction as an immutable tuple.
        object.__setattr__(self, 'direction', tuple(float(x) for x in d / n))
        for name in ('approach_speed_m_s', 'retract_distance_m', 'retract_speed_m_s',
                     'max_approach_distance_m', 'slip_timeout_s', 'pose_timeout_s',
                     'command_duration_s', 'rotation_threshold_rad_s'):
            _positive(name, getattr(self, name))
        if not isinstance(self.stop_on_rotation, (bool, np.bool_)):
            raise ValueError(f'stop_on_rotation must be a bool, got {self.stop_on_rotation!r}')
        if not math.isfinite(self.settle_s) or self.settle_s < 0.0:
            raise ValueError(f'settle_s must be finite and >= 0, got {self.settle_s}')
        if self.max_approach_distance_m <= self.retract_distance_m:
            raise ValueError('max_approach_distance_m must exceed retract_distance_m, or the '
                             'object can never reach the wall')
        if isinstance(self.debounce_count, bool) or int(self.debounce_count) != \
                self.debounce_count or self.debounce_count < 1:
            raise ValueError(f'debounce_count must be an integer >= 1, got '
                             f'{self.debounce_count}')
        if not math.isfinite(self.time_margin) or self.time_margin < 1.0:
            raise ValueError(f'time_margin must be >= 1, got {self.time_margin}')

    @property
    def unit_direction(self) -> np.ndarray:
        """The approach direction as a unit numpy vector."""
        return np.array(self.direction, dtype=np.float64)


@dataclass(frozen=True)
class SlipStopResult:
    """Outcome of one trial.

    Distances are signed along the approach direction. ``stopping_distance_m`` uses the
    newest TCP pose (keep feeding poses after the stop: the arm decelerates, and the resting
    pose is what the paper measures); ``command_distance_m`` is the same at the moment the
    stop was commanded.
    """

    reason: StopReason
    success: bool
    stopping_distance_m: float
    command_distance_m: float
    approach_travel_m: float
    approach_time_s: float
    detail: str = ''


class SlipStop:
    """The wall-push state machine. Thread-safe; every method takes an optional ``now``.

    Typical use from a node::

        task = SlipStop(SlipStopConfig(direction=(0, 1, 0)))
        # subscriptions:            task.on_slip(msg.slipping, angular_velocity=msg_wy)
        #                           task.on_tcp_pose(pose7)
        # after the first pose:     task.start()
        # control timer (100 Hz):   apply_command(arm, task.step())
        # on shutdown:              task.shutdown(); apply_command(arm, task.step())
    """

    def __init__(self, config: SlipStopConfig,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Create an idle task; ``clock`` is the monotonic time source shared by all methods."""
        self._cfg = config
        self._dir = config.unit_direction
        self._clock = clock
        self._lock = threading.RLock()
        self._slip_wd = Watchdog(config.slip_timeout_s, clock)
        self._pose_wd = Watchdog(config.pose_timeout_s, clock)
        self._pose: Optional[np.ndarray] = None
        self.rejected_inputs = 0
        self._reset_trial()

    # -- inputs -------------------------------------------------------------------------

    def on_slip(self, slipping: bool, now: Optional[float] = None,
                angular_velocity: float = 0.0) -> bool:
        """Feed one slip estimate: the model's planar slip/no-slip decision for one window
        and its angular velocity about the pad normal [rad/s] (0.0: none estimated).

        Returns False (and counts it in ``rejected_inputs``) for a non-finite angular
        velocity: the estimate is neither acted on nor taken as a sign of life (the
        watchdog is not fed), so a stream of them stops the arm as stale input.
        """
        try:
            w = float(angular_velocity)
        except (TypeError, ValueError):
            w = math.nan
        with self._lock:
            if not math.isfinite(w):
                self.rejected_inputs += 1
                return False
            t = self._now(now)
            self._slip_wd.feed(t)
            if self._state is not State.APPROACHING:
                # Slip while retracting or settling is arm noise or the object leaving the
                # wall; only the approach may end on slip, and its count starts from zero.
                return True
            planar = bool(slipping)
            rotating = self._cfg.stop_on_rotation and abs(w) >= self._cfg.rotation_threshold_rad_s
            self._consecutive = self._consecutive + 1 if planar or rotating else 0
            self._planar_consecutive = self._planar_consecutive + 1 if planar else 0
            if self._consecutive >= self._cfg.debounce_count:
                if self._planar_consecutive >= self._cfg.debounce_count:
                    self._stop(StopReason.SLIP, t,
                               f'{self._consecutive} consecutive slip estimates')
                else:
                    # Planar slip alone would not have stopped the arm: rotation did.
                    self._stop(StopReason.ROTATION, t,
                               f'{self._consecutive} consecutive slip or rotation estimates '
                               f'(last |angular_velocity| {abs(w):.3f} rad/s)')
            return True

    def on_tcp_pose(self, pose: Sequence[float], now: Optional[float] = None) -> bool:
        """Feed the TCP pose in ``link_base``. Returns False (and counts it) if it is invalid."""
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

    def start(self, contact_pose: Optional[Sequence[float]] = None,
              now: Optional[float] = None) -> None:
        """Begin a trial from the current contact with the wall.

        :param contact_pose: the initial wall-contact TCP pose; default: the newest TCP pose,
            which must be fresh.
        :raises RuntimeError: a trial is running, or no fresh pose to start from.
        """
        with self._lock:
            t = self._now(now)
            if self._state not in (State.IDLE, State.STOPPED):
                raise RuntimeError(f'cannot start while {self._state.value}')
            if contact_pose is None:
                if self._pose is None or self._pose_wd.is_stale(t):
                    raise RuntimeError('no fresh TCP pose to take as the contact pose')
                contact = self._pose.copy()
            else:
                contact = as_pose(contact_pose, 'contact_pose')
            self._reset_trial()
            self._contact = contact
            self._enter(State.RETRACTING, t)

    def step(self, now: Optional[float] = None) -> Optional[VelocityCommand]:
        """Advance the state machine and return this cycle's command.

        Returns a velocity command while moving, a zero-velocity command while settling,
        a stop command once when the task ends, and ``None`` when there is nothing to send.
        """
        with self._lock:
            t = self._now(now)
            if self._state in (State.RETRACTING, State.SETTLING, State.APPROACHING):
                self._check_inputs(t)
            if self._state is State.RETRACTING:
                return self._step_retract(t)
            if self._state is State.SETTLING:
                if t - self._entered >= self._cfg.settle_s:
                    self._approach_start = self._pose.copy()
                    self._enter(State.APPROACHING, t)
                    return self._move(self._dir * self._cfg.approach_speed_m_s)
                return self._move(np.zeros(3))
            if self._state is State.APPROACHING:
                return self._step_approach(t)
            if self._state is State.STOPPED and not self._halt_sent:
                self._halt_sent = True
                return VelocityCommand.halt(self._reason.value)
            return None

    def fault(self, detail: str = '', now: Optional[float] = None) -> None:
        """Abort on an external error (e.g. :class:`ArmError`); the next step stops the arm."""
        with self._lock:
            self._stop(StopReason.ERROR, self._now(now), detail)

    def shutdown(self, now: Optional[float] = None) -> None:
        """Abort because the process is shutting down; the next step stops the arm."""
        with self._lock:
            self._stop(StopReason.SHUTDOWN, self._now(now), 'shutdown')

    def reset(self) -> None:
        """Return to IDLE, forgetting the last trial (inputs and watchdogs are kept)."""
        with self._lock:
            self._reset_trial()

    # -- status ---------------------------------------------------------------------------

    @property
    def config(self) -> SlipStopConfig:
        """The task's configuration."""
        return self._cfg

    @property
    def state(self) -> State:
        """Current phase."""
        with self._lock:
            return self._state

    @property
    def reason(self) -> Optional[StopReason]:
        """Why the task stopped; ``None`` while not stopped."""
        with self._lock:
            return self._reason

    def travel(self) -> float:
        """Signed distance of the newest pose past the contact pose along the direction [m]."""
        with self._lock:
            if self._contact is None or self._pose is None:
                return math.nan
            return self._along(self._pose, self._contact)

    def result(self) -> Optional[SlipStopResult]:
        """The trial's outcome once stopped (re-evaluated with every new pose), else None."""
        with self._lock:
            if self._state is not State.STOPPED or self._contact is None:
                return None
            final = self._pose if self._pose is not None else self._stop_pose
            stop_pose = self._stop_pose if self._stop_pose is not None else final
            approach = math.nan
            if self._approach_start is not None and stop_pose is not None:
                approach = self._along(stop_pose, self._approach_start)
            return SlipStopResult(
                reason=self._reason,
                success=self._reason in SUCCESS_REASONS,
                stopping_distance_m=(self._along(final, self._contact)
                                     if final is not None else math.nan),
                command_distance_m=(self._along(stop_pose, self._contact)
                                    if stop_pose is not None else math.nan),
                approach_travel_m=approach,
                approach_time_s=(self._stop_time - self._approach_t0
                                 if self._approach_t0 is not None else math.nan),
                detail=self._detail)

    # -- internals ------------------------------------------------------------------------

    def _now(self, now: Optional[float]) -> float:
        return self._clock() if now is None else float(now)

    def _reset_trial(self) -> None:
        self._state = State.IDLE
        self._entered = 0.0
        self._reason: Optional[StopReason] = None
        self._detail = ''
        self._halt_sent = True
        self._consecutive = 0
        self._planar_consecutive = 0
        self._contact: Optional[np.ndarray] = None
        self._approach_start: Optional[np.ndarray] = None
        self._approach_t0: Optional[float] = None
        self._stop_pose: Optional[np.ndarray] = None
        self._stop_time = math.nan

    def _enter(self, state: State, t: float) -> None:
        self._state = state
        self._entered = t
        if state is State.APPROACHING:
            self._approach_t0 = t
            self._consecutive = 0
            self._planar_consecutive = 0

    def _stop(self, reason: StopReason, t: float, detail: str) -> None:
        if self._state is State.STOPPED:
            return
        if self._state is State.IDLE and reason not in (StopReason.ERROR, StopReason.SHUTDOWN):
            return
        self._state = State.STOPPED
        self._reason = reason
        self._detail = detail
        self._stop_time = t
        self._stop_pose = None if self._pose is None else self._pose.copy()
        # An idle task has nothing moving, but a stop is still the safe answer to a fault.
        self._halt_sent = False

    def _along(self, pose: np.ndarray, origin: np.ndarray) -> float:
        return float(np.dot(pose[:3] - origin[:3], self._dir))

    def _move(self, v: np.ndarray) -> VelocityCommand:
        return VelocityCommand(np.asarray(v, dtype=np.float64), self._cfg.command_duration_s)

    def _check_inputs(self, t: float) -> None:
        if self._slip_wd.is_stale(t):
            self._stop(StopReason.STALE_SLIP, t,
                       f'no slip estimate for {self._slip_wd.age(t):.3f} s')
        elif self._pose_wd.is_stale(t):
            self._stop(StopReason.STALE_POSE, t,
                       f'no TCP pose for {self._pose_wd.age(t):.3f} s')

    def _phase_deadline(self, distance: float, speed: float) -> float:
        return self._cfg.time_margin * distance / speed + 1.0

    def _step_retract(self, t: float) -> VelocityCommand:
        backed_off = -self._along(self._pose, self._contact)
        if backed_off >= self._cfg.retract_distance_m:
            self._enter(State.SETTLING, t)
            return self._move(np.zeros(3))
        if t - self._entered > self._phase_deadline(self._cfg.retract_distance_m,
                                                    self._cfg.retract_speed_m_s):
            self._stop(StopReason.TIMEOUT, t, f'retract reached only {backed_off:.4f} m')
            return self.step(t)
        return self._move(-self._dir * self._cfg.retract_speed_m_s)

    def _step_approach(self, t: float) -> VelocityCommand:
        travelled = self._along(self._pose, self._approach_start)
        if travelled >= self._cfg.max_approach_distance_m:
            self._stop(StopReason.MAX_TRAVEL, t,
                       f'approach travelled {travelled:.4f} m without slip')
            return self.step(t)
        if t - self._entered > self._phase_deadline(self._cfg.max_approach_distance_m,
                                                    self._cfg.approach_speed_m_s):
            self._stop(StopReason.TIMEOUT, t, f'approach reached only {travelled:.4f} m')
            return self.step(t)
        return self._move(self._dir * self._cfg.approach_speed_m_s)
