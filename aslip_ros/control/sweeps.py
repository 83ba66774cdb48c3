"""Robot-induced slip on hardware: random arm sweeps across a clamped probe, ROS-free.

The probe is held still in the world and lightly grasped; the arm sweeps the gripper across
it in the grasp plane, so the slip velocity is minus the TCP velocity there and the labels
come from the TCP pose alone (``aslip export`` with ``induced: robot``). The sweeps are the
scene's: :func:`aslip_ros.motion.robot_sweeps` draws them (pauses, speeds with their slow
share, durations, raised-cosine ramps, turning back towards the start) for the simulated
``robot_induced`` pretraining data and for this task alike, so the hardware recordings and
the pretraining data share one distribution, defined once. Its velocities are grasp-plane
``(x, z)`` of the TCP; here they are rotated into ``link_base`` by the start TCP orientation
and ``grasp_plane_in_tcp`` (:func:`aslip_ros.control.frames.grasp_to_base`), as the
controllers map slip.

Every command is then bounded, direction kept (the label is the measured TCP motion, so a
slower sweep is still a correct sample):

- its speed by ``max_speed_m_s``;
- its speed by what can still be braked within the ball of ``sweep_radius_m`` around the
  start and within the workspace box: moving at ``s`` for one command (``command_duration_s``,
  after which an arm stops by itself) and then braking at ``max_acc_m_s2`` must end inside
  both, measured along the command's direction from the newest TCP pose. Outside them
  (overshoot) only motion back in is allowed.

At the end (``duration_s`` elapsed, or :meth:`SweepTask.finish`) the arm returns to the start
position at ``return_speed_m_s``, braking on the same rule, and stops once within
``return_tolerance_m``; a return that takes longer than ``return_timeout_s`` stops where it
is. A stale TCP pose, a fault or shutdown stop at once; a stopped task stays stopped.
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
from aslip_ros.control.frames import IDENTITY_POSE, as_pose, grasp_to_base, planar_slip
from aslip_ros.control.limits import ArmLimits
from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S, Watchdog
from aslip_ros.motion import TRIAL_DURATION_S, robot_sweeps


class SweepState(enum.Enum):
    """Phases of a sweep run."""

    IDLE = 'idle'
    SWEEPING = 'sweeping'      # the scene's sweeps and the pauses between them
    RETURNING = 'returning'    # back to the start position
    STOPPED = 'stopped'        # latched until reset()


class SweepEnd(str, enum.Enum):
    """Why a run ended. Only :attr:`DONE` is a complete run."""

    DONE = 'done'                      # returned to the start
    RETURN_TIMEOUT = 'return_timeout'
    STALE_POSE = 'stale_pose'
    ERROR = 'error'
    SHUTDOWN = 'shutdown'


def _number(name: str, value: float, minimum: float, strict: bool) -> None:
    value = float(value)
    if not math.isfinite(value) or (value <= minimum if strict else value < minimum):
        raise ValueError(f'{name} must be finite and {">" if strict else ">="} {minimum}, '
                         f'got {value}')


@dataclass(frozen=True)
class SweepConfig:
    """Parameters of a sweep run (SI units, ``link_base``).

    :param seed: seeds the sweeps: the same seed, the same sequence of sweeps.
    :param duration_s: sweeping time before the return to start; 0 = until :meth:`finish`.
    :param sweep_radius_m: the TCP stays within this distance of the start position.
    :param max_speed_m_s: speed limit of every command; the drawn sweep speeds are capped
        at it as well (a scenario caps them at its own ``max_slip_speed_m_s``).
    :param max_acc_m_s2: deceleration the radius and workspace bounds count on (the limit
        :class:`~aslip_ros.control.limits.LimitedArm` enforces on every arm).
    :param workspace_min_m: lower corner of the TCP box; ``None`` = no box here.
    :param workspace_max_m: upper corner of the TCP box.
    :param grasp_plane_in_tcp: calibration pose of ``aslip_grasp_plane`` in the TCP frame.
    :param return_speed_m_s: speed of the return to the start position.
    :param return_tolerance_m: the return ends within this distance of the start.
    :param return_timeout_s: a return still under way after this long stops where it is.
    :param pose_timeout_s: TCP poses older than this are stale (watchdog).
    :param command_duration_s: validity of each velocity command on the arm.
    """

    seed: int = 0
    duration_s: float = TRIAL_DURATION_S
    sweep_radius_m: float = 0.02
    max_speed_m_s: float = ArmLimits.max_speed_m_s
    max_acc_m_s2: float = ArmLimits.max_acc_m_s2
    workspace_min_m: Optional[Sequence[float]] = ArmLimits.workspace_min_m
    workspace_max_m: Optional[Sequence[float]] = ArmLimits.workspace_max_m
    grasp_plane_in_tcp: Sequence[float] = tuple(IDENTITY_POSE)
    return_speed_m_s: float = 0.01
    return_tolerance_m: float = 0.001
    return_timeout_s: float = 10.0
    pose_timeout_s: float = DEFAULT_TIMEOUT_S
    command_duration_s: float = DEFAULT_DURATION_S

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or int(self.seed) != self.seed or self.seed < 0:
            raise ValueError(f'seed must be an integer >= 0, got {self.seed!r}')
        _number('duration_s', self.duration_s, 0.0, strict=False)
        for name in ('sweep_radius_m', 'max_speed_m_s', 'max_acc_m_s2', 'return_speed_m_s',
                     'return_tolerance_m', 'return_timeout_s', 'pose_timeout_s',
                     'command_duration_s'):
            _number(name, getattr(self, name), 0.0, strict=True)
        if self.return_tolerance_m >= self.sweep_radius_m:
            raise ValueError(f'return_tolerance_m ({self.return_tolerance_m}) must be below '
                             f'sweep_radius_m ({self.sweep_radius_m})')
        if (self.workspace_min_m is None) != (self.workspace_max_m is None):
            raise ValueError('give both workspace corners or neither')
        if self.workspace_min_m is not None:
            # ArmLimits validates the box (finite, lower below upper on every axis).
            box = ArmLimits(workspace_min_m=self.workspace_min_m,
                            workspace_max_m=self.workspace_max_m)
            object.__setattr__(self, 'workspace_min_m', box.workspace_min_m)
            object.__setattr__(self, 'workspace_max_m', box.workspace_max_m)
        object.__setattr__(self, 'grasp_plane_in_tcp',
                           tuple(as_pose(self.grasp_plane_in_tcp, 'grasp_plane_in_tcp')))


def braking_speed(distance_m: float, horizon_s: float, acc_m_s2: float) -> float:
    """The highest speed ``s`` with ``s * horizon + s**2 / (2 * acc) <= distance``: moving at
    it for one command and then braking ends within ``distance``."""
    if distance_m <= 0.0:
        return 0.0
    return acc_m_s2 * (math.sqrt(horizon_s ** 2 + 2.0 * distance_m / acc_m_s2) - horizon_s)


def room_in_ball(offset: np.ndarray, direction: np.ndarray, radius: float) -> float:
    """Distance along unit ``direction`` from ``offset`` (relative to the centre) to the
    sphere of ``radius``; 0 when that way does not lead (back) into the ball."""
    b = float(offset @ direction)
    disc = b * b - (float(offset @ offset) - radius * radius)
    if disc <= 0.0:
        return 0.0
    return max(0.0, -b + math.sqrt(disc))


def room_in_box(position: np.ndarray, direction: np.ndarray, lo: np.ndarray,
                hi: np.ndarray) -> float:
    """Distance along unit ``direction`` from ``position`` to the box wall ahead; 0 when an
    axis it moves along is already beyond its wall."""
    room = math.inf
    for p, d, a, b in zip(position, direction, lo, hi):
        if d > 0.0:
            room = min(room, (b - p) / d)
        elif d < 0.0:
            room = min(room, (a - p) / d)
    return max(0.0, room)


class SweepTask:
    """The sweep run. Thread-safe; every method takes an optional ``now``.

    Typical use from a node::

        task = SweepTask(SweepConfig(seed=3, duration_s=60.0))
        # pose stream:              task.on_tcp_pose(pose7)
        # after the first pose:     task.start()
        # control timer (100 Hz):   apply_command(arm, task.step())
        # on shutdown:              task.shutdown(); apply_command(arm, task.step())
    """

    def __init__(self, config: SweepConfig,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Create an idle task; ``clock`` is the monotonic time source of every method."""
        self._cfg = config
        self._clock = clock
        self._lock = threading.RLock()
        self._pose_wd = Watchdog(config.pose_timeout_s, clock)
        self._pose: Optional[np.ndarray] = None
        self._box = None if config.workspace_min_m is None else (
            np.array(config.workspace_min_m), np.array(config.workspace_max_m))
        self.rejected_inputs = 0
        self._reset_run()

    # -- inputs -------------------------------------------------------------------------

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
            if self._start is not None:
                self.max_offset_m = max(self.max_offset_m, self.offset_m())
        return True

    # -- commands -------------------------------------------------------------------------

    def start(self, now: Optional[float] = None) -> None:
        """Begin sweeping from the newest TCP pose (the start position and orientation).

        :raises RuntimeError: already running, or no fresh pose to start from.
        :raises ValueError: the start position is outside the workspace box.
        """
        with self._lock:
            t = self._now(now)
            if self._state not in (SweepState.IDLE, SweepState.STOPPED):
                raise RuntimeError(f'cannot start while {self._state.value}')
            if self._pose is None or self._pose_wd.is_stale(t):
                raise RuntimeError('no fresh TCP pose to start from')
            if self._box is not None and (np.any(self._pose[:3] < self._box[0]) or
                                          np.any(self._pose[:3] > self._box[1])):
                raise ValueError(f'start position {np.round(self._pose[:3], 4).tolist()} m is '
                                 'outside the workspace box')
            self._reset_run()
            self._start = self._pose.copy()
            self._plane = np.column_stack([
                grasp_to_base(planar_slip(1.0, 0.0), self._start, self._cfg.grasp_plane_in_tcp),
                grasp_to_base(planar_slip(0.0, 1.0), self._start, self._cfg.grasp_plane_in_tcp)])
            self._train = robot_sweeps(np.random.default_rng(int(self._cfg.seed)),
                                       self._cfg.max_speed_m_s)
            self._t0 = t
            self._state = SweepState.SWEEPING

    def step(self, now: Optional[float] = None) -> Optional[VelocityCommand]:
        """This cycle's command: a bounded velocity while sweeping (zero during pauses) or
        returning, a stop once when the run ends, ``None`` when idle or stopped."""
        with self._lock:
            t = self._now(now)
            if self._state in (SweepState.SWEEPING, SweepState.RETURNING) and \
                    self._pose_wd.is_stale(t):
                self._end(SweepEnd.STALE_POSE, f'no TCP pose for {self._pose_wd.age(t):.3f} s')
            if self._state is SweepState.SWEEPING:
                tau = max(t - self._t0, self._tau)
                if self._cfg.duration_s > 0.0 and tau >= self._cfg.duration_s:
                    self._begin_return(t)
                else:
                    self._tau = tau
                    return self._move(self._sweep_velocity(tau))
            if self._state is SweepState.RETURNING:
                return self._step_return(t)
            if self._state is SweepState.STOPPED and not self._halt_sent:
                self._halt_sent = True
                return VelocityCommand.halt(self._end_reason.value)
            return None

    def finish(self, now: Optional[float] = None) -> None:
        """End the sweeps now: return to the start, then stop (no-op unless sweeping)."""
        with self._lock:
            if self._state is SweepState.SWEEPING:
                self._begin_return(self._now(now))

    def fault(self, detail: str = '', now: Optional[float] = None) -> None:
        """Abort on an external error (e.g. an :class:`ArmError`); the next step stops."""
        with self._lock:
            self._end(SweepEnd.ERROR, detail)

    def shutdown(self, now: Optional[float] = None) -> None:
        """Abort because the process is shutting down; the next step stops the arm."""
        with self._lock:
            self._end(SweepEnd.SHUTDOWN, 'shutdown')

    def reset(self) -> None:
        """Back to IDLE (the pose and its watchdog are kept)."""
        with self._lock:
            self._reset_run()

    # -- status ---------------------------------------------------------------------------

    @property
    def config(self) -> SweepConfig:
        """The task's configuration."""
        return self._cfg

    @property
    def state(self) -> SweepState:
        """Current phase."""
        with self._lock:
            return self._state

    @property
    def end_reason(self) -> Optional[SweepEnd]:
        """Why the run ended; ``None`` while it has not."""
        with self._lock:
            return self._end_reason

    @property
    def detail(self) -> str:
        """What ended the run, in words."""
        with self._lock:
            return self._detail

    @property
    def start_pose(self) -> Optional[np.ndarray]:
        """The TCP pose the run started from."""
        with self._lock:
            return None if self._start is None else self._start.copy()

    def offset_m(self) -> float:
        """Distance of the newest TCP position from the start position [m]."""
        with self._lock:
            if self._start is None or self._pose is None:
                return math.nan
            return float(np.linalg.norm(self._pose[:3] - self._start[:3]))

    # -- internals ------------------------------------------------------------------------

    def _now(self, now: Optional[float]) -> float:
        return self._clock() if now is None else float(now)

    def _reset_run(self) -> None:
        self._state = SweepState.IDLE
        self._end_reason: Optional[SweepEnd] = None
        self._detail = ''
        self._halt_sent = True
        self._start: Optional[np.ndarray] = None
        self._plane = np.zeros((3, 2))
        self._train = None
        self._t0 = 0.0
        self._tau = 0.0
        self._return_t0 = 0.0
        self._moving = False
        self.sweeps = 0
        self.max_offset_m = 0.0

    def _end(self, reason: SweepEnd, detail: str) -> None:
        if self._state is SweepState.STOPPED:
            return
        self._state = SweepState.STOPPED
        self._end_reason = reason
        self._detail = detail
        self._halt_sent = False

    def _begin_return(self, t: float) -> None:
        self._state = SweepState.RETURNING
        self._return_t0 = t

    def _sweep_velocity(self, tau: float) -> np.ndarray:
        xz = self._train.evaluate(np.array([tau]))[0]
        moving = bool(np.any(xz != 0.0))
        self.sweeps += moving and not self._moving
        self._moving = moving
        return self._plane @ xz

    def _step_return(self, t: float) -> VelocityCommand:
        to_start = self._start[:3] - self._pose[:3]
        distance = float(np.linalg.norm(to_start))
        if distance <= self._cfg.return_tolerance_m:
            self._end(SweepEnd.DONE, 'returned to the start')
            return self.step(t)
        if t - self._return_t0 > self._cfg.return_timeout_s:
            self._end(SweepEnd.RETURN_TIMEOUT,
                      f'still {distance * 1e3:.1f} mm from the start after '
                      f'{self._cfg.return_timeout_s} s')
            return self.step(t)
        speed = min(self._cfg.return_speed_m_s,
                    braking_speed(distance, self._cfg.command_duration_s,
                                  self._cfg.max_acc_m_s2))
        return self._move(to_start * (speed / distance))

    def _move(self, v: np.ndarray) -> VelocityCommand:
        return VelocityCommand(self.bound(v), self._cfg.command_duration_s)

    def bound(self, v: np.ndarray) -> np.ndarray:
        """``v`` within the speed limit and what can be braked inside the ball around the
        start and the workspace box, from the newest TCP pose (direction kept)."""
        v = np.asarray(v, dtype=np.float64)
        speed = float(np.linalg.norm(v))
        if speed == 0.0:
            return np.zeros(3)
        direction = v / speed
        position = self._pose[:3]
        room = room_in_ball(position - self._start[:3], direction, self._cfg.sweep_radius_m)
        if self._box is not None:
            room = min(room, room_in_box(position, direction, *self._box))
        allowed = min(self._cfg.max_speed_m_s,
                      braking_speed(room, self._cfg.command_duration_s,
                                    self._cfg.max_acc_m_s2))
        return v if speed <= allowed else direction * allowed
