"""The `aslip` console command (issue #2): installed into the venv, --help works."""

import subprocess
import sys
from pathlib import Path

from aslip_ros import cli


def test_help_lists_subcommands():
    parser = cli.build_parser()
    text = parser.format_help()
    for name in ("simulate", "export", "train", "evaluate", "demo"):
        assert name in text


def test_console_script_runs():
    exe = Path(sys.executable).with_name("aslip")
    assert exe.exists(), "make setup installs the `aslip` command into the venv"
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "usage: aslip" in out.stdout


def test_unknown_subcommand_is_an_error():
    out = subprocess.run([sys.executable, "-m", "aslip_ros.cli", "nonsense"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode != 0
    assert "invalid choice" in out.stderr
