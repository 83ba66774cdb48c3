"""Slip ground truth: mean slip of the object relative to the finger per window.

Frames (docs/design.md): poses are ``(x, y, z, qx, qy, qz, qw)`` in metres. The grasp-plane
frame ``G`` is the finger (or TCP) rigid-body pose composed with a fixed calibration,
``G(t) = F(t) * grasp_plane_in_finger``. Slip is the motion of the object relative to the
finger, expressed in ``G``: a planar velocity (its y component, normal to the pads, is
dropped) and an angular velocity about the pad normal +y (``aslip_ros.slip``).

Motion capture (``mocap_window_velocity``): the object's pose in the grasp plane,
``r(t) = R_G(t)^T (p_O(t) - p_G(t))`` and ``Q(t) = R_G(t)^T R_O(t)``, is what a camera
rigidly attached to the finger would see. Over a window [t0, t1] the relative motion
``(Q(t1), r(t1)) (Q(t0), r(t0))^-1`` is a rotation ``dQ`` and a translation
``d = r(t1) - dQ r(t0)``; its logarithm is the constant twist that carries the object from
the pose at t0 to the pose at t1 (:func:`mean_twist`). Its rotation vector over the window
length is the mean angular velocity ``w`` (the label ``wy`` is its y component: the
object's turn about the pad normal), and its translation part is the mean velocity of the
object's material point at the grasp-plane origin, the pad centre:
``v_c = dr/dt - w x r``. Without rotation (``w = 0``) that is exactly
``(r(t1) - r(t0)) / (t1 - t0)``, whatever happens inside the window; a pure rotation about
the pad centre gives ``v_c = 0`` wherever the object's own origin lies.

The export reads ``r`` and ``Q`` at the window's ends from the relative track smoothed by a
quadratic fit over ``smoothing_s`` (150 ms, :data:`DEFAULT_LABEL_SMOOTHING_S`;
:func:`smoothed_window_twist`), not from two raw poses: differencing two poses 200 ms apart
puts the poses' noise into the label, amplified by sqrt(2) / 0.2 s (0.15 mm of marker
noise: about 2 mm/s; 0.3 mm: about 4 mm/s, near the 5 mm/s slip threshold). The fit keeps
a motion of constant acceleration exactly and spreads a step of velocity over 75 ms either
side.

Robot state (``robot_window_velocity``, robot-induced data): the probe is fixed in the
world and its pose is not recorded; its motion relative to the grasp plane is the inverse
of the grasp plane's own, ``G(t1)^-1 G(t0)``, read by the same :func:`mean_twist`. The
planar label is minus the grasp-plane origin's velocity in the grasp plane (for a
gripper that does not rotate, ``-R_G^T (p_G(t1) - p_G(t0)) / (t1 - t0)``) and ``wy`` is
minus the gripper's angular velocity about its grasp-plane y (0 for the sweeps, which are
translations).

Dropouts: poses are interpolated (position linearly, orientation by Slerp) between
neighbouring samples. A window is dropped (reason ``label_gap``) when either stream has a
gap longer than ``max_gap_s`` (default :data:`DEFAULT_MAX_GAP_S` = 50 ms, i.e. up to four
dropped frames at 100 Hz or five at 120 Hz) anywhere over the window, and (reason
``label_coverage``) when the window is not inside the stream's time span: labels are never
extrapolated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from aslip_ros.data.stream_labels import (DEFAULT_SMOOTHER, Smoother, relative_track,
                                          smooth_positions)
from aslip_ros.slip import ANGULAR_AXIS, VELOCITY_AXES
from aslip_ros.poses import IDENTITY_POSE, as_pose, compose, invert, quat_ok

DEFAULT_MAX_GAP_S = 0.05
#: The label window and its hop [s]: the exporter's grid and mocap_bridge's live truth.
DEFAULT_WINDOW_S = 0.2
DEFAULT_HOP_S = 0.1
# 5 mm/s = 1 mm of slip per 200 ms window: several times the velocity noise of
# sub-millimetre motion capture differenced over a window (about 1-3 mm/s), and the size
# of the paper's magnitude error, so "slip" means motion the sensor can be asked to see.
DEFAULT_EPSILON_M_S = 0.005
#: Motion-capture window labels: the ends are read from the relative pose track smoothed by
#: the streaming labels' fit (a quadratic over 150 ms), not from two raw poses. Against the
#: scene's true slip (``python -m benchmarks.label_smoother --windows``) that cuts the label
#: noise 2.8x at the default mocap noise and 2.5x at a lab's (docs/results.md, "Window
#: labels from smoothed poses"); 0 reads the raw poses at the window's ends.
DEFAULT_LABEL_SMOOTHING_S = DEFAULT_SMOOTHER.window_s

# Per-window reason codes returned with the labels.
OK, COVERAGE, GAP = 0, 1, 2
REASONS = {COVERAGE: "label_coverage", GAP: "label_gap"}


def measure_grasp_plane(finger_poses, object_poses, orientation=IDENTITY_POSE[3:],
                        min_pairs: int = 3) -> np.ndarray:
    """``grasp_plane_in_finger`` measured from simultaneous finger and object poses.

    The object is held centred between the pads, so the grasp-plane origin is the object's
    mean position in the finger frame over the pairs; the orientation (qx qy qz qw) cannot
    be measured this way and is taken as given. Returns the pose7.

    :raises ValueError: fewer than ``min_pairs`` pairs, mismatched shapes, non-finite values
        or a zero quaternion.
    """
    f = np.asarray(finger_poses, dtype=np.float64)
    o = np.asarray(object_poses, dtype=np.float64)
    if f.ndim != 2 or f.shape[1] != 7 or f.shape != o.shape:
        raise ValueError(f"finger and object poses must both be (N, 7), got {f.shape} and "
                         f"{o.shape}")
    if len(f) < max(1, min_pairs):
        raise ValueError(f"grasp-plane calibration needs at least {max(1, min_pairs)} pose "
                         f"pairs, got {len(f)}")
    if not (np.isfinite(f).all() and np.isfinite(o).all()):
        raise ValueError("grasp-plane calibration poses contain NaN or Inf")
    if not (quat_ok(f).all() and quat_ok(o).all()):
        raise ValueError("grasp-plane calibration poses contain a zero quaternion")
    q = as_pose(np.concatenate([np.zeros(3), np.asarray(orientation, dtype=np.float64)
                                .reshape(-1)]), "grasp-plane orientation")[3:]
    rel = compose(invert(f), o)[:, :3]
    return np.concatenate([rel.mean(axis=0), q])


class PoseTrack:
    """A time series of poses with interpolation and gap bookkeeping.

    ``t`` in seconds (any origin), ``poses`` (N, 7). Samples are sorted by time; repeated
    stamps keep the last sample; samples with non-finite values or a zero quaternion are
    treated as dropped frames.
    """

    def __init__(self, t, poses, name: str = "poses"):
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
        if t.shape[0] != poses.shape[0]:
            raise ValueError(f"{name}: {t.shape[0]} stamps but {poses.shape[0]} poses")
        ok = np.isfinite(t) & quat_ok(poses)
        t, poses = t[ok], poses[ok]
        qn = np.linalg.norm(poses[:, 3:], axis=1)
        order = np.argsort(t, kind="stable")
        t, poses, qn = t[order], poses[order], qn[order]
        if t.size:
            keep = np.append(np.diff(t) > 0, True)   # last of each run of equal stamps
            t, poses, qn = t[keep], poses[keep], qn[keep]
        self.name = name
        self.t = t
        self.pos = poses[:, :3]
        self.quat = poses[:, 3:] / qn[:, None]
        self._slerp = None
        if t.size >= 2:
            self._slerp = Slerp(t, Rotation.from_quat(self.quat))

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def rate_hz(self) -> float:
        """Median sample rate (0 when fewer than two samples)."""
        return float(1.0 / np.median(np.diff(self.t))) if self.t.size >= 2 else 0.0

    def interpolate(self, tq) -> tuple[np.ndarray, Rotation]:
        """Positions (M, 3) and rotations at ``tq`` (clamped into the track's span)."""
        if self.t.size < 2:
            raise ValueError(f"{self.name}: need at least two samples to interpolate, "
                             f"have {self.t.size}")
        tq = np.clip(np.asarray(tq, dtype=np.float64).reshape(-1), self.t[0], self.t[-1])
        pos = np.stack([np.interp(tq, self.t, self.pos[:, k]) for k in range(3)], axis=1)
        return pos, self._slerp(tq)

    def check(self, t0, t1, max_gap_s: float) -> np.ndarray:
        """Reason code per window [t0, t1]: OK, COVERAGE (outside the span) or GAP."""
        t0 = np.asarray(t0, dtype=np.float64).reshape(-1)
        t1 = np.asarray(t1, dtype=np.float64).reshape(-1)
        codes = np.full(t0.shape, OK, dtype=np.uint8)
        if self.t.size < 2:
            codes[:] = COVERAGE
            return codes
        # 1 us of slack absorbs rounding in the audio clock fit, not real extrapolation.
        inside = (t0 >= self.t[0] - 1e-6) & (t1 <= self.t[-1] + 1e-6)
        codes[~inside] = COVERAGE
        # Intervals between consecutive samples that touch the window: from the last
        # sample at or before t0 to the first sample at or after t1.
        bad = np.diff(self.t) > max_gap_s + 1e-9
        cum = np.concatenate([[0], np.cumsum(bad)])
        i0 = np.clip(np.searchsorted(self.t, t0, side="right") - 1, 0, bad.size)
        i1 = np.clip(np.searchsorted(self.t, t1, side="left"), 0, bad.size)
        gap = (cum[np.maximum(i1, i0)] - cum[i0]) > 0
        codes[inside & gap] = GAP
        return codes


def _grasp_plane(track: PoseTrack, tq, calib: np.ndarray) -> tuple[np.ndarray, Rotation]:
    pos, rot = track.interpolate(tq)
    rc = Rotation.from_quat(calib[3:])
    return pos + rot.apply(calib[:3]), rot * rc


def _window_times(t0, t1):
    t0 = np.asarray(t0, dtype=np.float64).reshape(-1)
    t1 = np.asarray(t1, dtype=np.float64).reshape(-1)
    if t0.shape != t1.shape:
        raise ValueError(f"t0 and t1 differ in length: {t0.shape} vs {t1.shape}")
    if np.any(t1 <= t0):
        raise ValueError("every window needs t1 > t0")
    return t0, t1


def mean_twist(r0: np.ndarray, q0: Rotation, r1: np.ndarray, q1: Rotation,
               dt) -> tuple[np.ndarray, np.ndarray]:
    """The constant twist that carries poses ``(q0, r0)`` to ``(q1, r1)`` in ``dt`` seconds.

    Poses of a rigid body in a reference frame (rotations and positions, ``(M, 3)``). Returns
    ``(v, w)``, each ``(M, 3)`` in the reference frame: ``w`` the angular velocity [rad/s]
    and ``v`` the velocity [m/s] of the body's material point at the frame's origin, the
    logarithm of the relative motion ``(q1, r1) (q0, r0)^-1`` over ``dt`` (exact for a
    motion of constant twist; ``v = (r1 - r0) / dt`` when the body does not turn).
    """
    dq = q1 * q0.inv()
    phi = dq.as_rotvec().reshape(-1, 3)
    d = np.asarray(r1, dtype=np.float64).reshape(-1, 3) - dq.apply(r0).reshape(-1, 3)
    # d = J(phi) rho, with J the left Jacobian of SO(3); rho = J(phi)^-1 d:
    # J^-1 = I - [phi]x / 2 + c(theta) [phi]x^2, c = (1 - (theta / 2) cot(theta / 2)) / theta^2.
    theta = np.linalg.norm(phi, axis=1)
    small = theta < 1e-4
    th = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12.0 + theta ** 2 / 720.0,
                 (1.0 - 0.5 * th / np.tan(0.5 * th)) / th ** 2)
    pxd = np.cross(phi, d)
    rho = d - 0.5 * pxd + c[:, None] * np.cross(phi, pxd)
    dt = np.asarray(dt, dtype=np.float64).reshape(-1, 1)
    return rho / dt, phi / dt


