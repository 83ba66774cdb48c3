"""A node's start pays only for what it runs.

Every test that starts a node, and every lab's launch, waits for the node's imports. On a
2-core machine torch costs about 3 s, scipy.signal (with the scipy.stats it imports) 1.3-1.8 s
and scipy.spatial about half a second of each start. Only slip_inference runs a model, and
its features need none of scipy.signal at the usual rates (integer decimation); the scene's
filters are scene_sim's. The nodes that read no pose (stream_watch, bag_recorder) need no
rotations. Each set of modules is
imported together in one fresh interpreter: what none of them loads together, none loads
alone.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from aslip_ros import node_table

pytestmark = pytest.mark.ros

#: The nodes that read no pose.
POSELESS = ("stream_watch", "bag_recorder")


def _loaded(modules: list[str], heavy: tuple[str, ...], env: dict) -> list[str]:
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + f"print(' '.join(m for m in {heavy!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-P", "-c", code], env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.split()


def test_only_the_inference_node_imports_torch_or_the_scenes_filters(ros_env):
    modules = [s.module for s in node_table.BUILTIN if s.name != "slip_inference"]
    assert len(modules) == len(node_table.BUILTIN) - 1
    assert _loaded(modules, ("torch", "scipy.signal", "sklearn", "matplotlib"), ros_env) == []


def test_the_inference_node_imports_neither_scipy_signal_nor_scipy_stats(ros_env):
    """slip_inference is the node tests and launches start most; scipy.signal is loaded only
    for a rational resampling ratio (features.LogMel), when a stream needs one."""
    module = node_table.spec("slip_inference").module
    assert _loaded([module], ("scipy.signal", "scipy.stats", "sklearn"), ros_env) == []


def test_the_nodes_that_read_no_pose_import_no_rotations(ros_env):
    modules = [node_table.spec(n).module for n in POSELESS]
    assert _loaded(modules, ("scipy.spatial", "torch", "scipy.signal"), ros_env) == []
