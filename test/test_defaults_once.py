"""Each default is written once, in the core (issue #24, "Each default once").

A node's parameter that sets a field of its core's config dataclass declares that field's
default (``nodes/params.py``: ``from_config``), so the node, the core and the demo cannot
disagree (slip_track's node once ran a 0.3 s hold and a position term while its core
defaulted to 0.2 s and none). A shipped config file (config/<node>.yaml) may restate a
default, never change it. Read without starting ROS (:mod:`aslip_ros.nodes.introspect`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from conftest import ROOT

pytestmark = pytest.mark.ros   # the node modules import the built messages

#: Where a node's default differs from its core's on purpose, and why.
INTENTIONAL = {
    ("slip_stop", "direction"): "0 0 0 = take the push direction from the scene's metadata",
    ("scene_sim", "wall_distance_m"): "0 = the object starts in contact with the wall",
    ("scene_sim", "duration_s"): "0 = a live scene runs until shut down (a trial: 30 s)",
    ("audio_capture", "sim.wall_distance_m"): "as scene_sim's",
    ("scene_sim", "pivot_lever_m"): "read by the pivot scenario only, which needs a lever "
                                    "(Scenario's 0 = the wall push that slides)",
    ("audio_capture", "sim.pivot_lever_m"): "as scene_sim's",
}
#: Core fields that no parameter sets (the node keeps the core's default).
NOT_PARAMETERS = {"SweepConfig": {"max_acc_m_s2"}}


def _cores() -> dict:
    """Executable -> [(core config dataclass, parameter-name prefix, every field a
    parameter)]: the prefixed fields are the node's parameters."""
    from aslip_ros.control.limits import ArmLimits
    from aslip_ros.control.slip_stop import SlipStopConfig
    from aslip_ros.control.slip_track import SlipTrackConfig
    from aslip_ros.control.sweeps import SweepConfig
    from aslip_ros.data.stream_watch import WatchConfig
    from aslip_ros.hw.xarm_config import XArmConfig
    from aslip_ros.scene.scenario import Scenario
    arm = [(ArmLimits, "arm_", False), (XArmConfig, "xarm_", False)]
    return {
        "slip_stop": [(SlipStopConfig, "", True)] + arm,
        "slip_track": [(SlipTrackConfig, "", True)] + arm,
        "robot_sweeps": [(SweepConfig, "", True), (SweepConfig, "arm_", True)] + arm,
        "scene_sim": [(Scenario, "", False)],
        "audio_capture": [(Scenario, "sim.", False)],
        "stream_watch": [(WatchConfig, "", True)],
    }


def _defaults(config) -> dict:
    """{field: default as a parameter value} of the fields that have one."""
    from aslip_ros.nodes.params import config_default
    return {f.name: config_default(config, f.name) for f in dataclasses.fields(config)
            if f.default is not dataclasses.MISSING
            or f.default_factory is not dataclasses.MISSING}


@pytest.mark.parametrize("executable", ["slip_stop", "slip_track", "robot_sweeps",
                                        "scene_sim", "audio_capture", "stream_watch"])
def test_every_parameter_of_a_core_field_declares_the_cores_default(executable):
    from aslip_ros.nodes.introspect import declared_by_name
    declared = declared_by_name(executable)
    wrong, reached, complete = [], set(), set()
    for config, prefix, every_field in _cores()[executable]:
        if every_field:
            complete.add(config)
        for field, default in _defaults(config).items():
            spec = declared.get(prefix + field)
            if spec is None:
                continue
            reached.add((config, field))
            if (executable, spec.name) in INTENTIONAL:
                assert spec.default != default, f"{spec.name}: no longer differs; drop it"
                continue
            if spec.default != default or type(spec.default) is not type(default):
                wrong.append(f"{spec.name}: node {spec.default!r}, "
                             f"{config.__name__}.{field} {default!r}")
    assert not wrong, wrong
    # The node's own core: every field is a parameter (a new field gets one, or a reason).
    unset = [f"{config.__name__}.{field}" for config in complete for field in _defaults(config)
             if (config, field) not in reached
             and field not in NOT_PARAMETERS.get(config.__name__, set())]
    assert not unset, f"{executable}: no parameter sets {unset}"


