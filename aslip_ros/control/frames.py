"""Frame helpers for the controllers: velocities between ``aslip_grasp_plane`` and
``link_base``.

The pose algebra itself (validation, compose, invert) is :mod:`aslip_ros.poses`; its names
are re-exported here for the controllers.
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np

from aslip_ros.poses import (IDENTITY_POSE, PoseLike, as_pose, as_vector3,  # noqa: F401
                             compose, invert, make_pose, rotation_of)


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
