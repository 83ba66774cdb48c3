"""Scenarios: the paper's data-collection protocols and the two closed-loop tasks.

A :class:`Scenario` is a frozen description (seed, object, layout, pad, condition, sensor
settings); :class:`aslip_ros.scene.World` turns it into a stream. The motion programs in this
module generate the random pushes and sweeps lazily from the trial's own RNG, so a scenario of
any length needs bounded memory and the same seed always gives the same motion.

- ``robot_induced``: the arm sweeps the gripper across a stationary probe held lightly between
  the pads; every arm motion is slip (labels from robot state). Only ``robot_moving``.
- ``external_induced``: the gripper holds an object still (or moves it with the arm for
  ``robot_moving``) while an agent's hand touches it and pushes it, impulsively or steadily,
  in random directions; some touches push without making it slip (labels from mocap).
- ``wall_push``: closed loop; the arm pushes the held object against a wall.
- ``external_drag``: closed loop; an agent drags the object along a random path.
- ``scripted``: a still gripper and a known, piecewise-constant slip velocity (tests, demos).
"""

from __future__ import annotations

import numpy as np

from .scenario import CONDITIONS, KINDS, Scenario  # noqa: F401 - KINDS, CONDITIONS: re-exported
# The variants live in their own module; re-exported here, where the scenarios are.
from .variants import (COUPLING_DB, HANDLING_PATH_DB, LAB_MOCAP, VARIANTS,  # noqa: F401
                       confounders_variant, contact_variant, coupling_variant,
                       mocap_variant, one_sided_variant)

#: Planned object excursion from the grasp centre beyond which pushes turn back [m].
_EXCURSION_M = 0.02
#: Pause between an agent's touches [s] (uniform range) and the longest slide of one push [m].
_TOUCH_GAP_S = (0.1, 0.8)
_PUSH_TRAVEL_M = 0.04
#: Share of an agent's slipping pushes that are impulsive (the rest are sustained).
_IMPULSIVE_SHARE = 0.4375


def _trial_id(prefix: str, obj: str, seed: int) -> str:
    # Formatted leniently: a bad seed must reach Scenario's own check and its clear message.
    tag = f"{seed:04d}" if isinstance(seed, (int, np.integer)) else str(seed)
    return f"{prefix}-{obj}-{tag}"


def robot_induced(seed: int, object: str = "pla_rod", layout: str = "4mic",
                  pad: str = "textured", condition: str = "robot_moving",
                  duration_s: float = 30.0, **kw) -> Scenario:
    """Randomized arm sweeps across a stationary probe; labels from robot state."""
    return Scenario("robot_induced", seed, object, layout, pad, condition, duration_s,
                    trial_id=kw.pop("trial_id", _trial_id("rob", object, seed)), **kw)


def external_induced(seed: int, object: str = "chips_can", layout: str = "4mic",
                     pad: str = "textured", condition: str = "robot_stationary",
                     duration_s: float = 30.0, **kw) -> Scenario:
    """Stationary (or moving) gripper, an agent pushes the object; labels from mocap."""
    return Scenario("external_induced", seed, object, layout, pad, condition, duration_s,
                    trial_id=kw.pop("trial_id", _trial_id("ext", object, seed)), **kw)


def wall_push(seed: int, object: str = "chips_can", layout: str = "4mic",
              pad: str = "textured", push_dir_xz: tuple[float, float] = (1.0, 0.0),
              wall_distance_m: float = 0.1, duration_s: float | None = None,
              **kw) -> Scenario:
    """Closed loop: push the held object along ``push_dir_xz`` (grasp plane) into a wall.

    The wall is a plane normal to the push direction, ``wall_distance_m`` ahead of the
    object's leading point. Contact is compliant (``wall_stiffness_n_m``); once the wall force
    exceeds the grip friction ``2 * friction * grip_force_n`` the object slips back.
    """
    return Scenario("wall_push", seed, object, layout, pad, "robot_moving", duration_s,
                    push_dir_xz=tuple(float(v) for v in push_dir_xz),
                    wall_distance_m=wall_distance_m,
                    trial_id=kw.pop("trial_id", _trial_id("wall", object, seed)), **kw)


def external_drag(seed: int, object: str = "chips_can", layout: str = "4mic",
                  pad: str = "textured", drag_speed_m_s: float = 0.04,
                  duration_s: float | None = None, **kw) -> Scenario:
    """Closed loop: an agent drags the object along a random in-plane path (after holding it
    still for the scenario's ``drag_hold_s``)."""
    return Scenario("external_drag", seed, object, layout, pad, "robot_moving", duration_s,
                    drag_speed_m_s=drag_speed_m_s,
                    trial_id=kw.pop("trial_id", _trial_id("drag", object, seed)), **kw)