def test_a_float_field_defaults_to_a_float():
    """ROS types a parameter by its default: an int default of a float field would make
    the node refuse ``0.5`` (and a YAML ``1.0`` where it expects ``1``)."""
    bad = []
    for cores in _cores().values():
        for config, _, _ in cores:
            for f in dataclasses.fields(config):
                default = _defaults(config).get(f.name)
                if f.type in ("float", float) and default is not None and \
                        not isinstance(default, float):
                    bad.append(f"{config.__name__}.{f.name} = {default!r}")
    assert not bad, bad


def test_module_level_defaults_are_the_cores():
    """Nodes whose core has constants rather than a dataclass."""
    from aslip_ros.control.command import DEFAULT_DURATION_S
    from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S
    from aslip_ros.data import labels
    from aslip_ros.nodes.introspect import declared_by_name
    from aslip_ros.scene.layouts import DEFAULT_LAYOUT, LAYOUTS
    bridge = declared_by_name("mocap_bridge")
    assert bridge["window_s"].default == labels.DEFAULT_WINDOW_S
    assert bridge["epsilon_m_s"].default == labels.DEFAULT_EPSILON_M_S
    assert bridge["max_gap_s"].default == labels.DEFAULT_MAX_GAP_S
    capture = declared_by_name("audio_capture")
    assert capture["layout"].default == DEFAULT_LAYOUT
    assert capture["channel_names"].default == LAYOUTS[DEFAULT_LAYOUT].channel_names
    for node in ("slip_stop", "slip_track", "robot_sweeps"):
        declared = declared_by_name(node)
        assert declared["pose_timeout_s"].default == DEFAULT_TIMEOUT_S
        assert declared["command_duration_s"].default == DEFAULT_DURATION_S


def _node_files() -> list:
    return sorted(p for p in (ROOT / "config").glob("*.yaml") if p.name != "cell_example.yaml")


def _flat(section: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in section.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


@pytest.mark.parametrize("path", _node_files(), ids=lambda p: p.name)
def test_a_config_file_restates_defaults_never_changes_them(path: Path):
    from aslip_ros.nodes.introspect import declared_by_name
    doc = yaml.safe_load(path.read_text())
    assert list(doc) == [path.stem], f"{path.name}: one section, named after its node"
    declared = declared_by_name(path.stem)
    values = _flat(doc[path.stem]["ros__parameters"])
    unknown = sorted(set(values) - set(declared))
    assert not unknown, f"{path.name}: not parameters of {path.stem}: {unknown}"
    wrong = [f"{k}: {v!r} (default {declared[k].default!r})" for k, v in values.items()
             if v != declared[k].default or type(v) is not type(declared[k].default)]
    assert not wrong, f"{path.name} changes defaults (set them in a cell file): {wrong}"


def test_the_arm_section_of_a_cell_is_every_arm_nodes_parameters():
    from aslip_ros.cell import ARM_KEYS
    from aslip_ros.node_table import arm_nodes
    from aslip_ros.nodes.introspect import declared_by_name
    for node in arm_nodes():
        assert set(ARM_KEYS) <= set(declared_by_name(node)), node
    assert not [k for k in ARM_KEYS if k.startswith("xarm_") and "ip" not in k
                and "connect" not in k], "the limits are every arm's: arm_*, not xarm_*"


def test_the_demo_runs_the_nodes_slip_track_law():
    from aslip_ros.control.slip_track import SlipTrackConfig
    from benchmarks.demo_episode import TrackSettings
    law = TrackSettings().law()
    assert law and all(law[k] == getattr(SlipTrackConfig, k) for k in law), law


def test_one_layout_registry():
    from aslip_ros.scene.layouts import DEFAULT_LAYOUT, LAYOUTS, PAPER_LAYOUTS
    assert sorted(PAPER_LAYOUTS) == sorted(LAYOUTS) and PAPER_LAYOUTS[0] == DEFAULT_LAYOUT


def test_synthetic_bags_name_the_scenes_default_layout():
    """data/ does not import the scene, so data/synthetic.py writes the name itself."""
    from aslip_ros.data.synthetic import DEFAULT_LAYOUT as SYNTHETIC
    from aslip_ros.scene.layouts import DEFAULT_LAYOUT
    assert SYNTHETIC == DEFAULT_LAYOUT
