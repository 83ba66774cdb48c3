"""nodes/convert.py and rotational slip (issue #21): the SlipVector's angular velocity, its
sigma, and the rviz arc beside the planar arrow (needs the built messages)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from aslip_ros.slip import ROTATION_EPSILON_RAD_S

pytestmark = pytest.mark.ros


def msg(w, slipping=False, p=0.2, sigma=-1.0, vx=0.0, vz=0.0):
    from aslip_ros.nodes import convert
    return convert.slip_to_msg(vx, vz, p, slipping, 0.5, 10**9, 0.2, "aslip_cnn",
                               angular_velocity=w, angular_sigma=sigma)


def test_angular_velocity_is_published_whatever_the_planar_decision():
    from aslip_ros.nodes import convert
    m = msg(1.3, sigma=0.2)                  # pure rotation: not slipping (planar)
    assert not m.slipping and m.speed == 0.0
    assert m.angular_velocity == pytest.approx(1.3)
    assert m.angular_velocity_sigma == pytest.approx(0.2)
    m = msg(-0.7, slipping=True, p=0.9, vx=0.02)
    assert m.slipping and m.angular_velocity == pytest.approx(-0.7)
    assert m.angular_velocity_sigma == -1.0
    # Defaults: "not estimated" (0, sigma -1); any negative sigma reads "none".
    plain = convert.slip_to_msg(0.02, 0.0, 0.9, True, 0.5, 0, 0.2, "svm")
    assert (plain.angular_velocity, plain.angular_velocity_sigma) == (0.0, -1.0)
    assert msg(0.1, sigma=-3.0).angular_velocity_sigma == -1.0


@pytest.mark.parametrize("field", ["angular_velocity", "angular_sigma"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_rotation_is_refused(field, bad):
    from aslip_ros.nodes import convert
    args = dict(vx=0.0, vz=0.0, probability=0.1, slipping=False, threshold=0.5, stamp_ns=0,
                window_length=0.2, source="x", angular_velocity=0.5, angular_sigma=0.1)
    args[field] = bad
    with pytest.raises(ValueError, match=field):
        convert.slip_to_msg(**args)


def test_prediction_to_slip_carries_the_rotation():
    from aslip_ros.learn.inference.predictor import Prediction
    from aslip_ros.nodes import convert
    pred = Prediction(0.1, False, 0.0, 0.0, 0.0, (0.0, 0.0), 0.2, threshold=0.6,
                      angular_velocity=-2.0, angular_sigma=0.4)
    m = convert.prediction_to_slip(pred, 0, "aslip_cnn")
    assert not m.slipping and m.angular_velocity == pytest.approx(-2.0)
    assert m.angular_velocity_sigma == pytest.approx(0.4)
    # A prediction object without the rotational fields (an older model's): not estimated.
    old = SimpleNamespace(probability=0.9, slipping=True, vx=0.01, vz=0.0, window_length=0.2,
                          threshold=0.5, direction_sigma=0.1)
    m = convert.prediction_to_slip(old, 0, "svm")
    assert (m.angular_velocity, m.angular_velocity_sigma) == (0.0, -1.0)


def test_slip_from_msg_decodes_and_checks_the_rotation():
    from aslip_ros.nodes import convert
    d = convert.slip_from_msg(msg(0.9, sigma=0.05))
    assert d.angular_velocity == pytest.approx(0.9) and d.angular_sigma == pytest.approx(0.05)
    assert not d.slipping
    for field in ("angular_velocity", "angular_velocity_sigma"):
        m = msg(0.9)
        setattr(m, field, math.nan)
        with pytest.raises(ValueError, match="non-finite"):
            convert.slip_from_msg(m)
    # SlipData built without the rotation (older callers): none.
    d = convert.SlipData(0, 0.01, 0.0, True, 0.9)
    assert (d.angular_velocity, d.angular_sigma) == (0.0, -1.0)


def _arc(w, scale_s=0.5, **kw):
    from aslip_ros.nodes import convert
    m = msg(w, **kw)
    markers = convert.slip_markers(m, scale_s=scale_s, arc_radius_m=0.02)
    assert [x.id for x in markers.markers] == [0, 1, 2, 3]
    return markers.markers


@pytest.mark.parametrize("w", [1.2, -3.0])
def test_rotation_arc_sweeps_the_angle_turned_in_scale_seconds(w):
    from visualization_msgs.msg import Marker
    arrow, dot, arc, head = _arc(w, scale_s=0.5)
    assert arc.type == Marker.LINE_STRIP and arc.action == Marker.ADD
    assert head.type == Marker.ARROW and head.action == Marker.ADD
    assert arc.header.frame_id == "aslip_grasp_plane"
    sweep = w * 0.5
    first, last = arc.points[0], arc.points[-1]
    assert (first.x, first.y, first.z) == pytest.approx((0.0, 0.0, 0.02))   # top of the pad
    # A turn by s about +y carries the top (0, 0, r) to r (sin s, 0, cos s).
    assert (last.x, last.z) == pytest.approx((0.02 * math.sin(sweep), 0.02 * math.cos(sweep)))
    assert all(abs(math.hypot(p.x, p.z) - 0.02) < 1e-9 and p.y == 0.0 for p in arc.points)
    # The head points along the turn at the arc's end.
    tail, tip = head.points
    tangent = (math.cos(sweep), -math.sin(sweep))
    d = (tip.x - tail.x, tip.z - tail.z)
    assert (d[0] * tangent[0] + d[1] * tangent[1]) * math.copysign(1.0, w) > 0
    # Colored like the arrow and the dot (by the slip probability).
    assert arc.color == dot.color == head.color


def test_no_arc_below_the_rotation_threshold_and_never_a_full_turn():
    from visualization_msgs.msg import Marker
    for w in (0.0, ROTATION_EPSILON_RAD_S, -0.9 * ROTATION_EPSILON_RAD_S):
        _, _, arc, head = _arc(w)
        assert arc.action == head.action == Marker.DELETE
    _, _, arc, _ = _arc(100.0, scale_s=2.0)
    last = arc.points[-1]
    swept = math.atan2(last.x, last.z) % (2 * math.pi)
    assert swept == pytest.approx(1.9 * math.pi)
