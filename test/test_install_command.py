"""colcon installs the `aslip` command (the finding: only setup.py declared it, and colcon does
not run setup.py for an ament_cmake package, so a workspace had no `aslip` on PATH)."""

from __future__ import annotations

import os
import subprocess

import pytest

from conftest import ROOT

pytestmark = pytest.mark.ros


def test_the_colcon_install_has_the_aslip_command_on_its_path():
    out = subprocess.run(
        ["bash", "-c", f"source {ROOT}/install/setup.bash && cd / && command -v aslip && "
         "aslip --help"],
        env={k: v for k, v in os.environ.items() if k not in ("PATH",)} | {
            "PATH": "/usr/bin:/bin"}, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    where, _, help_text = out.stdout.partition("\n")
    assert where == str(ROOT / "install" / "bin" / "aslip")
    for command in ("export", "train", "evaluate", "check"):
        assert command in help_text