@dataclass
class WindowLabels:
    """Per-window slip in the grasp plane (the pad centre's velocity and the angular
    velocity) and why a window has none."""

    velocity: np.ndarray       # (M, 3) m/s, grasp plane, y kept for diagnostics
    reason: np.ndarray         # (M,) uint8: OK, COVERAGE or GAP
    #: (M, 3) rad/s, grasp plane: the object's angular velocity relative to the finger
    #: (x and z kept for diagnostics; the label is ``angular``, about +y). None: zeros.
    omega: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.omega is None:
            self.omega = np.zeros_like(self.velocity)

    @property
    def valid(self) -> np.ndarray:
        return self.reason == OK

    @property
    def vx(self) -> np.ndarray:
        return self.velocity[:, 0]

    @property
    def vz(self) -> np.ndarray:
        return self.velocity[:, 2]

    @property
    def slip_velocity(self) -> np.ndarray:
        """(M, N_VELOCITY): the components of ``aslip_ros.slip`` (the y component is not
        slip)."""
        return self.velocity[:, list(VELOCITY_AXES)]

    @property
    def speed(self) -> np.ndarray:
        """Planar speed |(vx, vz)| (the y component is not slip)."""
        return np.linalg.norm(self.slip_velocity, axis=1)

    @property
    def angular(self) -> np.ndarray:
        """(M,) rad/s: the rotational slip ``wy`` about the pad normal (``aslip_ros.slip``)."""
        return self.omega[:, ANGULAR_AXIS]


