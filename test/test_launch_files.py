"""Every launch file assembles the documented graph (runs without `launch` installed).

`launch` and `launch_ros` are not installable from PyPI, so the launch API is replaced by
recording stand-ins: each launch file's generate_launch_description() runs for real and the
test inspects what it asked for — which executables, with which parameters and config files,
which processes (`ros2 bag record`, `aslip export`) and which launch arguments. Where the
real launch_testing is available, test/launch/ runs the files end to end as well.
"""

from __future__ import annotations

import runpy
import sys
import types
from pathlib import Path

import pytest

from conftest import ROOT

pytestmark = pytest.mark.ros   # needs the colcon install (ament index, share/aslip_ros)


class Rec:
    """Records its constructor arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def _kind(name):
    return type(name, (Rec,), {})


@pytest.fixture
def fake_launch(monkeypatch):
    mods = {
        "launch": {"LaunchDescription": _kind("LaunchDescription")},
        "launch.actions": {"DeclareLaunchArgument": _kind("DeclareLaunchArgument"),
                           "ExecuteProcess": _kind("ExecuteProcess")},
        "launch.conditions": {"IfCondition": _kind("IfCondition"),
                              "UnlessCondition": _kind("UnlessCondition")},
        "launch.substitutions": {"LaunchConfiguration": _kind("LaunchConfiguration"),
                                 "PythonExpression": _kind("PythonExpression")},
        "launch_ros": {}, "launch_ros.actions": {"Node": _kind("Node")},
    }
    for name, attrs in mods.items():
        mod = types.ModuleType(name)
        for k, v in attrs.items():
            setattr(mod, k, v)
        monkeypatch.setitem(sys.modules, name, mod)
    monkeypatch.delitem(sys.modules, "aslip_ros.nodes.closed_loop_launch", raising=False)
    yield
    sys.modules.pop("aslip_ros.nodes.closed_loop_launch", None)


def _describe(name):
    ns = runpy.run_path(str(ROOT / "launch" / f"{name}.launch.py"))
    desc = ns["generate_launch_description"]()
    (entities,) = desc.args
    by = {}
    for e in entities:
        by.setdefault(type(e).__name__, []).append(e)
    return by


def _subst(v):
    """Plain value of a recorded LaunchConfiguration (its name) or a literal."""
    return f"<{v.args[0]}>" if type(v).__name__ == "LaunchConfiguration" else v


def _nodes(by):
    out = {}
    for n in by.get("Node", []):
        params = {}
        for p in n.kwargs.get("parameters", []):
            if isinstance(p, str):
                assert Path(p).is_file(), f"missing config file {p}"
                params.setdefault("_files", []).append(Path(p).name)
            else:
                params.update({k: _subst(v) for k, v in p.items()})
        out[n.kwargs["executable"]] = params
    return out


def _arguments(by):
    return {a.args[0] for a in by.get("DeclareLaunchArgument", [])}


@pytest.mark.parametrize("task,scenario,task_arg", [
    ("slip_stop", "wall_push", "direction"), ("slip_track", "drag", "gain")])
def test_closed_loop_launch_files(fake_launch, task, scenario, task_arg):
    by = _describe(task)
    nodes = _nodes(by)
    assert set(nodes) == {"scene_sim", "audio_capture", "slip_inference", "mocap_bridge",
                          task, "rviz2"}
    assert nodes["scene_sim"]["scenario"] == scenario
    assert nodes["slip_inference"]["checkpoint"] == "<checkpoint>"
    assert nodes[task][task_arg] == f"<{task_arg}>"
    assert nodes[task]["_files"] == [f"{task}.yaml"]
    assert nodes["mocap_bridge"]["finger_topic"] == "<finger_topic>"
    assert {"sim", "checkpoint", "xarm_ip", "audio_device", "finger_topic", "object_topic",
            "rviz", task_arg} <= _arguments(by)


def test_data_collection_records_the_documented_topics(fake_launch):
    by = _describe("data_collection")
    cmd = " ".join(str(_subst(a)) for p in by["ExecuteProcess"]
                   for a in p.kwargs.get("cmd", []))
    assert "bag record" in cmd and "mcap" in cmd
    for topic in ("/aslip/audio", "/aslip/mocap/finger", "/aslip/mocap/object",
                  "/aslip/robot/tcp_pose", "/aslip/metadata"):
        assert topic in cmd, topic
    assert {"scene_sim", "audio_capture", "mocap_bridge"} <= set(_nodes(by))


def test_export_and_rviz_launch_files(fake_launch):
    cmd = " ".join(str(_subst(a)) for p in _describe("export")["ExecuteProcess"]
                   for a in p.kwargs.get("cmd", []))
    assert "export" in cmd and "<bag>" in cmd
    rviz = _describe("rviz")["Node"][0]
    assert rviz.kwargs["executable"] == "rviz2"
    assert Path(rviz.kwargs["arguments"][-1]).name == "aslip.rviz"
    assert Path(rviz.kwargs["arguments"][-1]).is_file()
