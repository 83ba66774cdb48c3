"""Slip ground truth: mean slip velocity of the object relative to the finger per window.

Frames (docs/design.md): poses are ``(x, y, z, qx, qy, qz, qw)`` in metres. The grasp-plane
frame ``G`` is the finger (or TCP) rigid-body pose composed with a fixed calibration,
``G(t) = F(t) * grasp_plane_in_finger``. Slip is the velocity of the object relative to
the finger, expressed in ``G``; its y component (normal to the pads) is dropped.

Motion capture (``mocap_window_velocity``): the object's position in the grasp plane,
``r(t) = R_G(t)^T (p_O(t) - p_G(t))``, is what a camera rigidly attached to the finger would
see, so the mean relative velocity over a window [t0, t1] is exactly
``(r(t1) - r(t0)) / (t1 - t0)``, whatever happens inside the window.

Robot state (``robot_window_velocity``, robot-induced data): the probe is fixed in the
world and its pose is not recorded, so the relative velocity is minus the grasp-plane
origin's velocity, expressed in the grasp plane at the window's middle:
``-R_G(t_mid)^T (p_G(t1) - p_G(t0)) / (t1 - t0)``. This equals the motion-capture value
whenever the gripper does not rotate during the window (the sweeps are translations).

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

from aslip_ros.slip import VELOCITY_AXES
from aslip_ros.poses import IDENTITY_POSE, as_pose, compose, invert, quat_ok

DEFAULT_MAX_GAP_S = 0.05
#: The label window and its hop [s]: the exporter's grid and mocap_bridge's live truth.
DEFAULT_WINDOW_S = 0.2
DEFAULT_HOP_S = 0.1
# 5 mm/s = 1 mm of slip per 200 ms window: several times the velocity noise of
# sub-millimetre motion capture differenced over a window (about 1-3 mm/s), and the size
# of the paper's magnitude error, so "slip" means motion the sensor can be asked to see.
DEFAULT_EPSILON_M_S = 0.005

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


@dataclass
class WindowLabels:
    """Per-window slip velocity in the grasp plane and why a window has none."""

    velocity: np.ndarray       # (M, 3) m/s, grasp plane, y kept for diagnostics
    reason: np.ndarray         # (M,) uint8: OK, COVERAGE or GAP

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


def mocap_window_velocity(finger: PoseTrack, obj: PoseTrack, t0, t1,
                          grasp_plane_in_finger=IDENTITY_POSE,
                          max_gap_s: float = DEFAULT_MAX_GAP_S) -> WindowLabels:
    """Mean object-relative-to-finger velocity over each window, from motion capture."""
    t0, t1 = _window_times(t0, t1)
    calib = as_pose(grasp_plane_in_finger, "grasp_plane_in_finger")
    reason = np.maximum(finger.check(t0, t1, max_gap_s), obj.check(t0, t1, max_gap_s))
    vel = np.zeros((t0.size, 3))
    if t0.size == 0 or len(finger) < 2 or len(obj) < 2:
        return WindowLabels(vel, reason)
    ends = []
    for tq in (t0, t1):
        pg, rg = _grasp_plane(finger, tq, calib)
        po, _ = obj.interpolate(tq)
        ends.append(rg.inv().apply(po - pg))
    vel = (ends[1] - ends[0]) / (t1 - t0)[:, None]
    vel[reason != OK] = 0.0
    return WindowLabels(vel, reason)


def robot_window_velocity(tcp: PoseTrack, t0, t1, grasp_plane_in_tcp=IDENTITY_POSE,
                          max_gap_s: float = DEFAULT_MAX_GAP_S) -> WindowLabels:
    """Mean probe-relative-to-finger velocity per window for a world-fixed probe."""
    t0, t1 = _window_times(t0, t1)
    calib = as_pose(grasp_plane_in_tcp, "grasp_plane_in_tcp")
    reason = tcp.check(t0, t1, max_gap_s)
    vel = np.zeros((t0.size, 3))
    if t0.size == 0 or len(tcp) < 2:
        return WindowLabels(vel, reason)
    p0, _ = _grasp_plane(tcp, t0, calib)
    p1, _ = _grasp_plane(tcp, t1, calib)
    _, rmid = _grasp_plane(tcp, 0.5 * (t0 + t1), calib)
    vel = -rmid.inv().apply(p1 - p0) / (t1 - t0)[:, None]
    vel[reason != OK] = 0.0
    return WindowLabels(vel, reason)