def smoothed_window_twist(track: np.ndarray, t0, t1, smoother: Smoother
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`mean_twist` over each window [t0, t1] between the poses of a relative track
    (``stream_labels.relative_track``: t [s], r, a) smoothed by ``smoother``
    (``stream_labels.smooth_positions``); the turn over the window is the change of the
    accumulated rotation ``a``. Returns ``(v, w, valid)``: valid where both ends are
    (no pose gap longer than ``smoother.max_gap_s`` within half a smoother window)."""
    t0, t1 = _window_times(t0, t1)
    t, cols = track[:, 0], track[:, 1:7]
    e0, ok0 = smooth_positions(t, cols, t0, smoother)
    e1, ok1 = smooth_positions(t, cols, t1, smoother)
    turn = Rotation.from_rotvec(e1[:, 3:] - e0[:, 3:]) if t0.size else Rotation.identity(0)
    v, w = mean_twist(e0[:, :3], Rotation.identity(t0.size), e1[:, :3], turn, t1 - t0)
    return v, w, ok0 & ok1


def mocap_window_velocity(finger: PoseTrack, obj: PoseTrack, t0, t1,
                          grasp_plane_in_finger=IDENTITY_POSE,
                          max_gap_s: float = DEFAULT_MAX_GAP_S,
                          smoothing_s: float = 0.0) -> WindowLabels:
    """Mean motion of the object relative to the finger over each window, from motion
    capture: the pad-centre velocity and the angular velocity (:func:`mean_twist`).

    ``smoothing_s`` > 0: the ends are read from the relative track smoothed over that long
    (:func:`smoothed_window_twist`; the export's default, :data:`DEFAULT_LABEL_SMOOTHING_S`),
    and from the raw poses where a gap is too near an end. 0: the raw poses at the ends,
    which is all a live reader has (``mocap_bridge``: the poses after "now" are not in yet).
    """
    t0, t1 = _window_times(t0, t1)
    calib = as_pose(grasp_plane_in_finger, "grasp_plane_in_finger")
    reason = np.maximum(finger.check(t0, t1, max_gap_s), obj.check(t0, t1, max_gap_s))
    vel, omega = np.zeros((t0.size, 3)), np.zeros((t0.size, 3))
    if t0.size == 0 or len(finger) < 2 or len(obj) < 2:
        return WindowLabels(vel, reason, omega)
    ends = []
    for tq in (t0, t1):
        pg, rg = _grasp_plane(finger, tq, calib)
        po, ro = obj.interpolate(tq)
        ends.append((rg.inv().apply(po - pg), rg.inv() * ro))
    (r0, q0), (r1, q1) = ends
    vel, omega = mean_twist(r0, q0, r1, q1, t1 - t0)
    if smoothing_s > 0:
        smoother = Smoother(smoothing_s, DEFAULT_SMOOTHER.polyorder, max_gap_s)
        sv, sw, ok = smoothed_window_twist(relative_track("mocap", finger, calib, obj),
                                           t0, t1, smoother)
        vel[ok], omega[ok] = sv[ok], sw[ok]
    vel[reason != OK] = 0.0
    omega[reason != OK] = 0.0
    return WindowLabels(vel, reason, omega)


def robot_window_velocity(tcp: PoseTrack, t0, t1, grasp_plane_in_tcp=IDENTITY_POSE,
                          max_gap_s: float = DEFAULT_MAX_GAP_S) -> WindowLabels:
    """Mean motion of a world-fixed probe relative to the finger over each window: the
    inverse of the grasp plane's own motion (:func:`mean_twist`)."""
    t0, t1 = _window_times(t0, t1)
    calib = as_pose(grasp_plane_in_tcp, "grasp_plane_in_tcp")
    reason = tcp.check(t0, t1, max_gap_s)
    vel, omega = np.zeros((t0.size, 3)), np.zeros((t0.size, 3))
    if t0.size == 0 or len(tcp) < 2:
        return WindowLabels(vel, reason, omega)
    # The probe's pose in the grasp plane, for a probe at the world origin (any world-fixed
    # pose gives the same relative motion): (R_G^T, -R_G^T p_G).
    ends = []
    for tq in (t0, t1):
        pg, rg = _grasp_plane(tcp, tq, calib)
        ends.append((-rg.inv().apply(pg), rg.inv()))
    (r0, q0), (r1, q1) = ends
    vel, omega = mean_twist(r0, q0, r1, q1, t1 - t0)
    vel[reason != OK] = 0.0
    omega[reason != OK] = 0.0
    return WindowLabels(vel, reason, omega)
