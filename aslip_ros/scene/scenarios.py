"""Scenarios: the paper's data-collection protocols and the two closed-loop tasks.

A :class:`Scenario` is a frozen description (seed, object, layout, pad, condition, sensor
settings); :class:`aslip_ros.scene.World` turns it into a stream. The motion programs in this
module (and the arm sweeps, :func:`aslip_ros.motion.robot_sweeps`) generate the random pushes
and sweeps lazily from the trial's own RNG, so a scenario of any length needs bounded memory
and the same seed always gives the same motion.

- ``robot_induced``: the arm sweeps the gripper across a stationary probe held lightly between
  the pads; every arm motion is slip (labels from robot state). Only ``robot_moving``.
- ``external_induced``: the gripper holds an object still (or moves it with the arm for
  ``robot_moving``) while an agent's hand touches it and pushes it, impulsively or steadily,
  in random directions; some touches push without making it slip (labels from mocap).
- ``wall_push``: closed loop; the arm pushes the held object against a wall.
- ``external_drag``: closed loop; an agent drags the object along a random path.
- ``scripted``: a still gripper and a known, piecewise-constant slip velocity (tests, demos).
- ``gravity_pivot``: the gripper holds an object off its centre of mass; whenever the grip
  relaxes, gravity turns it about the pad normal (and drags it down a little), until the grip
  is restored; now and then a hand turns it back (labels from mocap). The arm is still, or
  with ``robot_moving`` wanders as in ``external_induced``.

Rotational slip (scene version 4): the agent's pulses are ``(vx, vz, wy)``, the planar slip
velocity at the pad centre and the angular velocity about the pad normal (+y of the grasp
plane) [rad/s]; ``Scenario.twist_fraction`` makes some pushes twist (docs/scene.md).
"""

from __future__ import annotations

import numpy as np

from aslip_ros.motion import PulseTrain, direction_back, slip_speed

from .layouts import get_object
from .scenario import CONDITIONS, KINDS, Scenario  # noqa: F401 - KINDS, CONDITIONS: re-exported
# The variants live in their own module; re-exported here, where the scenarios are.
from .variants import (COUPLING_DB, HANDLING_PATH_DB, LAB_MOCAP, PATH_DB,  # noqa: F401
                       VARIANTS, confounders_variant, contact_variant, coupling_variant,
                       mocap_variant, one_sided_variant, path_variant, speed_variant)

#: Pause between an agent's touches [s] (uniform range) and the longest slide of one push [m].
_TOUCH_GAP_S = (0.1, 0.8)
_PUSH_TRAVEL_M = 0.04
#: Share of an agent's slipping pushes that are impulsive (the rest are sustained).
_IMPULSIVE_SHARE = 0.4375
#: Twisting pushes (docs/scene.md, "Rotational slip"): angular speed ranges [rad/s] of an
#: impulsive twist (a flick of the wrist), of a sustained one, and of a slow sustained one
#: (straddling the 0.5 rad/s rotation threshold, as slow pushes straddle 5 mm/s).
_TWIST_IMPULSIVE_RAD_S = (1.0, 6.0)
_TWIST_SUSTAINED_RAD_S = (1.0, 3.3)
_TWIST_SLOW_RAD_S = (0.2, 1.0)
#: Longest turn of one sustained twist [rad] and the planned angle beyond which twists turn
#: back (the hand's forearm range; the mocap pose stays plausible).
_TWIST_MAX_RAD = 1.0
_TWIST_EXCURSION_RAD = 0.5
#: Standard gravity [m/s^2].
GRAVITY_M_S2 = 9.81
#: gravity_pivot (docs/scene.md, "Rotational slip"): offset of the centre of mass from the pad
#: centre [m], its tilt from the horizontal [rad], the grip's safety factor over the grip that
#: just holds the torque, how fast the grip relaxes [share of the hold per s], how long it
#: keeps relaxing after the object starts to turn [s] and how fast it comes back [share per
#: s], the pause before each relaxation [s]; the relaxed grip still carries the weight with
#: margin (load at most ``_PIVOT_MAX_LOAD`` of the sliding friction). A hand turns the object
#: back (at ``_PIVOT_RESET_RAD_S``) once it has turned ``_PIVOT_RESET_RAD``.
_PIVOT_COM_M = (0.03, 0.10)
_PIVOT_TILT_RAD = 0.4
_PIVOT_SAFETY = (1.2, 2.0)
_PIVOT_RELAX_PER_S = (0.5, 2.0)
_PIVOT_REACT_S = (0.05, 0.25)
_PIVOT_REGRIP_PER_S = (5.0, 20.0)
_PIVOT_HOLD_S = (0.3, 1.0)
_PIVOT_MAX_LOAD = 0.6
_PIVOT_RESET_RAD = 0.3
_PIVOT_RESET_RAD_S = (0.8, 3.0)
_PIVOT_DT_S = 1.0e-3


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


