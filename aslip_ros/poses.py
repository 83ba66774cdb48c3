"""Pose algebra: the one definition of a pose and how poses combine (docs/design.md).

A pose is ``(x, y, z, qx, qy, qz, qw)`` float64, metres, quaternion x-y-z-w (scalar last,
scipy's order); arrays of poses have shape ``(..., 7)``. Rotation arithmetic is
:class:`scipy.spatial.transform.Rotation`. ROS-free (floor 0): the controllers, the labels,
the synthetic bags and the message conversion all validate and combine poses here.
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np
from scipy.spatial.transform import Rotation

PoseLike = Union[Sequence[float], np.ndarray]

#: The identity pose (frames coincide), e.g. a missing calibration.
IDENTITY_POSE = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])

#: Quaternions shorter than this are garbage, not rotations: normalising a near-zero vector
#: amplifies noise into an arbitrary rotation.
MIN_QUAT_NORM = 1e-6


def quat_ok(poses) -> np.ndarray:
    """Per pose of ``(..., 7)`` ``poses``: all finite and the quaternion not (near) zero."""
    p = np.asarray(poses, dtype=np.float64)
    finite = np.all(np.isfinite(p), axis=-1)
    with np.errstate(invalid="ignore"):
        return finite & (np.linalg.norm(p[..., 3:], axis=-1) >= MIN_QUAT_NORM)


def as_pose(pose: PoseLike, name: str = "pose") -> np.ndarray:
    """Validate one pose and return a float64 copy with a unit quaternion.

    :raises ValueError: not 7 finite numbers, or a (near-)zero quaternion.
    """
    try:
        p = np.asarray(pose, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 7 finite numbers (x y z qx qy qz qw), "
                         f"got {pose!r}") from None
    if p.shape != (7,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be 7 finite numbers (x y z qx qy qz qw), got {pose!r}")
    n = float(np.linalg.norm(p[3:]))
    if n < MIN_QUAT_NORM:
        raise ValueError(f"{name} has a zero quaternion: {pose!r}")
    p[3:] /= n
    return p


def as_poses(poses, name: str = "poses") -> np.ndarray:
    """Validate an array of poses ``(..., 7)``; a float64 copy with unit quaternions."""
    p = np.array(poses, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] != 7:
        raise ValueError(f"{name} must have 7 values per pose, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name} has a non-finite value")
    n = np.linalg.norm(p[..., 3:], axis=-1, keepdims=True)
    if np.any(n < MIN_QUAT_NORM):
        raise ValueError(f"{name} contain a zero quaternion")
    p[..., 3:] /= n
    return p


def as_vector3(v: Union[Sequence[float], np.ndarray], name: str = "vector") -> np.ndarray:
    """Validate a finite 3-vector and return a float64 copy."""
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{name} must have 3 values, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} has a non-finite value: {a.tolist()}")
    return a


def rotation_of(pose: PoseLike) -> Rotation:
    """The orientation part of a pose."""
    return Rotation.from_quat(as_pose(pose)[3:])


def make_pose(position: Sequence[float], rotation: Rotation) -> np.ndarray:
    """Build a pose from a position [m] and a :class:`Rotation`."""
    return np.concatenate([as_vector3(position, "position"), rotation.as_quat()])


def compose(a_in_w, b_in_a) -> np.ndarray:
    """Pose of ``b`` in ``w`` from ``a`` in ``w`` and ``b`` in ``a`` (``T_wa * T_ab``).

    Either argument may be an array of poses (broadcasting).
    """
    a = as_poses(a_in_w, "a_in_w")
    b = as_poses(b_in_a, "b_in_a")
    ra, rb = Rotation.from_quat(a[..., 3:]), Rotation.from_quat(b[..., 3:])
    return np.concatenate([a[..., :3] + ra.apply(b[..., :3]), (ra * rb).as_quat()], axis=-1)


def invert(a_in_w) -> np.ndarray:
    """Pose of ``w`` in ``a`` from ``a`` in ``w`` (``compose(invert(a), a)`` is the
    identity); also for an array of poses."""
    a = as_poses(a_in_w, "a_in_w")
    r = Rotation.from_quat(a[..., 3:]).inv()
    return np.concatenate([-r.apply(a[..., :3]), r.as_quat()], axis=-1)
