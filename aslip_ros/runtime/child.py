"""A node executable in a child process: the one helper the tests, the benchmarks and the
fault experiments start nodes with (a stand-in for what ``ros2 launch`` does for users).

The child is the installed launcher (``<prefix>/lib/aslip_ros/<name>``, found on
AMENT_PREFIX_PATH) with ``--ros-args -p name:=value`` parameters, tied to this process
(``util.die_with_parent``), its merged output collected by a thread. No rclpy here.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from aslip_ros.util import die_with_parent


def node_exe(name: str) -> str:
    """The installed launcher of node ``name`` (``<prefix>/lib/aslip_ros/<name>``)."""
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        path = Path(prefix) / "lib" / "aslip_ros" / name
        if prefix and path.is_file():
            return str(path)
    raise FileNotFoundError(f"no installed executable {name}; run scripts/setup.sh and "
                            "source install/setup.bash")


def ros_args(params: dict) -> list:
    """``--ros-args -p k:=v ...`` with YAML-style values."""
    out = ["--ros-args"]
    for k, v in params.items():
        out += ["-p", f"{k}:={_yaml(v)}"]
    return out


def _yaml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v) if (v == "" or any(ch in v for ch in " :,[]{}#")) else v
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_yaml(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(float(v))
    return str(v)


class NodeProcess:
    """A node executable in a child process, its merged output collected by a thread.

    ``lines``: the output so far; ``ready``: an event set at the node's readiness line.
    """

    def __init__(self, name: str, env: dict, params: dict | None = None,
                 extra_args: list | None = None) -> None:
        exe = node_exe(name)
        # A launcher installed without its executable bit still runs through its own
        # interpreter; test_nodes_fresh_shell checks the bit separately.
        launcher = [exe] if os.access(exe, os.X_OK) else [sys.executable, exe]
        cmd = launcher + ros_args(params or {}) + list(extra_args or [])
        self.name = name
        self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, bufsize=1,
                                     preexec_fn=die_with_parent)
        self.lines: list[str] = []
        self.ready = threading.Event()
        self._cv = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            with self._cv:
                self.lines.append(line.rstrip("\n"))
                if "ready" in line:
                    self.ready.set()
                self._cv.notify_all()
        with self._cv:
            self._cv.notify_all()

    @property
    def output(self) -> str:
        """Everything the process printed so far."""
        with self._cv:
            return "\n".join(self.lines)

    def wait_for(self, text: str, timeout: float = 30.0) -> bool:
        """True once ``text`` appears in the output (False on timeout or exit)."""
        deadline = time.monotonic() + timeout
        with self._cv:
            while True:
                if any(text in ln for ln in self.lines):
                    return True
                if self.proc.poll() is not None and not self._reader.is_alive():
                    return False
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cv.wait(min(left, 0.2))

    def wait_ready(self, timeout: float = 45.0) -> None:
        """Wait for the node's readiness line; fail with its output otherwise."""
        if not self.wait_for("ready", timeout):
            out = self.stop()
            raise AssertionError(f"{self.name} did not become ready:\n{out}")

    def stop(self, sig=signal.SIGINT, timeout: float = 10.0) -> str:
        """Signal, wait, return the output (kill if it does not exit)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._reader.join(5)
        return self.output

    def __enter__(self) -> "NodeProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