def scripted(seed: int, segments: list[tuple[float, float, float, float]],
             object: str = "chips_can", layout: str = "4mic", pad: str = "textured",
             condition: str = "robot_off", duration_s: float = 5.0, **kw) -> Scenario:
    """A still gripper; the object slips at ``(vx, vz)`` [m/s, grasp plane] between
    ``t_start`` and ``t_end`` [s] of each segment (overlapping segments add). Labels from
    mocap. For tests with analytically known motion."""
    if condition == "robot_moving":
        raise ValueError("scripted scenarios keep the arm still: use robot_off or "
                         "robot_stationary")
    script = tuple(tuple(float(x) for x in seg) for seg in segments)
    return Scenario("scripted", seed, object, layout, pad, condition, duration_s,
                    script=script,
                    trial_id=kw.pop("trial_id", _trial_id("script", object, seed)), **kw)


# --------------------------------------------------------------------------- motion programs

class PulseTrain:
    """A lazily generated sum of smooth velocity pulses (raised-cosine trapezoids).

    Each pulse: start, end, ramp time, peak vector, turn rate [rad/s] (2-D pulses only: the
    direction rotates during the pulse, so long windows blur direction as in the paper).
    """

    def __init__(self, dim: int, generate) -> None:
        self.dim = dim
        self._generate = generate          # callable(t_from) -> (list of pulses, t_next)
        self._pulses: list[tuple] = []
        self._t_next = 0.0

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """Velocity at times ``t`` (ascending), shape ``(len(t), dim)``."""
        while self._t_next <= t[-1]:
            pulses, self._t_next = self._generate(self._t_next)
            self._pulses.extend(pulses)
        self._pulses = [p for p in self._pulses if p[1] >= t[0]]
        out = np.zeros((t.shape[0], self.dim))
        for t0, t1, ramp, vec, turn in self._pulses:
            if t0 > t[-1]:
                continue
            lo, hi = np.searchsorted(t, [t0, t1])
            if hi <= lo:
                continue
            u = t[lo:hi] - t0
            dur = t1 - t0
            s = np.ones_like(u)
            m = u < ramp
            s[m] = 0.5 * (1.0 - np.cos(np.pi * u[m] / ramp))
            m = u > dur - ramp
            s[m] = 0.5 * (1.0 - np.cos(np.pi * (dur - u[m]) / ramp))
            if turn != 0.0:
                a = turn * (u - 0.5 * dur)
                c, sn = np.cos(a), np.sin(a)
                v = np.column_stack([c * vec[0] - sn * vec[1], sn * vec[0] + c * vec[1]])
                out[lo:hi] += v * s[:, None]
            else:
                out[lo:hi] += s[:, None] * vec[None, :]
        return out


def _direction_back(rng: np.random.Generator, planned: np.ndarray) -> np.ndarray:
    """A random unit direction, turned back towards the centre once the excursion is large."""
    if np.hypot(*planned) > _EXCURSION_M:
        phi = np.arctan2(-planned[1], -planned[0]) + rng.uniform(-0.8, 0.8)
    else:
        phi = rng.uniform(-np.pi, np.pi)
    return np.array([np.cos(phi), np.sin(phi)])


def _push_direction(rng: np.random.Generator, scn: Scenario,
                    planned: np.ndarray) -> np.ndarray:
    """An agent's push direction; with ``one_sided_fraction`` most pushes go one way.

    One-sided pushes stand for gravity or a wall: they keep their sector however far the
    object has gone (the excursion only moves the mocap pose, not the sound); the other
    pushes go in uniformly random directions.
    """
    if scn.one_sided_fraction <= 0.0:
        return _direction_back(rng, planned)
    if rng.random() < scn.one_sided_fraction:
        phi = scn.one_sided_direction_rad + rng.uniform(-1.0, 1.0) * scn.one_sided_spread_rad
    else:
        phi = rng.uniform(-np.pi, np.pi)
    return np.array([np.cos(phi), np.sin(phi)])


def _is_one_sided(e: np.ndarray, scn: Scenario) -> bool:
    """True when ``e`` lies within the preferred sector of a one-sided scenario."""
    d = np.angle(np.exp(1j * (np.arctan2(e[1], e[0]) - scn.one_sided_direction_rad)))
    return bool(abs(d) <= scn.one_sided_spread_rad + 1e-12)


def _slip_speed(rng: np.random.Generator, scn: Scenario, fast_max: float) -> float:
    """Slip speed: a share of slow slip near a few mm/s, the rest up to ``fast_max``."""
    if rng.random() < scn.slow_fraction:
        return float(rng.uniform(1e-3, 8e-3))
    return float(rng.uniform(8e-3, min(fast_max, scn.max_slip_speed_m_s)))


def robot_sweeps(scn: Scenario, rng: np.random.Generator) -> PulseTrain:
    """Arm sweeps in the grasp plane, in grasp-plane coordinates (x, z) of the TCP."""
    planned = np.zeros(2)          # planned probe offset relative to the grasp centre

    def gen(t: float):
        nonlocal planned
        rest = rng.uniform(0.3, 1.6)
        speed = _slip_speed(rng, scn, 0.1)
        e = _direction_back(rng, -planned)            # probe moves opposite to the arm
        dur = rng.uniform(0.25, 2.0)
        ramp = min(rng.uniform(0.04, 0.2), dur / 3.0)
        dur = min(dur, 0.025 / speed + ramp)
        planned = planned - e * speed * (dur - ramp)
        t0 = t + rest
        return [(t0, t0 + dur, ramp, e * speed, 0.0)], t0 + dur
    return PulseTrain(2, gen)


