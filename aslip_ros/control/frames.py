"""Pose and frame helpers for the controllers: ``aslip_grasp_plane`` <-> ``link_base``.

Poses are ``(x, y, z, qx, qy, qz, qw)`` float64 arrays in metres (docs/design.md). Rotation
arithmetic is delegated to :class:`scipy.spatial.transform.Rotation`, which uses the same
x-y-z-w (scalar-last) quaternion order.
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np
from scipy.spatial.transform import Rotation

PoseLike = Union[Sequence[float], np.ndarray]

#: The identity pose: grasp plane coincident with the TCP when no calibration is given.
IDENTITY_POSE = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])

# Quaternions shorter than this are treated as garbage rather than normalised, because
# normalising a near-zero vector amplifies noise into an arbitrary rotation.
_MIN_QUAT_NORM = 1e-6


def as_pose(pose: PoseLike, name: str = 'pose') -> np.ndarray:
    """Validate a pose and return a float64 copy with a unit quaternion.

    :raises ValueError: wrong shape, a non-finite value, or a (near-)zero quaternion.
    """
    p = np.asarray(pose, dtype=np.float64).reshape(-1)
    if p.shape != (7,):
        raise ValueError(f'{name} must have 7 values (x, y, z, qx, qy, qz, qw), got {p.shape}')
    if not np.all(np.isfinite(p)):
        raise ValueError(f'{name} has a non-finite value: {p.tolist()}')
    n = float(np.linalg.norm(p[3:]))
    if n < _MIN_QUAT_NORM:
        raise ValueError(f'{name} has a zero quaternion')
    p[3:] /= n
    return p


def as_vector3(v: Union[Sequence[float], np.ndarray], name: str = 'vector') -> np.ndarray:
    """Validate a finite 3-vector and return a float64 copy."""
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f'{name} must have 3 values, got shape {a.shape}')
    if not np.all(np.isfinite(a)):
        raise ValueError(f'{name} has a non-finite value: {a.tolist()}')
    return a


def rotation_of(pose: PoseLike) -> Rotation:
    """The orientation part of a pose."""
    return Rotation.from_quat(as_pose(pose)[3:])


def make_pose(position: Sequence[float], rotation: Rotation) -> np.ndarray:
    """Build a pose from a position [m] and a :class:`Rotation`."""
    return np.concatenate([as_vector3(position, 'position'), rotation.as_quat()])


def compose(a_in_w: PoseLike, b_in_a: PoseLike) -> np.ndarray:
    """Pose of ``b`` in ``w`` from ``a`` in ``w`` and ``b`` in ``a`` (``T_wa * T_ab``)."""
    a = as_pose(a_in_w, 'a_in_w')
    b = as_pose(b_in_a, 'b_in_a')
    r_a = Rotation.from_quat(a[3:])
    return make_pose(a[:3] + r_a.apply(b[:3]), r_a * Rotation.from_quat(b[3:]))


def invert(a_in_w: PoseLike) -> np.ndarray:
    """Pose of ``w`` in ``a`` from ``a`` in ``w``."""
    a = as_pose(a_in_w, 'a_in_w')
    r_inv = Rotation.from_quat(a[3:]).inv()
    return make_pose(-r_inv.apply(a[:3]), r_inv)


def grasp_plane_in_base(tcp_in_base: PoseLike, grasp_plane_in_tcp: PoseLike) -> np.ndarray:
    """The grasp-plane pose in ``link_base`` from the TCP pose and the TCP calibration."""
    return compose(tcp_in_base, grasp_plane_in_tcp)


def planar_slip(vx: float, vz: float) -> np.ndarray:
    """A planar slip ``(vx, vz)`` as a grasp-plane 3-vector; y (pad normal) is zero."""
    return np.array([float(vx), 0.0, float(vz)])


def grasp_to_base(v_grasp: Union[Sequence[float], np.ndarray], tcp_in_base: PoseLike,
                  grasp_plane_in_tcp: PoseLike = IDENTITY_POSE) -> np.ndarray:
    """Rotate a free vector (a velocity) from the grasp plane into ``link_base``.

    Velocities are free vectors, so only the orientations matter: the translation parts of
    the poses do not enter.
    """
    r = rotation_of(tcp_in_base) * rotation_of(grasp_plane_in_tcp)
    return r.apply(as_vector3(v_grasp, 'v_grasp'))


def base_to_grasp(v_base: Union[Sequence[float], np.ndarray], tcp_in_base: PoseLike,
                  grasp_plane_in_tcp: PoseLike = IDENTITY_POSE) -> np.ndarray:
    """Rotate a free vector from ``link_base`` into the grasp plane."""
    r = rotation_of(tcp_in_base) * rotation_of(grasp_plane_in_tcp)
    return r.inv().apply(as_vector3(v_base, 'v_base'))