def scripted(seed: int, segments: list[tuple[float, ...]],
             object: str = "chips_can", layout: str = "4mic", pad: str = "textured",
             condition: str = "robot_off", duration_s: float = 5.0, **kw) -> Scenario:
    """A still gripper; the object slips at ``(vx, vz)`` [m/s, grasp plane, at the pad
    centre] and turns at ``wy`` [rad/s, about the pad normal; 0 when the segment has four
    numbers] between ``t_start`` and ``t_end`` [s] of each segment ``(t_start, t_end, vx, vz)``
    or ``(t_start, t_end, vx, vz, wy)`` (overlapping segments add). Labels from mocap. For
    tests with analytically known motion."""
    if condition == "robot_moving":
        raise ValueError("scripted scenarios keep the arm still: use robot_off or "
                         "robot_stationary")
    script = tuple(tuple(float(x) for x in seg) for seg in segments)
    return Scenario("scripted", seed, object, layout, pad, condition, duration_s,
                    script=script,
                    trial_id=kw.pop("trial_id", _trial_id("script", object, seed)), **kw)


def gravity_pivot(seed: int, object: str = "chips_can", layout: str = "4mic",
                  pad: str = "textured", condition: str = "robot_stationary",
                  duration_s: float = 30.0, **kw) -> Scenario:
    """The gripper holds the object off its centre of mass; when the grip relaxes, gravity
    turns it about the pad normal (with a little downward slide) until the grip is
    restored, and a hand turns it back now and then. With ``robot_moving`` the arm wanders
    meanwhile, carrying the object (as in ``external_induced``): the turns are the same
    draws, heard beside the arm's noise. Labels from mocap (docs/scene.md, "Rotational
    slip")."""
    return Scenario("gravity_pivot", seed, object, layout, pad, condition, duration_s,
                    trial_id=kw.pop("trial_id", _trial_id("piv", object, seed)), **kw)


# --------------------------------------------------------------------------- motion programs

class ProfileTrain(PulseTrain):
    """A lazily generated sum of sampled velocity profiles ``(t0, t1, grid, values)``,
    linearly interpolated between their samples and zero outside them."""

    @staticmethod
    def _add(out: np.ndarray, t: np.ndarray, pulse: tuple) -> None:
        _, _, grid, values = pulse
        for k in range(out.shape[1]):
            out[:, k] += np.interp(t, grid, values[:, k])


def _push_direction(rng: np.random.Generator, scn: Scenario,
                    planned: np.ndarray) -> np.ndarray:
    """An agent's push direction; with ``one_sided_fraction`` most pushes go one way.

    One-sided pushes stand for gravity or a wall: they keep their sector however far the
    object has gone (the excursion only moves the mocap pose, not the sound); the other
    pushes go in uniformly random directions.
    """
    if scn.one_sided_fraction <= 0.0:
        return direction_back(rng, planned)
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
    """A push's slip speed, up to ``fast_max`` and the scenario's ``max_slip_speed_m_s``."""
    return slip_speed(rng, scn.slow_fraction, min(fast_max, scn.max_slip_speed_m_s))


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


def _twist(rng: np.random.Generator, scn: Scenario, planned_angle: float,
           impulsive: bool) -> tuple[float, bool]:
    """A twisting push's angular velocity [rad/s] and whether it keeps its planar part.

    Half the twists are pure, half come with the push. The sign is random, and turns back
    once the planned angle passes ``_TWIST_EXCURSION_RAD``.
    """
    if impulsive:
        rate = rng.uniform(*_TWIST_IMPULSIVE_RAD_S)
    elif rng.random() < scn.slow_fraction:
        rate = rng.uniform(*_TWIST_SLOW_RAD_S)
    else:
        rate = rng.uniform(*_TWIST_SUSTAINED_RAD_S)
    sign = rng.choice((-1.0, 1.0))
    if abs(planned_angle) > _TWIST_EXCURSION_RAD:
        sign = -np.sign(planned_angle)
    return float(sign * rate), bool(rng.random() < 0.5)