def arm_wander(scn: Scenario, rng: np.random.Generator) -> PulseTrain:
    """Random arm motions (world frame) that carry the grasped object with them."""
    planned = np.zeros(3)

    def gen(t: float):
        nonlocal planned
        rest = rng.uniform(0.2, 1.5)
        d = rng.standard_normal(3)
        d /= np.linalg.norm(d)
        if np.linalg.norm(planned) > 0.1:
            d = -planned / np.linalg.norm(planned)
        speed = rng.uniform(0.02, 0.15)
        dur = rng.uniform(0.3, 1.5)
        ramp = min(0.15, dur / 3.0)
        planned = planned + d * speed * (dur - ramp)
        t0 = t + rest
        return [(t0, t0 + dur, ramp, d * speed, 0.0)], t0 + dur
    return PulseTrain(3, gen)


def agent_pushes(scn: Scenario, rng: np.random.Generator) -> tuple[PulseTrain, PulseTrain]:
    """An agent's touches and pushes: (slip velocity x, z; touch level 0..1)."""
    planned = np.zeros(2)
    touches: list[tuple] = []

    def gen(t: float):
        nonlocal planned
        t_touch = t + rng.uniform(*_TOUCH_GAP_S)
        preload = rng.uniform(0.05, 0.3)
        t0 = t_touch + preload
        kind = rng.random()
        pushes = 1.0 - scn.no_slip_touch_fraction
        pulses = []
        if kind < _IMPULSIVE_SHARE * pushes:              # impulsive push
            dur = rng.uniform(0.04, 0.15)
            speed = float(rng.uniform(0.02, scn.max_slip_speed_m_s))
            e = _push_direction(rng, scn, planned)
            pulses.append((t0, t0 + dur, 0.5 * dur, e * speed, 0.0))
            planned = planned + e * speed * 0.5 * dur
        elif kind < pushes:                               # sustained push, may curve
            speed = _slip_speed(rng, scn, 0.06)
            dur = rng.uniform(0.3, 2.0)
            ramp = min(rng.uniform(0.05, 0.2), dur / 3.0)
            dur = min(dur, _PUSH_TRAVEL_M / speed + ramp)
            e = _push_direction(rng, scn, planned)
            turn = rng.uniform(-1.0, 1.0) if rng.random() < 0.5 else 0.0
            if scn.one_sided_fraction > 0.0 and _is_one_sided(e, scn):
                turn = 0.0          # a curving push would leave the preferred sector
            pulses.append((t0, t0 + dur, ramp, e * speed, turn))
            planned = planned + e * speed * (dur - ramp)
        else:                                             # a touch that does not slip
            dur = rng.uniform(0.2, 1.0)
        t_end = t0 + dur + rng.uniform(0.05, 0.3)
        touches.append((t_touch, t_end, 0.02, np.array([rng.uniform(0.4, 1.0)]), 0.0))
        return pulses, t_end

    slip = PulseTrain(2, gen)

    def touch_gen(t: float):
        # Touches are produced by the slip generator; make sure it has run far enough.
        while slip._t_next <= t + 1e-9:
            pulses, slip._t_next = gen(slip._t_next)
            slip._pulses.extend(pulses)
        out = list(touches)
        touches.clear()
        return out, slip._t_next
    return slip, PulseTrain(1, touch_gen)


def drag_path(scn: Scenario, rng: np.random.Generator) -> PulseTrain:
    """The dragging agent's object velocity in grasp-plane (x, z) coordinates.

    The first pull comes after ``drag_hold_s`` (the hold at the grasp) plus the usual rest;
    the random draws are the same whatever the hold, so a hold only delays the path."""
    planned = np.zeros(2)
    hold = [float(scn.drag_hold_s)]

    def gen(t: float):
        nonlocal planned
        rest = rng.uniform(0.2, 1.0) + (hold.pop() if hold else 0.0)
        speed = rng.uniform(0.3, 1.0) * scn.drag_speed_m_s
        e = _direction_back(rng, planned * 0.5)
        dur = rng.uniform(0.5, 2.0)
        ramp = min(0.2, dur / 3.0)
        planned = planned + e * speed * (dur - ramp)
        t0 = t + rest
        return [(t0, t0 + dur, ramp, e * speed, 0.0)], t0 + dur
    return PulseTrain(2, gen)


def script_train(scn: Scenario) -> PulseTrain:
    """The scripted slip velocity: rectangular segments, no ramps."""
    pulses = [(a, b, 0.0, np.array([vx, vz]), 0.0) for a, b, vx, vz in scn.script]

    def gen(t: float):
        return pulses, np.inf
    return PulseTrain(2, gen)
