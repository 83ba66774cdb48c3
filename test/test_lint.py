"""Lint as ament does: flake8 at 99 columns over the package, benchmarks, tests, launch files."""

import subprocess
import sys

from conftest import ROOT


def test_flake8_clean():
    out = subprocess.run([sys.executable, "-m", "flake8", "--max-line-length", "99",
                          "aslip_ros", "benchmarks", "test", "launch", "scripts"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
