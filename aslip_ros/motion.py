"""Motion programs of the scene and of a real arm: lazily drawn velocity pulses (ROS-free).

A :class:`PulseTrain` is a sum of smooth velocity pulses generated on demand from an RNG, so
a program of any length needs bounded memory and the same seed always gives the same motion.
The scene's agents and arms (:mod:`aslip_ros.scene.scenarios`) are written with it.

:func:`robot_sweeps` draws the arm sweeps of robot-induced slip (pauses, speeds with their
slow share, durations, raised-cosine ramps, turning back towards the start). The scene's
simulated ``robot_induced`` trials and the sweeps a real arm makes on a cell
(:mod:`aslip_ros.control.sweeps`) both draw them here, so the pretraining data and the
hardware recordings share one distribution, defined once. Floor 0 (docs/design.md): the
scene and control/ take it from here, neither from the other.
"""

from __future__ import annotations

import numpy as np

#: Length of one trial of the paper's protocols [s]: a simulated scenario's default and the
#: sweeping time of a robot-sweeps run on a cell.
TRIAL_DURATION_S = 30.0
#: Share of slow slip (1-8 mm/s) among the drawn pushes and sweeps.
SLOW_FRACTION = 0.3
#: Fastest arm sweep [m/s] (a caller's lower limit caps it further).
SWEEP_MAX_SPEED_M_S = 0.1
#: Planned excursion from the grasp centre beyond which pushes and sweeps turn back [m].
_EXCURSION_M = 0.02


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

    def extend_to(self, t_end: float) -> None:
        """Generate pulses until the program reaches past ``t_end``."""
        while self._t_next <= t_end:
            pulses, self._t_next = self._generate(self._t_next)
            self._pulses.extend(pulses)

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """Velocity at times ``t`` (ascending), shape ``(len(t), dim)``."""
        self.extend_to(t[-1])
        self._pulses = [p for p in self._pulses if p[1] >= t[0]]
        out = np.zeros((t.shape[0], self.dim))
        for pulse in self._pulses:
            if pulse[0] > t[-1]:
                continue
            lo, hi = np.searchsorted(t, [pulse[0], pulse[1]])
            if hi > lo:
                self._add(out[lo:hi], t[lo:hi], pulse)
        return out

    @staticmethod
    def _add(out: np.ndarray, t: np.ndarray, pulse: tuple) -> None:
        """Add one raised-cosine pulse to ``out`` (its samples at times ``t``). In 3-D pulses
        (vx, vz, wy) a turn rate turns the planar part only."""
        t0, t1, ramp, vec, turn = pulse
        u = t - t0
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
            out[:, :2] += v * s[:, None]
            if len(vec) > 2:
                out[:, 2:] += s[:, None] * vec[None, 2:]
        else:
            out += s[:, None] * vec[None, :]


def direction_back(rng: np.random.Generator, planned: np.ndarray) -> np.ndarray:
    """A random unit direction, turned back towards the centre once the excursion is large."""
    if np.hypot(*planned) > _EXCURSION_M:
        phi = np.arctan2(-planned[1], -planned[0]) + rng.uniform(-0.8, 0.8)
    else:
        phi = rng.uniform(-np.pi, np.pi)
    return np.array([np.cos(phi), np.sin(phi)])


def slip_speed(rng: np.random.Generator, slow_fraction: float, fast_max: float) -> float:
    """Slip speed [m/s]: a share ``slow_fraction`` of slow slip near a few mm/s, the rest up
    to ``fast_max``."""
    if rng.random() < slow_fraction:
        return float(rng.uniform(1e-3, 8e-3))
    return float(rng.uniform(8e-3, fast_max))


def robot_sweeps(rng: np.random.Generator, max_speed_m_s: float,
                 slow_fraction: float = SLOW_FRACTION) -> PulseTrain:
    """Arm sweeps in the grasp plane, in grasp-plane coordinates (x, z) of the TCP, at most
    ``max_speed_m_s`` (and :data:`SWEEP_MAX_SPEED_M_S`) fast."""
    planned = np.zeros(2)          # planned probe offset relative to the grasp centre
    fast_max = min(SWEEP_MAX_SPEED_M_S, max_speed_m_s)

    def gen(t: float):
        nonlocal planned
        rest = rng.uniform(0.3, 1.6)
        speed = slip_speed(rng, slow_fraction, fast_max)
        e = direction_back(rng, -planned)             # probe moves opposite to the arm
        dur = rng.uniform(0.25, 2.0)
        ramp = min(rng.uniform(0.04, 0.2), dur / 3.0)
        dur = min(dur, 0.025 / speed + ramp)
        planned = planned - e * speed * (dur - ramp)
        t0 = t + rest
        return [(t0, t0 + dur, ramp, e * speed, 0.0)], t0 + dur
    return PulseTrain(2, gen)
