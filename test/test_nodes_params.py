"""Parameter rules are declared where ROS tools look: the ParameterDescriptor.

``ros2 param describe`` and rqt read ranges and constraints from the node's
/describe_parameters service; each node's validators (aslip_ros/nodes/params.py) declare
them, so what is shown is what is enforced.
"""

from __future__ import annotations


import pytest

from conftest import ROOT
from node_support import Bus, NodeProcess

pytestmark = pytest.mark.ros


# ------------------------------------------------------------------ descriptor derivation

def test_descriptor_is_derived_from_the_rule():
    from aslip_ros.nodes import common as c
    d = c.descriptor(c.Param("w", 0.1, "window", c.in_range(0.005, 2.0), read_only=True))
    assert (d.description, d.read_only, d.additional_constraints) == (
        "window", True, "in [0.005, 2.0]")
    assert [(r.from_value, r.to_value, r.step) for r in d.floating_point_range] == [
        (0.005, 2.0, 0.0)]
    assert not d.integer_range

    d = c.descriptor(c.Param("n", 3, "count", c.int_range(1, 100)))
    assert [(r.from_value, r.to_value, r.step) for r in d.integer_range] == [(1, 100, 1)]
    assert not d.floating_point_range

    d = c.descriptor(c.Param("mode", "a", "mode", c.one_of("a", "b")))
    assert d.additional_constraints == "one of: a, b" and not d.floating_point_range

    # "-1 or [0, 1]": the declared range spans both; the rule text says which values count.
    rule = c.off_or(-1.0, c.in_range(0.0, 1.0), "the checkpoint's")
    d = c.descriptor(c.Param("threshold", -1.0, "p", rule))
    assert [(r.from_value, r.to_value) for r in d.floating_point_range] == [(-1.0, 1.0)]
    assert d.additional_constraints == "-1 (the checkpoint's) or in [0.0, 1.0]"
    assert rule(-0.5) == "must be -1 (the checkpoint's) or in [0.0, 1.0], got -0.5"
    assert rule(-1.0) is None and rule(0.5) is None

    # Half-open rules and plain callables declare no range.
    for check in (c.positive, c.non_negative, c.at_least(1.0), c.pose7, None,
                  lambda v: None):
        d = c.descriptor(c.Param("x", 1.0, "x", check))
        assert not d.floating_point_range and not d.integer_range
    assert c.descriptor(c.Param("x", 1.0, "x", c.positive)).additional_constraints == \
        "finite and > 0"


def test_validator_messages_are_unchanged():
    from aslip_ros.nodes import common as c
    assert c.in_range(0.005, 2.0)(5.0) == "must lie in [0.005, 2.0], got 5.0"
    assert c.positive(0.0) == "must be finite and > 0, got 0.0"
    assert c.non_negative(-1.0) == "must be finite and >= 0, got -1.0"
    assert c.one_of("a", "b")("c") == "must be one of ['a', 'b'], got 'c'"
    assert c.non_empty(" ") == "must be a non-empty string"
    assert c.pose7([0.0] * 7) == "has a zero quaternion"
    assert c.vector3()([0, 0, 0]) == "must not be the zero vector"
    assert c.int_range(1, 64)(65) == "must be in [1, 64]"
    assert c.at_least(1.0)(0.5) == "must be >= 1"


# ------------------------------------------------------------------ live nodes

def _describe(bus, node: str, names: list, timeout: float = 20.0) -> dict:
    from rcl_interfaces.srv import DescribeParameters
    res = bus.call(DescribeParameters, f"/{node}/describe_parameters",
                   DescribeParameters.Request(names=names), timeout)
    return {d.name: d for d in res.descriptors}


def _float_range(d) -> tuple:
    return tuple((r.from_value, r.to_value, r.step) for r in d.floating_point_range)


def _int_range(d) -> tuple:
    return tuple((r.from_value, r.to_value, r.step) for r in d.integer_range)