def agent_pushes(scn: Scenario, rng: np.random.Generator) -> tuple[PulseTrain, PulseTrain]:
    """An agent's touches and pushes: ((slip velocity x, z, angular velocity wy); touch level
    0..1). With ``twist_fraction`` 0 the draws are those of scene version 3, one for one."""
    planned = np.zeros(3)          # planned offset x, z [m] and angle [rad]
    touches: list[tuple] = []

    def twisted(vec: np.ndarray, impulsive: bool) -> np.ndarray:
        if scn.twist_fraction <= 0.0 or rng.random() >= scn.twist_fraction:
            return vec
        wy, with_push = _twist(rng, scn, planned[2], impulsive)
        return np.array([vec[0], vec[1], wy]) * ([1.0, 1.0, 1.0] if with_push else [0, 0, 1])

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
            e = _push_direction(rng, scn, planned[:2])
            vec = twisted(np.r_[e * speed, 0.0], True)
            pulses.append((t0, t0 + dur, 0.5 * dur, vec, 0.0))
            planned = planned + vec * 0.5 * dur
        elif kind < pushes:                               # sustained push, may curve
            speed = _slip_speed(rng, scn, 0.06)
            dur = rng.uniform(0.3, 2.0)
            ramp = min(rng.uniform(0.05, 0.2), dur / 3.0)
            dur = min(dur, _PUSH_TRAVEL_M / speed + ramp)
            e = _push_direction(rng, scn, planned[:2])
            turn = rng.uniform(-1.0, 1.0) if rng.random() < 0.5 else 0.0
            if scn.one_sided_fraction > 0.0 and _is_one_sided(e, scn):
                turn = 0.0          # a curving push would leave the preferred sector
            vec = twisted(np.r_[e * speed, 0.0], False)
            if vec[2] != 0.0:
                dur = min(dur, _TWIST_MAX_RAD / abs(vec[2]) + ramp)
            pulses.append((t0, t0 + dur, ramp, vec, turn))
            planned = planned + vec * (dur - ramp)
        else:                                             # a touch that does not slip
            dur = rng.uniform(0.2, 1.0)
        t_end = t0 + dur + rng.uniform(0.05, 0.3)
        touches.append((t_touch, t_end, 0.02, np.array([rng.uniform(0.4, 1.0)]), 0.0))
        return pulses, t_end

    slip = PulseTrain(3, gen)
    return slip, _slaved_touches(slip, touches)


def _slaved_touches(motion: PulseTrain, touches: list) -> PulseTrain:
    """The touch levels that ``motion``'s generator appends to ``touches`` as it runs."""
    def touch_gen(t: float):
        # Touches are produced by the motion generator; make sure it has run far enough.
        motion.extend_to(t + 1e-9)
        out = list(touches)
        touches.clear()
        return out, motion._t_next
    return PulseTrain(1, touch_gen)


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
        e = direction_back(rng, planned * 0.5)
        dur = rng.uniform(0.5, 2.0)
        ramp = min(0.2, dur / 3.0)
        planned = planned + e * speed * (dur - ramp)
        t0 = t + rest
        return [(t0, t0 + dur, ramp, e * speed, 0.0)], t0 + dur
    return PulseTrain(2, gen)


def script_train(scn: Scenario) -> PulseTrain:
    """The scripted slip velocity ``(vx, vz, wy)``: rectangular segments, no ramps."""
    pulses = [(seg[0], seg[1], 0.0, np.array([seg[2], seg[3], seg[4] if len(seg) > 4 else 0.0]),
               0.0) for seg in scn.script]

    def gen(t: float):
        return pulses, np.inf
    return PulseTrain(3, gen)


