"""The :class:`Scenario`: a frozen description of one simulated trial, validated on creation.

The builders of the paper's protocols and the motion programs are
:mod:`aslip_ros.scene.scenarios` (which re-exports :class:`Scenario`); the held-out variants
(:mod:`aslip_ros.scene.variants`) map one Scenario to another. Both build on this module.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from aslip_ros.motion import SLOW_FRACTION, TRIAL_DURATION_S

from .layouts import DEFAULT_LAYOUT, get_layout, get_object, get_pad
from .physics import Acoustics

KINDS = ("robot_induced", "external_induced", "wall_push", "external_drag", "scripted",
         "gravity_pivot")
CONDITIONS = ("robot_off", "robot_stationary", "robot_moving")


@dataclass(frozen=True)
class Scenario:
    """Everything that defines one simulated trial. Build with :mod:`.scenarios`."""

    kind: str
    seed: int
    object: str = "chips_can"
    layout: str = DEFAULT_LAYOUT
    pad: str = "textured"
    condition: str = "robot_stationary"
    duration_s: float | None = TRIAL_DURATION_S
    sample_rate: float = 48000.0
    mocap_rate_hz: float = 120.0
    mocap_latency_s: float = 0.0083
    mocap_noise_m: float = 1.5e-4
    mocap_drop_prob: float = 0.005
    tcp_rate_hz: float = 100.0
    arm_lag_s: float = 0.02
    max_slip_speed_m_s: float = 0.1
    slow_fraction: float = SLOW_FRACTION
    push_dir_xz: tuple[float, float] = (1.0, 0.0)
    wall_distance_m: float = 0.1
    grip_force_n: float = 15.0
    wall_stiffness_n_m: float = 3000.0
    drag_speed_m_s: float = 0.04
    #: external_drag: the agent holds the object still this long after the grasp before
    #: its first pull [s], as grasp_calibration asks a user to while the per-grasp
    #: calibration converges (0.6-0.8 s on the scene's grasps); 0 = it may pull at once.
    drag_hold_s: float = 1.0
    one_sided_fraction: float = 0.0
    one_sided_spread_rad: float = np.pi / 6.0
    #: The preferred slip direction of a one-sided trial [rad, grasp-plane angle]; None:
    #: drawn from the seed (``one_sided_direction_rad``).
    one_sided_heading_rad: float | None = None
    no_slip_touch_fraction: float = 0.2
    #: external_induced: share of the agent's slipping pushes that twist the object about
    #: the pad normal, half of them pure twists and half twists with the push (docs/scene.md,
    #: "Rotational slip"); 0 = the pushes of scene version 3, draw for draw.
    twist_fraction: float = 0.0
    #: wall_push: lever arm [m] at which the surface meets the object, perpendicular to the
    #: push (along +x for a downward push); 0 = the wall meets it in line with the grasp and
    #: it slides. Beyond 2/3 of contact_radius_m the pads' torsional friction gives way first
    #: and the object turns instead.
    pivot_lever_m: float = 0.0
    #: Radius of each pad's contact patch [m]: the torsional friction of the two pads is
    #: 2 * (2/3) * friction * grip_force_n * contact_radius_m (uniform pressure).
    contact_radius_m: float = 0.01
    #: (t_start, t_end, vx, vz) or (t_start, t_end, vx, vz, wy) segments of ``scripted``.
    script: tuple[tuple[float, ...], ...] = ()
    #: robot_induced: the arm follows velocity commands (a driver such as robot_sweeps on
    #: a cell) instead of the scene's own sweeps; the probe still stands in the world.
    commanded_arm: bool = False
    trial_id: str = ""
    acoustics: Acoustics = field(default_factory=Acoustics)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown scenario kind {self.kind!r}; choose one of {KINDS}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        get_object(self.object)
        get_layout(self.layout)
        get_pad(self.pad)
        if self.condition not in CONDITIONS:
            raise ValueError(f"unknown condition {self.condition!r}; choose one of "
                             f"{CONDITIONS}")
        if self.kind == "robot_induced" and self.condition != "robot_moving":
            raise ValueError("robot_induced slip needs condition 'robot_moving': the arm's "
                             "motion is what makes the probe slip")
        if self.kind in ("wall_push", "external_drag") and self.condition != "robot_moving":
            raise ValueError(f"{self.kind} is closed loop: condition must be 'robot_moving'")
        if self.duration_s is not None and not (np.isfinite(self.duration_s)
                                                and self.duration_s > 0):
            raise ValueError(f"duration_s must be positive (or None), got {self.duration_s!r}")
        for name in ("sample_rate", "mocap_rate_hz", "tcp_rate_hz", "max_slip_speed_m_s",
                     "grip_force_n", "wall_stiffness_n_m", "drag_speed_m_s", "arm_lag_s",
                     "contact_radius_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value!r}")
        if self.sample_rate < 8000.0:
            raise ValueError(f"sample_rate must be at least 8000 Hz, got {self.sample_rate}")
        if self.mocap_rate_hz > self.sample_rate or self.tcp_rate_hz > self.sample_rate:
            raise ValueError("mocap_rate_hz and tcp_rate_hz must not exceed sample_rate")
        for name in ("mocap_latency_s", "mocap_noise_m", "wall_distance_m", "drag_hold_s",
                     "pivot_lever_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be >= 0, got {value!r}")
        if not 0.0 <= self.mocap_drop_prob < 1.0:
            raise ValueError(f"mocap_drop_prob must lie in [0, 1), got {self.mocap_drop_prob}")
        if not 0.0 <= self.slow_fraction <= 1.0:
            raise ValueError(f"slow_fraction must lie in [0, 1], got {self.slow_fraction}")
        if not 0.0 <= self.one_sided_fraction <= 1.0:
            raise ValueError(f"one_sided_fraction must lie in [0, 1], got "
                             f"{self.one_sided_fraction}")
        if not 0.0 <= self.twist_fraction <= 1.0:
            raise ValueError(f"twist_fraction must lie in [0, 1], got {self.twist_fraction}")
        if not 0.0 <= self.no_slip_touch_fraction < 1.0:
            raise ValueError(f"no_slip_touch_fraction must lie in [0, 1), got "
                             f"{self.no_slip_touch_fraction}")
        if not 0.0 <= self.one_sided_spread_rad <= np.pi:
            raise ValueError(f"one_sided_spread_rad must lie in [0, pi], got "
                             f"{self.one_sided_spread_rad}")
        if self.one_sided_heading_rad is not None and not (
                np.isfinite(self.one_sided_heading_rad)
                and -np.pi <= self.one_sided_heading_rad <= np.pi):
            raise ValueError(f"one_sided_heading_rad must lie in [-pi, pi], got "
                             f"{self.one_sided_heading_rad!r}")
        d = np.asarray(self.push_dir_xz, dtype=float)
        if d.shape != (2,) or not np.all(np.isfinite(d)) or np.hypot(*d) < 1e-9:
            raise ValueError(f"push_dir_xz must be a nonzero 2-vector, got {self.push_dir_xz}")
        for seg in self.script:
            if len(seg) not in (4, 5) or not all(np.isfinite(seg)) \
                    or not 0.0 <= seg[0] < seg[1]:
                raise ValueError(f"script segments are (t_start, t_end, vx, vz) or (t_start, "
                                 f"t_end, vx, vz, wy) with 0 <= t_start < t_end, got {seg!r}")
        if not isinstance(self.acoustics, Acoustics):
            raise ValueError("acoustics must be an Acoustics instance")
        self.acoustics.validate()

    @property
    def induced(self) -> str:
        """``"robot"`` when labels come from robot state, else ``"external"``."""
        return "robot" if self.kind == "robot_induced" else "external"

    @property
    def torsional_friction_nm(self) -> float:
        """The torque [N m] at which the two pads' grip gives way to a turn about the pad
        normal: ``2 * (2/3) * friction * grip_force_n * contact_radius_m``."""
        mu = get_object(self.object).friction
        return 2.0 * (2.0 / 3.0) * mu * self.grip_force_n * self.contact_radius_m

    @property
    def pivots(self) -> bool:
        """True when a wall push turns the object rather than sliding it: the lever arm
        makes the wall's torque reach the torsional friction before its force reaches the
        sliding friction ``2 * friction * grip_force_n`` (lever > 2/3 contact radius)."""
        return self.pivot_lever_m > (2.0 / 3.0) * self.contact_radius_m

    @property
    def closed_loop(self) -> bool:
        """True for the tasks driven by arm commands."""
        return self.kind in ("wall_push", "external_drag")

    @property
    def one_sided_direction_rad(self) -> float:
        """Grasp-plane angle of the preferred slip direction of this trial (one-sided variant):
        ``one_sided_heading_rad``, or drawn from the seed."""
        if self.one_sided_heading_rad is not None:
            return float(self.one_sided_heading_rad)
        return float(np.random.default_rng([self.seed, 0x051D]).uniform(-np.pi, np.pi))

    @property
    def yaw_rad(self) -> float:
        """Heading of the level gripper about world z, drawn from the seed."""
        return float(np.random.default_rng([self.seed, 0x9A3]).uniform(-np.pi, np.pi))

    def with_(self, **changes) -> "Scenario":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)