def test_nodes_declare_their_ranges_and_choices(rclpy_context, ros_env):
    """mocap_bridge, scene_sim and slip_stop answer /describe_parameters with the ranges
    and constraints their validators enforce; rclpy then refuses an out-of-range set
    itself, and the node's own check still refuses what the range cannot express."""
    bus = Bus(rclpy_context)
    with NodeProcess("mocap_bridge", ros_env) as bridge, \
            NodeProcess("scene_sim", ros_env) as scene, \
            NodeProcess("slip_stop", ros_env) as stop:
        for proc in (bridge, scene, stop):
            proc.wait_ready()
        d = _describe(bus, "mocap_bridge", ["window_s", "calibration", "epsilon_m_s",
                                            "grasp_plane_in_finger"])
        assert _float_range(d["window_s"]) == ((0.005, 2.0, 0.0),)
        assert d["calibration"].additional_constraints == "one of: param, metadata, measure"
        assert d["calibration"].read_only
        assert d["epsilon_m_s"].additional_constraints == "finite and >= 0"
        assert "quaternion" in d["grasp_plane_in_finger"].additional_constraints

        d = _describe(bus, "scene_sim", ["block_s", "command_timeout_s", "seed", "scenario"])
        assert _float_range(d["block_s"]) == ((0.001, 0.1, 0.0),)
        assert _float_range(d["command_timeout_s"]) == ((0.005, 1.0, 0.0),)
        assert d["seed"].additional_constraints == ">= 0" and not d["seed"].integer_range
        assert "wall_push" in d["scenario"].additional_constraints

        d = _describe(bus, "slip_stop", ["debounce_count", "slip_timeout_s", "time_margin",
                                         "start_after_messages"])
        assert _int_range(d["debounce_count"]) == ((1, 100, 1),)
        assert _int_range(d["start_after_messages"]) == ((1, 1000, 1),)
        assert _float_range(d["slip_timeout_s"]) == ((0.001, 1.0, 0.0),)
        assert d["time_margin"].additional_constraints == ">= 1"

        res = bus.set_params("mocap_bridge", {"window_s": 5.0})
        assert not res[0].successful and "out of range" in res[0].reason
        assert bus.set_params("mocap_bridge", {"window_s": 0.05})[0].successful
        res = bus.set_params("slip_stop", {"debounce_count": 0})
        assert not res[0].successful and "out of range" in res[0].reason
        res = bus.set_params("slip_stop", {"time_margin": 0.5})
        assert not res[0].successful and "time_margin: must be >= 1" in res[0].reason
    bus.close()


def test_out_of_range_start_value_is_refused_in_the_nodes_words(ros_env):
    """A start value outside the declared range stops the node with exit code 2 and the
    same message as every other invalid value, not an rclpy traceback."""
    proc = NodeProcess("mocap_bridge", ros_env, {"window_s": 5.0, "stale_timeout_s": -1.0})
    assert proc.proc.wait(30) == 2
    out = proc.stop()
    assert "window_s: must lie in [0.005, 2.0], got 5.0" in out
    assert "stale_timeout_s: must be finite and > 0" in out
    assert "Traceback" not in out


def test_a_node_takes_parameter_overrides_through_its_constructor(rclpy_context):
    """Composed in one process, a node gets its parameters as ``parameter_overrides`` (its
    ``**kwargs`` reach rclpy's Node), checked by the same declarations as from a launch."""
    from rclpy.parameter import Parameter

    from aslip_ros.runtime.process import ConfigError
    from aslip_ros.nodes.mocap_bridge import MocapBridge
    node = MocapBridge(context=rclpy_context,
                       parameter_overrides=[Parameter("rate_hz", value=50.0)])
    try:
        assert node.get_parameter("rate_hz").value == 50.0
    finally:
        node.destroy_node()
    with pytest.raises(ConfigError, match=r"rate_hz: must lie in \[1.0, 1000.0\]"):
        MocapBridge(context=rclpy_context,
                    parameter_overrides=[Parameter("rate_hz", value=5000.0)])


def test_audio_capture_names_its_default_microphones_as_the_shipped_models_do():
    """The default channel names are those the shipped checkpoints and the scene use (they
    were left_front, left_rear, ...: a default stream that every shipped model refused)."""
    from aslip_ros.learn.checkpoint import load_checkpoint
    from aslip_ros.nodes.introspect import declared_by_name
    names = declared_by_name("audio_capture")["channel_names"].default
    for model in ("aslip_cnn.pt", "svm.pt"):
        path = ROOT / "models" / model
        if path.is_file():
            assert load_checkpoint(path).channel_names == names, model
    import yaml
    cfg = yaml.safe_load((ROOT / "config" / "audio_capture.yaml").read_text())
    assert cfg["audio_capture"]["ros__parameters"]["channel_names"] == names