class _Pivot:
    """The object held off its centre of mass in a relaxing grip (``gravity_pivot``).

    Friction of the two pads: sliding ``Fm = 2 mu N`` and torsional ``Tm = 2 (2/3) mu N a``
    (uniform pressure over a contact of radius ``a``). Under combined load the elliptic limit
    surface ``(F/Fm)^2 + (T/Tm)^2 = 1`` holds, with the motion normal to it (Howe and
    Cutkosky 1996): while the object turns, the weight ``F = m g`` takes the share
    ``r = F/Fm`` of the surface, the torque the pads resist drops to ``Tm sqrt(1 - r^2)``,
    and the pad centre slides down at ``v = (2a/3) |w| r / sqrt(1 - r^2)``.
    """

    def __init__(self, scn: Scenario, rng: np.random.Generator) -> None:
        obj = get_object(scn.object)
        self.rng = rng
        self.lever = rng.uniform(*_PIVOT_COM_M)
        side = np.pi if rng.random() < 0.5 else 0.0
        self.alpha = side + rng.uniform(-_PIVOT_TILT_RAD, _PIVOT_TILT_RAD)  # from +x to +z
        self.weight = obj.mass_kg * GRAVITY_M_S2
        # About the pad centre: the object as a rod of half-length length_m, off by lever.
        self.inertia = obj.mass_kg * (self.lever ** 2 + obj.length_m ** 2 / 3.0)
        self.t_per_n = 2.0 * (2.0 / 3.0) * obj.friction * scn.contact_radius_m
        self.f_per_n = 2.0 * obj.friction
        self.n_floor = self.weight / (self.f_per_n * _PIVOT_MAX_LOAD)

    def episode(self, t_relax: float) -> tuple[np.ndarray, np.ndarray]:
        """Relax the grip from ``t_relax`` until gravity turns the object, then restore it:
        the profile ``(grid, values (vx, vz, wy))`` of the motion, from onset to standstill."""
        rng = self.rng
        torque0 = self.weight * self.lever * np.cos(self.alpha)
        n_crit = max(abs(torque0) / self.t_per_n, self.n_floor)
        n_hold = n_crit * rng.uniform(*_PIVOT_SAFETY)
        rate = n_hold * rng.uniform(*_PIVOT_RELAX_PER_S)
        react = rng.uniform(*_PIVOT_REACT_S)
        regrip = n_hold * rng.uniform(*_PIVOT_REGRIP_PER_S)
        t_on = t_relax + (n_hold - n_crit) / rate
        n_react = max(n_crit - rate * react, self.n_floor)
        sign = 1.0 if torque0 >= 0.0 else -1.0
        w, turned, rows, dt = 0.0, 0.0, [np.zeros(3)], _PIVOT_DT_S
        for k in range(1, int(3.0 / dt)):
            tau = k * dt
            grip = max(n_crit - rate * tau, self.n_floor) if tau < react \
                else min(n_react + regrip * (tau - react), n_hold)
            load = min(self.weight / (self.f_per_n * grip), _PIVOT_MAX_LOAD)
            resist = self.t_per_n * grip * np.sqrt(1.0 - load * load)
            torque = self.weight * self.lever * np.cos(self.alpha - turned)
            w += dt * (torque - sign * resist) / self.inertia
            if w * sign <= 0.0:
                break                                  # friction holds it again
            slide = (self.t_per_n / self.f_per_n) * abs(w) * load / np.sqrt(1.0 - load * load)
            rows.append(np.array([0.0, -slide, w]))
            turned += w * dt
        rows.append(np.zeros(3))
        values = np.array(rows)
        return t_on + dt * np.arange(len(values)), values


def gravity_pivots(scn: Scenario, rng: np.random.Generator) -> tuple[ProfileTrain, PulseTrain]:
    """The motion of ``gravity_pivot``: ((vx, vz, wy) at the pad centre; touch level 0..1).

    Each cycle: the grip holds, relaxes until gravity turns the object, and is restored
    (:class:`_Pivot`); once the object has turned ``_PIVOT_RESET_RAD`` a hand turns it back
    (and lifts it by what it slid), touching it meanwhile."""
    pivot = _Pivot(scn, rng)
    touches: list[tuple] = []
    since_reset = np.zeros(3)          # slid x, z [m] and turned [rad] since the last reset

    def gen(t: float):
        nonlocal since_reset
        grid, values = pivot.episode(t + rng.uniform(*_PIVOT_HOLD_S))
        moved = values[:-1].sum(axis=0) * _PIVOT_DT_S
        pivot.alpha -= moved[2]
        since_reset = since_reset + moved
        profiles = [(grid[0], grid[-1], grid, values)]
        t_next = grid[-1] + rng.uniform(0.2, 0.6)
        if abs(since_reset[2]) > _PIVOT_RESET_RAD:
            peak = rng.uniform(*_PIVOT_RESET_RAD_S)
            dur = max(1.5 * abs(since_reset[2]) / peak, 0.2)
            ramp = dur / 3.0
            g = t_next + _PIVOT_DT_S * np.arange(int(np.ceil(dur / _PIVOT_DT_S)) + 1)
            v = np.zeros((len(g), 3))
            PulseTrain._add(v, g, (t_next, t_next + dur, ramp, -since_reset / (dur - ramp),
                                   0.0))
            profiles.append((g[0], g[-1], g, v))
            touches.append((t_next - 0.1, g[-1] + 0.1, 0.02,
                            np.array([rng.uniform(0.4, 1.0)]), 0.0))
            pivot.alpha += since_reset[2]
            since_reset = np.zeros(3)
            t_next = g[-1] + rng.uniform(0.2, 0.6)
        return profiles, t_next

    motion = ProfileTrain(3, gen)
    return motion, _slaved_touches(motion, touches)
