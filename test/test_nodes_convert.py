"""nodes/convert.py: messages <-> numpy, with validation (needs the built messages)."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytestmark = pytest.mark.ros


def test_audio_round_trip_is_frame_major():
    from aslip_ros.nodes import convert
    block = np.arange(12, dtype=np.float32).reshape(4, 3) / 100.0
    msg = convert.audio_to_msg(960, 1_500_000_000, 48000.0, ["a", "b", "c"], block, "3mic")
    assert list(msg.data[:3]) == pytest.approx([0.0, 0.01, 0.02])   # frame 0, channels 0..2
    back = convert.audio_from_msg(msg)
    np.testing.assert_array_equal(back.block, block)
    assert (back.first_sample_index, back.stamp_ns, back.sample_rate) == (960, 1_500_000_000,
                                                                          48000.0)
    assert back.channel_names == ["a", "b", "c"] and back.layout == "3mic"
    assert back.end_stamp_ns == 1_500_000_000 + round(4 / 48000.0 * 1e9)


@pytest.mark.parametrize("mutate, reason", [
    (lambda m: setattr(m, "channel_names", []), "no_channels"),
    (lambda m: setattr(m, "sample_rate", 0.0), "bad_rate"),
    (lambda m: setattr(m, "sample_rate", float("nan")), "bad_rate"),
    (lambda m: setattr(m, "data", []), "empty"),
    (lambda m: setattr(m, "data", [0.0] * 7), "ragged"),
    (lambda m: setattr(m, "data", [0.0, float("nan")] * 3), "non_finite"),
    (lambda m: setattr(m, "data", [0.0, float("inf")] * 3), "non_finite"),
    (lambda m: setattr(m, "data", [0.0, 1e30] * 3), "out_of_range"),
    (lambda m: setattr(m, "data", [0.0, -1.0001] * 3), "out_of_range"),
])
def test_audio_from_msg_refuses_malformed_frames(mutate, reason):
    from aslip_ros.nodes import convert
    msg = convert.audio_to_msg(0, 0, 48000.0, ["a", "b"], np.zeros((3, 2), np.float32))
    mutate(msg)
    with pytest.raises(convert.AudioFrameError) as err:
        convert.audio_from_msg(msg)
    assert err.value.reason == reason


def test_full_scale_samples_are_accepted():
    from aslip_ros.nodes import convert
    block = np.array([[1.0, -1.0], [0.5, 0.0]], np.float32)
    msg = convert.audio_to_msg(0, 0, 48000.0, ["a", "b"], block)
    np.testing.assert_array_equal(convert.audio_from_msg(msg).block, block)


def test_audio_to_msg_refuses_wrong_shapes():
    from aslip_ros.nodes import convert
    with pytest.raises(ValueError):
        convert.audio_to_msg(0, 0, 48000.0, ["a", "b"], np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError):
        convert.audio_to_msg(0, 0, -1.0, ["a"], np.zeros((3, 1), np.float32))


def test_prediction_to_slip_vector_and_zero_vector_when_not_slipping():
    from aslip_ros.learn.inference.predictor import Prediction
    from aslip_ros.nodes import convert
    pred = Prediction(0.9, True, 0.03, -0.04, 0.05, (0.6, -0.8), 0.2, threshold=0.8)
    msg = convert.prediction_to_slip(pred, 2_000_000_000, "aslip_cnn")
    assert msg.threshold == pytest.approx(0.8)      # the threshold it was decided at
    assert msg.slipping and msg.speed == pytest.approx(0.05)
    assert msg.direction == pytest.approx(math.atan2(-0.04, 0.03))
    assert msg.velocity.y == 0.0 and msg.header.frame_id == "aslip_grasp_plane"
    assert msg.window_length == pytest.approx(0.2)
    assert msg.direction_sigma == -1.0              # the prediction gives none
    sure = Prediction(0.9, True, 0.03, -0.04, 0.05, (0.6, -0.8), 0.2, 0.8, direction_sigma=0.3)
    assert convert.prediction_to_slip(sure, 0, "aslip_cnn").direction_sigma == \
        pytest.approx(0.3)
    quiet = convert.slip_to_msg(0.03, 0.01, 0.2, False, 0.5, 0, 0.2, "svm")
    assert (quiet.velocity.x, quiet.velocity.z, quiet.speed, quiet.direction) == (0, 0, 0, 0)


@pytest.mark.parametrize("field", ["probability", "vx", "vz", "window_length"])
def test_slip_vector_never_carries_nan(field):
    from aslip_ros.nodes import convert
    args = dict(vx=0.01, vz=0.0, probability=0.7, slipping=True, threshold=0.5, stamp_ns=0,
                window_length=0.1, source="x")
    args[field] = float("nan")
    with pytest.raises(ValueError):
        convert.slip_to_msg(**args)
    with pytest.raises(ValueError):
        convert.slip_to_msg(**{**args, field: 0.01, "probability": 1.5})


def test_slip_from_msg_rejects_nan():
    from aslip_ros.msg import SlipVector
    from aslip_ros.nodes import convert
    msg = SlipVector()
    msg.velocity.x = float("nan")
    with pytest.raises(ValueError):
        convert.slip_from_msg(msg)


def test_pose_round_trip_normalises_quaternion():
    from aslip_ros.nodes import convert
    msg = convert.pose_to_msg([1, 2, 3, 0, 0, 0, 2], 5, "world")
    stamp, frame, pose = convert.pose_from_msg(msg)
    assert (stamp, frame) == (5, "world")
    np.testing.assert_allclose(pose, [1, 2, 3, 0, 0, 0, 1])
    msg.pose.orientation.w = 0.0
    with pytest.raises(ValueError):
        convert.pose_from_msg(msg)


def test_twist_round_trip_and_nan_refused():
    from aslip_ros.nodes import convert
    msg = convert.twist_to_msg([0.01, -0.02, 0.0], 7)
    np.testing.assert_allclose(convert.twist_from_msg(msg), [0.01, -0.02, 0.0])
    assert msg.header.frame_id == "link_base"
    with pytest.raises(ValueError):
        convert.twist_to_msg([0.0, float("nan"), 0.0], 7)


def test_marker_arrow_follows_slip_and_color_follows_probability():
    from aslip_ros.nodes import convert
    slip = convert.slip_to_msg(0.02, 0.01, 0.9, True, 0.5, 0, 0.1, "aslip_cnn")
    arr = convert.slip_markers(slip, scale_s=10.0)
    arrow, dot, arc, head = arr.markers
    assert arc.action == head.action == arc.DELETE          # no rotation estimated
    assert arrow.action == arrow.ADD and arrow.header.frame_id == "aslip_grasp_plane"
    assert (arrow.points[1].x, arrow.points[1].z) == pytest.approx((0.2, 0.1))
    assert dot.color.r > dot.color.g                        # high probability: red
    calm = convert.slip_markers(convert.slip_to_msg(0, 0, 0.1, False, 0.5, 0, 0.1, "x"))
    assert calm.markers[0].action == calm.markers[0].DELETE
    assert calm.markers[1].color.g > calm.markers[1].color.r


@pytest.mark.parametrize("samples, reason", [
    ([0.0, float("nan")], None), ([float("-inf"), 0.5], None), ([1.0, -1.0], None),
    ([float("nan"), 1.5], "out_of_range"), ([-2.0, float("inf")], "out_of_range")])
def test_without_require_finite_only_finite_samples_are_range_checked(samples, reason):
    """A reader that keeps NaN/Inf (and names them itself) still gets the range check on
    the finite samples, however the block's extremes fall."""
    from aslip_ros.audio_frame import AudioFrameError, decode_audio_frame
    from aslip_ros.nodes import convert
    msg = convert.audio_to_msg(0, 0, 48000.0, ["a", "b"], np.zeros((2, 2), np.float32))
    msg.data = samples * 2
    if reason is None:
        assert decode_audio_frame(msg, require_finite=False).block.shape == (2, 2)
    else:
        with pytest.raises(AudioFrameError) as err:
            decode_audio_frame(msg, require_finite=False)
        assert err.value.reason == reason


