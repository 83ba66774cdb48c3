"""A lab's cell in one file: the microphones, the motion capture and the arm of one setup.

Every launch file takes it as ``cell:=PATH`` (config/cell_example.yaml is a template;
docs/hardware-quickstart.md, step 1). Sections are named after the node they configure and
their keys are that node's parameters (README, "Nodes reference"), so each value is checked
by the node's own declared range and no default is repeated here. ``arm`` holds what every
node that drives the arm must share (the limits, the connection and the grasp plane in the
TCP); it goes to every node of :mod:`aslip_ros.node_table` that drives the arm
(``slip_stop``, ``slip_track``, ``robot_sweeps``) alike, and a section of one of those may
not set it differently.

ROS-free: the launch files (through :mod:`aslip_ros.launch_support.common`, which also
checks the keys against what each node declares) and ``aslip check`` read it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional

import yaml

from aslip_ros import node_table

#: The keys of ``arm`` (its section goes to every node that drives the arm: the node table's
#: ``arm_nodes()``).
ARM_KEYS = ("arm", "xarm_ip", "arm_max_speed_m_s", "arm_max_acc_m_s2",
            "xarm_connect_timeout_s", "arm_workspace_min_m", "arm_workspace_max_m",
            "grasp_plane_in_tcp",
            "control_rate_hz", "command_duration_s")


def section_names() -> tuple:
    """The sections a cell file may have: the node table's ``cell_sections()`` and ``arm``."""
    return node_table.cell_sections() + ("arm",)


class CellError(ValueError):
    """The cell file is unreadable or does not describe a cell."""


@dataclass(frozen=True)
class Cell:
    """A loaded cell file (``path`` '' and no sections: no cell given)."""

    path: str = ""
    sections: Dict[str, Dict[str, Any]] = field(default_factory=dict)

    def section(self, name: str) -> Dict[str, Any]:
        """The keys of one section as written (empty when absent)."""
        return dict(self.sections.get(name, {}))

    def params(self, node: str) -> Dict[str, Any]:
        """The parameters the cell gives ``node`` (the ``arm`` section included for the
        nodes that drive the arm; ``channels`` follows ``channel_names``)."""
        out = self.section("arm") if node in node_table.arm_nodes() else {}
        out.update(self.section(node))
        if node == "audio_capture" and "channel_names" in out and "channels" not in out:
            out["channels"] = len(out["channel_names"])
        return out

    def get(self, node: str, key: str, default: Any = None) -> Any:
        """One parameter the cell gives ``node``, or ``default``."""
        return self.params(node).get(key, default)

    def recording_metadata(self) -> Dict[str, Any]:
        """What a recording must carry for export: the calibrations this cell uses."""
        out: Dict[str, Any] = {}
        finger = self.get("mocap_bridge", "grasp_plane_in_finger")
        tcp = self.section("arm").get("grasp_plane_in_tcp")
        if finger is not None:
            out["grasp_plane_in_finger"] = [float(x) for x in finger]
        if tcp is not None:
            out["grasp_plane_in_tcp"] = [float(x) for x in tcp]
        if self.path:
            out["cell"] = Path(self.path).stem
        return out


def _names(keys) -> str:
    return ", ".join(sorted(keys))


def load_cell(path: Optional[str]) -> Cell:
    """Read and check the structure of a cell file; '' or None is no cell (all defaults).

    Raises :class:`CellError` naming the file and the problem: not YAML, not a mapping, an
    unknown section, an ``arm`` key that is not one, or an arm-node section setting an
    ``arm`` key. Values are checked by the nodes (their ranges), not here.
    """
    if not path:
        return Cell()
    p = Path(path).expanduser()
    try:
        doc = yaml.safe_load(p.read_text())
    except OSError as exc:
        raise CellError(f"cell file {p}: cannot read it ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        raise CellError(f"cell file {p}: not YAML ({exc})") from None
    doc = {} if doc is None else doc
    if not isinstance(doc, dict):
        raise CellError(f"cell file {p}: must be a mapping of sections "
                        f"({_names(section_names())})")
    problems: List[str] = []
    known, arm_nodes = section_names(), node_table.arm_nodes()
    bodies: Dict[str, Dict[str, Any]] = {}
    for name, body in doc.items():
        if name not in known:
            problems.append(f"unknown section {name!r} (sections: {_names(known)})")
            continue
        body = {} if body is None else body
        if not isinstance(body, dict):
            problems.append(f"section {name!r} must be a mapping of parameter: value")
            continue
        if name == "arm":
            problems += [f"arm: unknown key {k!r} (arm keys: {_names(ARM_KEYS)})"
                         for k in body if k not in ARM_KEYS]
        elif name in arm_nodes:
            problems += [f"{name}: {k!r} belongs in the 'arm' section (every node that drives "
                         "the arm must use the same value)" for k in body if k in ARM_KEYS]
        bodies[name] = dict(body)
    if problems:
        raise CellError(f"cell file {p}: " + "; ".join(problems))
    return Cell(str(p), bodies)
