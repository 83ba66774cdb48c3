"""Frame helpers: composition, inversion, grasp-plane <-> base velocity mapping."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros.control import frames


def random_pose(rng):
    return np.concatenate([rng.normal(size=3), Rotation.random(random_state=rng).as_quat()])


def test_compose_with_inverse_is_identity():
    rng = np.random.default_rng(0)
    for _ in range(20):
        a = random_pose(rng)
        ident = frames.compose(a, frames.invert(a))
        assert np.allclose(ident[:3], 0, atol=1e-12)
        assert Rotation.from_quat(ident[3:]).magnitude() == pytest.approx(0, abs=1e-7)


def test_compose_matches_homogeneous_matrices():
    rng = np.random.default_rng(1)
    a, b = random_pose(rng), random_pose(rng)

    def mat(p):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat(p[3:]).as_matrix()
        m[:3, 3] = p[:3]
        return m

    c = frames.compose(a, b)
    assert np.allclose(mat(c), mat(a) @ mat(b))


def test_grasp_base_round_trip_ignores_translation():
    rng = np.random.default_rng(2)
    tcp, calib = random_pose(rng), random_pose(rng)
    v = np.array([0.01, 0.0, -0.03])
    vb = frames.grasp_to_base(v, tcp, calib)
    assert np.linalg.norm(vb) == pytest.approx(np.linalg.norm(v))
    assert np.allclose(frames.base_to_grasp(vb, tcp, calib), v)
    tcp2 = tcp.copy()
    tcp2[:3] += 5.0
    assert np.allclose(frames.grasp_to_base(v, tcp2, calib), vb)


def test_grasp_plane_in_base():
    tcp = [1.0, 0, 0] + list(Rotation.from_euler('z', 90, degrees=True).as_quat())
    gp = frames.grasp_plane_in_base(tcp, [0.1, 0, 0, 0, 0, 0, 1])
    assert np.allclose(gp[:3], [1.0, 0.1, 0.0])


def test_as_pose_normalises_and_validates():
    p = frames.as_pose([0, 0, 0, 0, 0, 0, 2])
    assert p[6] == 1.0
    for bad in ([0] * 7, [np.nan] + [0] * 5 + [1], [0, 0, 0]):
        with pytest.raises(ValueError):
            frames.as_pose(bad)
    assert np.allclose(frames.planar_slip(1, 2), [1, 0, 2])