def _fields(msg) -> tuple:
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id,
            msg.probability, msg.slipping, msg.threshold, msg.velocity.x, msg.velocity.y,
            msg.velocity.z, msg.speed, msg.direction, msg.direction_sigma,
            msg.angular_velocity, msg.angular_velocity_sigma, msg.window_length, msg.source)


def test_a_reused_slip_vector_keeps_nothing_of_the_estimate_before():
    """The inference node fills one message for every estimate: each fill equals a new
    message, and a refused estimate leaves the message as it was."""
    from aslip_ros.nodes import convert
    slipping = dict(vx=0.02, vz=-0.01, probability=0.9, slipping=True, threshold=0.5,
                    stamp_ns=3_200_000_000, window_length=0.2, source="aslip",
                    direction_sigma=0.3, angular_velocity=0.4, angular_sigma=0.1)
    quiet = dict(vx=0.03, vz=0.01, probability=0.2, slipping=False, threshold=0.5,
                 stamp_ns=3_210_000_000, window_length=0.0, source="aslip_stream",
                 frame_id="other_frame")
    msg = convert.slip_to_msg(**slipping)
    assert convert.slip_to_msg(**quiet, out=msg) is msg
    assert _fields(msg) == _fields(convert.slip_to_msg(**quiet))
    assert (msg.velocity.x, msg.speed, msg.direction_sigma) == (0.0, 0.0, -1.0)
    assert _fields(convert.slip_to_msg(**slipping, out=msg)) == \
        _fields(convert.slip_to_msg(**slipping))
    before = _fields(msg)
    for bad in ({"vz": float("inf")}, {"probability": 1.5}, {"stamp_ns": -1}):
        with pytest.raises(ValueError):
            convert.slip_to_msg(**{**quiet, **bad}, out=msg)
        assert _fields(msg) == before
