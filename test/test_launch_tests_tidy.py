"""The launch tests leave nothing in the temporary directory: every process that imports one
(pytest's collection, launch_testing's runner) removes the scratch directory it made."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

LAUNCH_TESTS = Path(__file__).resolve().parent / "launch"


@pytest.mark.parametrize("name", ["test_data_collection_launch.py", "test_export_launch.py"])
def test_importing_a_launch_test_leaves_no_scratch_directory(tmp_path, name):
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    run = subprocess.run(
        [sys.executable, "-c", "import runpy, sys; runpy.run_path(sys.argv[1])",
         str(LAUNCH_TESTS / name)],
        env=dict(os.environ, TMPDIR=str(scratch)), capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    assert not list(scratch.iterdir()), sorted(p.name for p in scratch.iterdir())
