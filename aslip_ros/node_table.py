"""The node table: every node executable of the package, by name, in one place.

Each row names the executable, the module and class of its node, whether it drives the arm
(a cell file's ``arm`` section goes to it) and, for a controller, the checkpoint its
closed-loop launch uses when none is given. Everything that lists nodes derives from here:
CMakeLists.txt installs an executable per row (it runs this file at configure time:
``python aslip_ros/node_table.py`` prints the names), :mod:`aslip_ros.nodes.introspect`
reads their parameters, :mod:`aslip_ros.cell` gives the arm section to the arm nodes, and
:mod:`aslip_ros.launch_support.closed_loop` starts a controller with its default model.

A node outside the package (a controller of your own, docs/design.md "A new controller") is
made known with :func:`register` in the program that launches it (its launch file); it is
not installed, and its launch starts it through ``python -m aslip_ros.runtime.launcher
<module>``.

Pure data and the standard library: the launcher reads it before any other import, and
CMake runs it without the package on the path.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Tuple


@dataclass(frozen=True)
class NodeSpec:
    """One node executable.

    ``module`` holds ``node_class`` and a ``main()``; ``drives_arm``: a node that commands
    the arm (the cell's ``arm`` section is its too); ``cell``: a lab's cell file may have a
    section for it; ``default_model``: a controller's shipped checkpoint (a file in
    ``share/aslip_ros/models``, ``models/`` of the checkout), '' for none; ``config``: its
    parameter file in ``share/aslip_ros/config`` ('' for none); ``installed``: an
    executable in ``lib/aslip_ros`` (``ros2 run aslip_ros <name>``).
    """

    name: str
    module: str
    node_class: str
    drives_arm: bool = False
    cell: bool = True
    default_model: str = ""
    config: str = ""
    installed: bool = False


def _builtin(name: str, node_class: str, **kw) -> NodeSpec:
    return NodeSpec(name, f"aslip_ros.nodes.{name}", node_class, installed=True,
                    config=kw.pop("config", f"{name}.yaml"), **kw)


#: The package's default estimator, the one shipped checkpoint both closed-loop tasks run:
#: the hybrid of the streaming model and the 200 ms window CNN (learn/models/aslip_hybrid.py;
#: ``make demo``'s ``aslip``). In ``make demo`` (docs/results.md, "One estimator for both
#: tasks") it stops as the streaming model does (50/50) and tracks as the window CNN does,
#: where each of those two is worse at the other task; at 4x the robot's noise it still
#: stops 15/15 where the window CNN stops 6/15.
DEFAULT_MODEL = "aslip.pt"

#: The package's node executables.
BUILTIN: Tuple[NodeSpec, ...] = (
    _builtin("audio_capture", "AudioCapture"),
    _builtin("mocap_bridge", "MocapBridge"),
    _builtin("slip_inference", "SlipInference"),
    _builtin("slip_stop", "SlipStopNode", drives_arm=True, default_model=DEFAULT_MODEL),
    _builtin("slip_track", "SlipTrackNode", drives_arm=True, default_model=DEFAULT_MODEL),
    _builtin("scene_sim", "SceneSim", cell=False),
    _builtin("bag_recorder", "Recorder", cell=False, config=""),
    _builtin("robot_sweeps", "RobotSweeps", drives_arm=True),
    _builtin("stream_watch", "StreamWatchNode", config=""),
)

_registered: Dict[str, NodeSpec] = {}


def register(spec: NodeSpec) -> None:
    """Make ``spec`` known to this process (a node of your own, e.g. in its launch file).
    ValueError for a name the package uses or a spec marked installed."""
    if any(s.name == spec.name for s in BUILTIN):
        raise ValueError(f"{spec.name!r} is a node of the package")
    if spec.installed:
        raise ValueError(f"{spec.name}: a registered node is not installed (installed=False)")
    _registered[spec.name] = spec


def unregister(name: str) -> None:
    """Forget a node made known with :func:`register` (tests)."""
    _registered.pop(name, None)


def nodes() -> Dict[str, NodeSpec]:
    """Every known node, by name: the package's, then the registered ones."""
    out = {s.name: s for s in BUILTIN}
    out.update(_registered)
    return out


def spec(name: str) -> NodeSpec:
    """The row of node ``name``; KeyError naming the known ones."""
    try:
        return nodes()[name]
    except KeyError:
        raise KeyError(f"no node {name!r} (known: {', '.join(nodes())})") from None


def arm_nodes() -> Tuple[str, ...]:
    """The nodes that drive the arm."""
    return tuple(n for n, s in nodes().items() if s.drives_arm)


def controllers() -> Tuple[str, ...]:
    """The nodes a closed-loop launch can run: arm nodes with a default model."""
    return tuple(n for n, s in nodes().items() if s.drives_arm and s.default_model)


def cell_sections() -> Tuple[str, ...]:
    """The node sections a cell file may have."""
    return tuple(n for n, s in nodes().items() if s.cell)


if __name__ == "__main__":
    # CMakeLists.txt: the executables to install, separated by ';' (a CMake list).
    print(";".join(s.name for s in BUILTIN if s.installed), end="")
