"""Microphone layout geometry, pads and objects of the simulated scene."""

import numpy as np
import pytest

from aslip_ros.scene import layouts


def test_channel_names_and_counts():
    expected = {"1mic": 1, "2mic_centered": 2, "2mic_corners": 2, "2mic_same_finger": 2,
                "4mic": 4}
    assert set(layouts.LAYOUTS) == set(expected)
    for name, n in expected.items():
        lay = layouts.get_layout(name)
        assert lay.n_channels == n
        assert len(set(lay.channel_names)) == n          # names unique
        assert all(m.finger in ("left", "right") for m in lay.mics)


def test_centered_has_no_in_plane_baseline():
    lay = layouts.get_layout("2mic_centered")
    xz = lay.positions_xz()
    assert np.allclose(xz, 0.0)
    assert sorted(lay.finger_index()) == [0, 1]


def test_corners_diagonal_baseline_across_fingers():
    lay = layouts.get_layout("2mic_corners")
    base = np.subtract(*lay.positions_xz())
    assert sorted(lay.finger_index()) == [0, 1]
    assert abs(base[0]) > 0.01 and abs(base[1]) > 0.01  # touches both axes


def test_same_finger_baseline_along_x_only():
    lay = layouts.get_layout("2mic_same_finger")
    base = np.subtract(*lay.positions_xz())
    assert set(lay.finger_index()) == {0}
    assert base[0] == pytest.approx(0.025) and base[1] == 0.0


def test_four_mics_two_per_finger_both_axes_each():
    lay = layouts.get_layout("4mic")
    xz, fing = lay.positions_xz(), lay.finger_index()
    for f in (0, 1):
        pair = xz[fing == f]
        assert len(pair) == 2
        base = pair[0] - pair[1]
        assert abs(base[0]) > 0.01 and abs(base[1]) > 0.01
    # Crossing diagonals: the two per-finger baselines are independent.
    b0 = xz[fing == 0][0] - xz[fing == 0][1]
    b1 = xz[fing == 1][0] - xz[fing == 1][1]
    assert abs(b0[0] * b1[1] - b0[1] * b1[0]) > 1e-4
    spacing = np.linalg.norm(b0)
    assert 0.02 < spacing < 0.03                         # about 25 mm within a pad


def test_positions_3d_put_fingers_at_half_width():
    lay = layouts.get_layout("4mic")
    p = lay.positions(0.06)
    assert np.allclose(p[lay.finger_index() == 0, 1], -0.03)
    assert np.allclose(p[lay.finger_index() == 1, 1], 0.03)
    with pytest.raises(ValueError, match="grasp_width_m"):
        lay.positions(0.0)


def test_objects_differ_and_lookups_fail_clearly():
    objs = [layouts.get_object(n) for n in ("pla_rod", "glass_cleaner", "chips_can",
                                            "mustard_container", "cracker_box")]
    for attr in ("roughness", "width_m", "mass_kg", "friction"):
        assert len({getattr(o, attr) for o in objs}) >= 4
    with pytest.raises(ValueError, match="unknown layout 'x'.*4mic"):
        layouts.get_layout("x")
    with pytest.raises(ValueError, match="unknown object"):
        layouts.get_object("banana")
    with pytest.raises(ValueError, match="unknown pad"):
        layouts.get_pad("bumpy")


def test_yaw_rotation_is_grasp_plane():
    r = layouts.yaw_rotation(0.3)
    assert np.allclose(r.T @ r, np.eye(3))
    assert np.allclose(np.cross(r[:, 2], r[:, 0]), r[:, 1])   # y = z x x
    q = layouts.yaw_quaternion(0.3)
    assert np.isclose(np.linalg.norm(q), 1.0)
