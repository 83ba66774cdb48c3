"""A lab's cell file reaches the arm (issue #34, item 9): the acceleration limit is a cell
key that every node driving the arm turns into its limits, and the quickstart's arm check
takes the cell's address instead of overriding it with the example's."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_cells_acceleration_limit_is_every_arm_nodes_limit(tmp_path):
    from aslip_ros.cell import load_cell
    from aslip_ros.node_table import arm_nodes
    from aslip_ros.nodes.arms import limits
    from aslip_ros.nodes.introspect import declared_by_name
    path = tmp_path / "cell.yaml"
    path.write_text("arm:\n  xarm_ip: 10.0.0.7\n  arm_max_acc_m_s2: 0.4\n")
    cell = load_cell(str(path))
    for node in arm_nodes():
        declared = declared_by_name(node)
        values = {name: p.default for name, p in declared.items()}
        values.update(cell.params(node))
        assert limits(values).max_acc_m_s2 == pytest.approx(0.4), node
        check = declared["arm_max_acc_m_s2"].check
        assert check is not None and check(0.0) is not None     # a range, not anything


def test_the_quickstarts_arm_check_takes_the_cells_address():
    text = (ROOT / "docs" / "hardware-quickstart.md").read_text()
    lines = [ln.split("#")[0] for ln in text.splitlines()
             if re.match(r"\s*aslip check arm\b", ln)]
    assert lines, "the quickstart has no aslip check arm step"
    for line in lines:
        words = shlex.split(line)
        assert "--setup" in words, line
        assert "--ip" not in words, f"--ip overrides the cell's xarm_ip: {line}"
