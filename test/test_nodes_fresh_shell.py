"""A node starts from a fresh shell that only sources install/setup.bash."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from node_support import node_exe

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
NODES = ("audio_capture", "mocap_bridge", "slip_inference", "slip_stop", "slip_track",
         "scene_sim")


def test_launchers_are_installed_and_executable():
    """`ros2 run aslip_ros <node>` needs every launcher to carry the executable bit."""
    missing = [node_exe(n) for n in NODES if not os.access(node_exe(n), os.X_OK)]
    assert not missing, f"not executable: {missing}"


def test_launch_files_compile():
    """Launch files cannot run here (no `launch`), but they must at least be valid Python."""
    import py_compile
    files = sorted((ROOT / "launch").glob("*.launch.py"))
    assert len(files) >= 5
    for f in files:
        py_compile.compile(str(f), doraise=True)


def test_node_starts_from_a_fresh_shell(ros_domain):
    exe = node_exe("scene_sim")
    launcher = f"'{exe}'" if os.access(exe, os.X_OK) else \
        f"\"$(head -1 '{exe}' | cut -c3-)\" '{exe}'"
    script = (f"cd '{ROOT}' && source install/setup.bash && "
              f"ROS_DOMAIN_ID={ros_domain} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "
              f"timeout -s INT 8 {launcher} --ros-args -p duration_s:=0.5 "
              "-p exit_when_done:=true")
    proc = subprocess.run(["env", "-i", f"HOME={os.environ.get('HOME', '/root')}",
                           "PATH=/usr/bin:/bin", "bash", "-c", script],
                          capture_output=True, text=True, timeout=60)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "ready" in out and "world stopped" in out, out
