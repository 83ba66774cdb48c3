"""The simulated world: kinematics, sensors and the simulated arm, streamed in blocks.

Kinematics run at the audio rate (one velocity per sample, vectorised per block), so labels,
audio and poses agree to the sample. Sensors sample that state: motion capture at its own
rate with latency, noise and dropped frames; the TCP at the robot-state rate. Nothing here
grows with the length of a trial except the optional trajectory log (``record``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np
from scipy.spatial.transform import Rotation

import aslip_ros.scene.scenarios as sc
from ..arm import ArmError
from ..motion import robot_sweeps
from .layouts import get_layout, get_object, get_pad, yaw_quaternion, yaw_rotation
from .physics import SCENE_VERSION, Synth

#: Where the TCP starts in ``world`` [m]; an arbitrary reachable point in front of the base.
TCP_START_M = np.array([0.40, 0.0, 0.30])
#: Commands faster than this are refused, like the xArm's Cartesian speed limit [m/s].
MAX_ARM_SPEED_M_S = 1.0
#: Internal synthesis block used by :meth:`World.stream` [s]; larger blocks amortise the
#: per-call overhead of numpy, and the output does not depend on it.
_SYNTH_BLOCK_S = 0.1


@dataclass
class MocapSample:
    """One motion-capture frame: capture time [s], finger and object poses in ``world``."""

    t: float
    finger_pose: np.ndarray
    object_pose: np.ndarray


@dataclass
class Chunk:
    """One block of the stream.

    ``audio`` is float32 ``(n, n_channels)``; ``mocap`` holds the frames delivered during the
    block (their ``t`` is the capture time, i.e. up to the latency earlier); ``tcp`` holds
    ``(t, pose)`` robot-state samples; ``v_rel`` is the true slip velocity per sample
    (grasp-plane x, z, of the object's point at the pad centre) [m/s] and ``w_rel`` its true
    angular velocity about the pad normal (+y of the grasp plane) [rad/s], for tests and
    evaluation only.
    """

    first_sample_index: int
    t0: float
    audio: np.ndarray
    mocap: list
    tcp: list
    v_rel: np.ndarray
    w_rel: np.ndarray | None = field(default=None)


class SimArm:
    """Simulated Cartesian velocity arm; satisfies :class:`aslip_ros.arm.Arm`.

    The TCP velocity follows the command with a first-order lag (``Scenario.arm_lag_s``) and
    decays to zero once ``duration_s`` has passed without a new command.
    """

    def __init__(self, world: "World") -> None:
        self._world = world
        self._connected = False
        self._velocity_mode = False
        self._cmd = np.zeros(3)
        self._deadline = 0.0
        self.v = np.zeros(3)
        self.n_commands = 0
        self.stop_times: list[float] = []      # scene time of every stop command [s]

    def connect(self) -> None:
        """Open the (simulated) connection."""
        self._connected = True

    def enable_velocity_mode(self) -> None:
        """Accept velocity commands from now on."""
        if not self._connected:
            raise ArmError("connect() the arm before enabling velocity mode")
        self._velocity_mode = True

    def send_velocity(self, v_xyz_m_s: np.ndarray, duration_s: float) -> None:
        """Command a TCP velocity [m/s] in ``link_base`` (= ``world``) for ``duration_s``."""
        v = np.asarray(v_xyz_m_s, dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"v_xyz_m_s must be 3 finite numbers, got {v_xyz_m_s!r}")
        if not (np.isfinite(duration_s) and duration_s > 0.0):
            raise ValueError(f"duration_s must be positive, got {duration_s!r}")
        if not self._velocity_mode:
            raise ArmError("call connect() and enable_velocity_mode() before send_velocity()")
        scn = self._world.scenario
        if scn.kind == "robot_induced" and not scn.commanded_arm:
            raise ArmError("robot_induced scenarios drive the arm themselves "
                           "(commanded_arm=False)")
        if np.linalg.norm(v) > MAX_ARM_SPEED_M_S:
            raise ArmError(f"speed {np.linalg.norm(v):.3f} m/s exceeds "
                           f"{MAX_ARM_SPEED_M_S} m/s")
        self._cmd = v.copy()
        self._deadline = self._world.t + float(duration_s)
        self.n_commands += 1

    def holds(self, v_xyz_m_s: np.ndarray, until_s: float) -> bool:
        """True when the arm is commanded exactly ``v_xyz_m_s``, non-zero, until at least
        scene time ``until_s``: the same command sent then changes nothing before it."""
        v = np.asarray(v_xyz_m_s, dtype=float)
        return bool(np.any(v) and np.array_equal(v, self._cmd) and self._deadline > until_s)

    def stop(self) -> None:
        """Command zero velocity now (the lag still applies, as on a real arm)."""
        self._cmd = np.zeros(3)
        self._deadline = self._world.t
        self.stop_times.append(float(self._world.t))

    def tcp_pose(self) -> np.ndarray:
        """Current TCP pose ``(x, y, z, qx, qy, qz, qw)`` in ``link_base`` [m]."""
        return self._world.tcp_pose()

    def close(self) -> None:
        """Stop and disconnect."""
        self.stop()
        self._velocity_mode = False
        self._connected = False

    def velocities(self, t: np.ndarray) -> np.ndarray:
        """TCP velocity at sample times ``t`` (advances the lag state)."""
        tau = self._world.scenario.arm_lag_s
        out = np.empty((t.shape[0], 3))
        split = int(np.searchsorted(t, self._deadline))
        start = t[0] - 1.0 / self._world.fs
        for lo, hi, target in ((0, split, self._cmd), (split, t.shape[0], np.zeros(3))):
            if hi <= lo:
                continue
            decay = np.exp(-(t[lo:hi] - start) / tau)[:, None]
            out[lo:hi] = target + (self.v - target) * decay
            self.v = out[hi - 1].copy()
            start = t[hi - 1]
        return out


class World:
    """A running simulated trial. Deterministic by ``scenario.seed``.

    ``record`` keeps a trajectory log at the mocap rate (true, noise-free values); it defaults
    to on for the closed-loop scenarios and off otherwise (it is the only part that grows).
    """

    def __init__(self, scenario: sc.Scenario, record: bool | None = None) -> None:
        if not isinstance(scenario, sc.Scenario):
            raise ValueError("World needs a Scenario (see aslip_ros.scene.scenarios)")
        self.scenario = scn = scenario
        self.layout = get_layout(scn.layout)
        self.object = get_object(scn.object)
        self.pad = get_pad(scn.pad)
        self.fs = float(scn.sample_rate)
        self.record = scn.closed_loop if record is None else bool(record)
        self._R = yaw_rotation(scn.yaw_rad)
        self._q = yaw_quaternion(scn.yaw_rad)
        self._plane = self._R[:, [0, 2]]        # grasp-plane x and z axes in world
        seeds = np.random.SeedSequence([scn.seed, 0xA511]).spawn(4)
        motion_rng, agent_rng, self._mocap_rng, _ = (np.random.default_rng(s) for s in seeds)
        self.synth = Synth(self.layout, self.pad, self.object, scn.acoustics, self.fs,
                           scn.seed)
        self.arm = SimArm(self)
        self._i = 0
        self._p_tcp = TCP_START_M.copy()
        self._r = np.zeros(2)
        self._angle = 0.0
        self._v_rel_last = np.zeros(2)
        self._sweeps = self._wander = self._agent = self._touch = self._drag = None
        if scn.kind == "robot_induced" and not scn.commanded_arm:
            self._sweeps = robot_sweeps(motion_rng, scn.max_slip_speed_m_s, scn.slow_fraction)
        if scn.kind == "external_induced":
            self._agent, self._touch = sc.agent_pushes(scn, agent_rng)
            if scn.condition == "robot_moving":
                self._wander = sc.arm_wander(scn, motion_rng)
        if scn.kind == "external_drag":
            self._drag = sc.drag_path(scn, agent_rng)
        if scn.kind == "scripted":
            self._agent = sc.script_train(scn)
        if scn.kind == "gravity_pivot":
            self._agent, self._touch = sc.gravity_pivots(scn, agent_rng)
            if scn.condition == "robot_moving":
                self._wander = sc.arm_wander(scn, motion_rng)
        d = np.asarray(scn.push_dir_xz, dtype=float)
        self._push_xz = d / np.hypot(*d)
        self._push_world = self._plane @ self._push_xz
        lead0 = float(self._push_world @ TCP_START_M) + self.object.length_m
        self._wall_s = lead0 + scn.wall_distance_m
        self._wall_slack = 2.0 * self.object.friction * scn.grip_force_n \
            / scn.wall_stiffness_n_m
        # Pivoting wall push: where the surface meets the object (grasp plane, object frame
        # at angle 0), the lever arm perpendicular to the push (+x for a downward push).
        self._pivot = scn.kind == "wall_push" and scn.pivots
        lever_dir = np.array([-self._push_xz[1], self._push_xz[0]])
        self._contact_body = scn.pivot_lever_m * lever_dir \
            + self.object.length_m * self._push_xz
        self.wall_contact_time: float | None = None
        self.wall_contact_tcp_position: np.ndarray | None = None
        #: Every contact onset (time [s], TCP position [m]), e.g. after retract-and-reapproach.
        self.wall_contacts: list[tuple[float, np.ndarray]] = []
        self._in_contact = False
        self.slip_onset_time: float | None = None
        #: First time the object turns relative to the fingers [s] (None until it does).
        self.rotation_onset_time: float | None = None
        self._next_mocap = 0
        self._next_tcp = 0
        self._pending: deque = deque()
        self._log: dict[str, list] = {k: [] for k in ("t", "tcp", "object", "rel", "v_rel",
                                                      "w_rel", "angle")}

    # ------------------------------------------------------------------ state accessors
    @property
    def t(self) -> float:
        """Simulated time [s] of the next sample."""
        return self._i / self.fs

    @property
    def sample_index(self) -> int:
        """Index of the next audio sample."""
        return self._i

    def tcp_pose(self) -> np.ndarray:
        """True TCP pose now, ``(x, y, z, qx, qy, qz, qw)`` in ``world``."""
        return np.concatenate([self._p_tcp, self._q])

    def object_pose(self) -> np.ndarray:
        """True object pose now in ``world``."""
        return np.concatenate([self._p_tcp + self._plane @ self._r,
                               self._object_quaternion(self._angle)])

    def angle_turned(self) -> float:
        """Angle the object has turned relative to the fingers since the start, about the pad
        normal (+y of the grasp plane) [rad]."""
        return float(self._angle)

    def _object_quaternion(self, angle: float) -> np.ndarray:
        """The object's orientation in ``world``: the grasp plane's, turned by ``angle``
        about the grasp plane's y axis."""
        if angle == 0.0:
            return self._q
        return (Rotation.from_quat(self._q) * Rotation.from_rotvec([0.0, angle, 0.0])).as_quat()

    def relative_xz(self) -> np.ndarray:
        """Object position relative to the grasp centre, grasp-plane (x, z) [m]."""
        return self._r.copy()

    def slip_velocity(self) -> np.ndarray:
        """True slip velocity at the last sample, grasp-plane (x, z) [m/s]."""
        return self._v_rel_last.copy()

    def wall_position(self) -> np.ndarray:
        """A point on the wall plane in ``world`` (wall_push only) [m]."""
        return TCP_START_M + self._push_world * (self._wall_s - self._push_world @ TCP_START_M)

    def wall_normal(self) -> np.ndarray:
        """Unit push direction in ``world``; the wall faces against it."""
        return self._push_world.copy()

    def trajectory(self) -> dict[str, np.ndarray]:
        """Logged truth at the mocap rate (needs ``record``): t, tcp, object (world xyz),
        rel (grasp-plane xz), v_rel (grasp-plane xz, at the pad centre), w_rel (about the
        grasp plane's y) [rad/s], angle (turned relative to the fingers) [rad]."""
        if not self.record:
            raise ValueError("trajectory() needs World(..., record=True)")
        return {k: np.asarray(v) for k, v in self._log.items()}

    def metadata(self) -> dict:
        """Scenario metadata in the format of docs/design.md."""
        scn = self.scenario
        return {"format": "aslip-metadata", "version": 1,
                "sample_rate": self.fs, "channel_names": self.layout.channel_names,
                "layout": scn.layout, "object": scn.object, "pad": scn.pad,
                "induced": scn.induced, "condition": scn.condition, "seed": int(scn.seed),
                "trial_id": scn.trial_id, "scenario": scn.kind,
                "scene_version": SCENE_VERSION,
                "mocap_rate_hz": scn.mocap_rate_hz, "tcp_rate_hz": scn.tcp_rate_hz,
                "grasp_plane_in_finger": [0, 0, 0, 0, 0, 0, 1],
                "grasp_plane_in_tcp": [0, 0, 0, 0, 0, 0, 1]}

    # ------------------------------------------------------------------ stepping
    def stream(self, block_frames: int = 480) -> Iterator[Chunk]:
        """Chunks of ``block_frames`` samples until ``duration_s`` (the last may be shorter)."""
        _check_frames(block_frames, "block_frames")
        if self.scenario.duration_s is None:
            raise ValueError("stream() needs a scenario with duration_s; use step() for "
                             "open-ended closed-loop runs")
        total = int(round(self.scenario.duration_s * self.fs))
        per = max(1, int(np.ceil(_SYNTH_BLOCK_S * self.fs / block_frames)))
        while self._i < total:
            n = min(block_frames * per, total - self._i)
            base, audio, v_rel, w_rel, tcp = self._advance(n)
            for lo in range(0, n, block_frames):
                hi = min(lo + block_frames, n)
                yield self._chunk(base + lo, audio[lo:hi], v_rel[lo:hi], w_rel[lo:hi], tcp)

    def step(self, n_frames: int) -> Chunk:
        """Advance ``n_frames`` samples under the current arm command; return the chunk."""
        _check_frames(n_frames, "n_frames")
        base, audio, v_rel, w_rel, tcp = self._advance(int(n_frames))
        return self._chunk(base, audio, v_rel, w_rel, tcp)

    def _chunk(self, start: int, audio, v_rel, w_rel, tcp: list) -> Chunk:
        end = start + audio.shape[0]
        mocap = []
        while self._pending and self._pending[0][0] < end:
            mocap.append(self._pending.popleft()[1])
        tcp_here = [s for s in tcp if start <= s[0] < end]
        return Chunk(start, start / self.fs, audio, mocap,
                     [(i / self.fs, pose) for i, pose in tcp_here], v_rel, w_rel)

    def _advance(self, n: int):
        scn, fs = self.scenario, self.fs
        i0 = self._i
        t = (i0 + np.arange(n)) / fs
        touch = np.zeros(n)
        if self._sweeps is not None:
            arm_xz = self._sweeps.evaluate(t)
            v_tcp = arm_xz @ self._plane.T
        elif self._wander is not None:
            v_tcp = self._wander.evaluate(t)
        else:
            v_tcp = np.zeros((n, 3))
        if scn.kind != "robot_induced" or scn.commanded_arm:
            v_tcp = v_tcp + self.arm.velocities(t)
        p_tcp = self._p_tcp + np.cumsum(v_tcp, axis=0) / fs

        w_rel = np.zeros(n)
        if scn.kind == "robot_induced":
            # The probe stands still in the world: slip is minus the arm's in-plane motion.
            v_rel = -(v_tcp @ self._plane)
        elif scn.kind in ("external_induced", "scripted", "gravity_pivot"):
            vw = self._agent.evaluate(t)
            v_rel, w_rel = np.ascontiguousarray(vw[:, :2]), vw[:, 2].copy()
            if self._touch is not None:
                touch = self._touch.evaluate(t)[:, 0]
        elif scn.kind == "external_drag":
            # The agent carries the object; it slips unless the arm moves with it.
            v_obj_xz = self._drag.evaluate(t)
            v_rel = v_obj_xz - v_tcp @ self._plane
            touch[:] = 0.6
        elif self._pivot:
            w_rel, touch = self._wall_pivot(t, p_tcp)
            v_rel = np.zeros((n, 2))
        else:
            r, v_rel, touch = self._wall(t, p_tcp)
        angle = self._angle + np.cumsum(w_rel) / fs if np.any(w_rel) else np.full(n, self._angle)
        if scn.kind != "wall_push" or self._pivot:
            r = self._integrate(v_rel, w_rel, angle)
        if self.rotation_onset_time is None and np.any(w_rel != 0.0):
            self.rotation_onset_time = float(t[int(np.argmax(w_rel != 0.0))])

        obj = p_tcp + r @ self._plane.T
        self._v_rel_last = v_rel[-1].copy()
        audio = self.synth.render(i0, v_rel, v_tcp, touch, w_rel=w_rel)
        tcp = self._sample_sensors(i0, n, p_tcp, obj, r, v_rel, w_rel, angle)
        self._p_tcp = p_tcp[-1].copy()
        self._r = r[-1].copy()
        self._angle = float(angle[-1])
        self._i += n
        return i0, audio, v_rel, w_rel, tcp

    def _integrate(self, v_rel: np.ndarray, w_rel: np.ndarray,
                   angle: np.ndarray) -> np.ndarray:
        """The object origin relative to the grasp centre per sample, grasp-plane (x, z).

        The object turns about the pad centre: ``dr/dt = v + w x r`` (x: ``+ wy rz``, z:
        ``- wy rx``), with ``v`` the velocity of its point at the pad centre and ``angle``
        the integral of ``w``. In the frame turning with the object, ``q = Ry(-angle) r``
        moves at ``Ry(-angle) v``.
        """
        fs = self.fs
        if not np.any(w_rel):
            return self._r + np.cumsum(v_rel, axis=0) / fs
        c, s = np.cos(angle), np.sin(angle)
        c0, s0 = np.cos(self._angle), np.sin(self._angle)
        q0 = np.array([self._r[0] * c0 - self._r[1] * s0, self._r[0] * s0 + self._r[1] * c0])
        q = q0 + np.cumsum(np.column_stack([v_rel[:, 0] * c - v_rel[:, 1] * s,
                                            v_rel[:, 0] * s + v_rel[:, 1] * c]), axis=0) / fs
        return np.column_stack([q[:, 0] * c + q[:, 1] * s, -q[:, 0] * s + q[:, 1] * c])

    def _wall(self, t: np.ndarray, p_tcp: np.ndarray):
        """Rigid grip until the wall force beats friction, then a slip ratchet.

        Along the push direction the object's leading point may press at most ``slack``
        (friction / wall stiffness) into the wall; beyond that the object slips back relative
        to the fingers. Retreating never pulls it forward again: friction holds it.
        """
        along = p_tcp @ self._push_world                              # (n,)
        limit = self._wall_s + self._wall_slack - self.object.length_m - along
        r_d0 = float(self._r @ self._push_xz)
        r_d = np.minimum(r_d0, np.minimum.accumulate(limit))
        r = self._r + np.outer(r_d - r_d0, self._push_xz)
        prev = np.concatenate([[r_d0], r_d[:-1]])
        v_rel = np.outer((r_d - prev) * self.fs, self._push_xz)
        lead = along + r_d + self.object.length_m
        touch = self._wall_touch(t, p_tcp, lead - self._wall_s)
        if self.slip_onset_time is None and np.any(r_d < r_d0 - 1e-9):
            self.slip_onset_time = float(t[int(np.argmax(r_d < r_d0 - 1e-9))])
        return r, v_rel, touch

    def _wall_touch(self, t: np.ndarray, p_tcp: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Touch level from the contact depth into the wall [m]; records contact onsets."""
        touch = np.clip(depth / 1e-3, 0.0, 1.0) * 0.5
        contact = depth >= 0.0
        onsets = np.flatnonzero(contact & ~np.concatenate([[self._in_contact], contact[:-1]]))
        for k in onsets:
            self.wall_contacts.append((float(t[k]), p_tcp[k].copy()))
        self._in_contact = bool(contact[-1])
        if self.wall_contact_time is None and self.wall_contacts:
            self.wall_contact_time, first = self.wall_contacts[0]
            self.wall_contact_tcp_position = first.copy()
        return touch

    def _wall_pivot(self, t: np.ndarray, p_tcp: np.ndarray):
        """Rigid grip until the wall's torque beats the pads' torsional friction, then a turn
        ratchet: ``(w_rel, touch)``.

        The surface meets the object at the lever arm: its force ``F`` turns the object with
        the torque ``F * m`` (``m``: the contact point's moment arm about the pad centre).
        The contact may press at most ``torsional friction / (m * stiffness)`` into the
        surface; beyond that the object turns (about the pad centre, the whole object
        rigidly) just enough to stay there. Friction holds the angle when the arm backs off,
        and the turning stops when the arm stops: it is driven by the arm's travel.
        """
        d = self._push_xz
        along = p_tcp @ self._push_world                              # (n,)
        c = self._r + _turn(self._contact_body, self._angle)         # contact point now
        a, m = float(c @ d), float(d @ np.array([c[1], -c[0]]))     # g(u) = a cos + m sin
        scn = self.scenario
        slack = scn.torsional_friction_nm / (max(abs(m), 1e-6) * scn.wall_stiffness_n_m)
        limit = self._wall_s + slack - along
        # Turning by u in the direction that withdraws the contact point: g = rho cos(u + phi).
        rho, phi = np.hypot(a, m), np.arctan2(abs(m), a)
        need = np.arccos(np.clip(limit / rho, -1.0, 1.0)) - phi
        u = np.maximum.accumulate(np.maximum(need, 0.0))
        sign = -1.0 if m > 0.0 else 1.0
        prev = np.concatenate([[0.0], u[:-1]])
        w_rel = sign * (u - prev) * self.fs
        depth = along + rho * np.cos(u + phi) - self._wall_s
        return w_rel, self._wall_touch(t, p_tcp, depth)

    def _sample_sensors(self, i0: int, n: int, p_tcp, obj, r, v_rel, w_rel, angle) -> list:
        scn, fs = self.scenario, self.fs
        end = i0 + n
        latency = int(round(scn.mocap_latency_s * fs))
        while True:
            k = self._next_mocap
            idx = int(round(k * fs / scn.mocap_rate_hz))
            if idx >= end:
                break
            self._next_mocap += 1
            j = idx - i0
            noise = self._mocap_rng.normal(0.0, scn.mocap_noise_m, 6)
            dropped = self._mocap_rng.random() < scn.mocap_drop_prob
            tc = idx / fs
            if self.record:
                self._log["t"].append(tc)
                self._log["tcp"].append(p_tcp[j].copy())
                self._log["object"].append(obj[j].copy())
                self._log["rel"].append(r[j].copy())
                self._log["v_rel"].append(v_rel[j].copy())
                self._log["w_rel"].append(float(w_rel[j]))
                self._log["angle"].append(float(angle[j]))
            if dropped:
                continue
            sample = MocapSample(tc, np.concatenate([p_tcp[j] + noise[:3], self._q]),
                                 np.concatenate([obj[j] + noise[3:],
                                                 self._object_quaternion(float(angle[j]))]))
            self._pending.append((idx + latency, sample))
        tcp = []
        while True:
            idx = int(round(self._next_tcp * fs / scn.tcp_rate_hz))
            if idx >= end:
                break
            self._next_tcp += 1
            tcp.append((idx, np.concatenate([p_tcp[idx - i0], self._q])))
        return tcp


def _check_frames(n, name: str) -> None:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n <= 0:
        raise ValueError(f"{name} must be a positive integer, got {n!r}")


def _turn(p: np.ndarray, angle: float) -> np.ndarray:
    """Grasp-plane point ``(x, z)`` turned by ``angle`` about the grasp plane's y axis."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([p[0] * c + p[1] * s, -p[0] * s + p[1] * c])
