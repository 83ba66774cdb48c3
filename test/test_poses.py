"""The one pose algebra (aslip_ros/poses.py) and the modules that use it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aslip_ros import poses


def test_every_user_refuses_the_same_near_zero_quaternion():
    """Controllers, labels and the synthetic bags share one tolerance: a quaternion of norm
    1e-8 (noise, not a rotation) is refused by each, never normalised into a rotation."""
    from aslip_ros.control import frames
    from aslip_ros.data import labels
    tiny = [0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1e-8]
    for as_pose in (poses.as_pose, frames.as_pose, labels.as_pose):
        with pytest.raises(ValueError, match="zero quaternion"):
            as_pose(tiny)
    track = labels.PoseTrack([0.0, 0.01, 0.02], [poses.IDENTITY_POSE, tiny,
                                                 poses.IDENTITY_POSE])
    assert len(track) == 2                      # the garbage sample counts as dropped
    assert poses.quat_ok(np.array([tiny, poses.IDENTITY_POSE])).tolist() == [False, True]


def test_compose_and_invert_broadcast_and_agree():
    rng = np.random.default_rng(0)
    a = np.concatenate([rng.normal(size=(5, 3)), Rotation.random(5, random_state=1).as_quat()],
                       axis=1)
    b = np.concatenate([rng.normal(size=3), Rotation.random(random_state=2).as_quat()])
    ab = poses.compose(a, b)
    for k in range(5):
        np.testing.assert_allclose(ab[k], poses.compose(a[k], b), atol=1e-12)
    ident = poses.compose(poses.invert(a), a)
    np.testing.assert_allclose(ident[:, :3], 0.0, atol=1e-12)
    assert np.allclose(np.abs(ident[:, 6]), 1.0)


def test_bad_poses_are_refused_with_the_argument_name():
    with pytest.raises(ValueError, match="calibration must be 7 finite"):
        poses.as_pose([0.0] * 6, "calibration")
    with pytest.raises(ValueError, match="non-finite"):
        poses.compose([0, 0, np.nan, 0, 0, 0, 1], poses.IDENTITY_POSE)


@pytest.mark.ros
def test_a_pose_parameter_refuses_what_the_pose_algebra_refuses():
    from aslip_ros.nodes import common as c
    assert c.pose7([0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1e-8]) == "has a zero quaternion"
    assert c.pose7([0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0]) is None
