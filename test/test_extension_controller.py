"""A controller added in test code runs through a launch (docs/design.md, "A new controller").

test/helpers/fake_controller.py is the whole controller: its law, its node on the
controllers' shell and its row of the node table. A launch file of the test's own
registers the row and calls the package's closed-loop description; nothing of the package
changes. What the package derives from the node table follows: the cell's arm section goes
to it, its parameters are checked like a built-in node's, and its default model is the one
slip_inference loads.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from conftest import HELPERS, ROOT

pytestmark = pytest.mark.ros

LAUNCH = f"""
import sys
sys.path.insert(0, {str(HELPERS)!r})
from fake_controller import ROW
from aslip_ros import node_table
from aslip_ros.launch_support.closed_loop import closed_loop_description


def generate_launch_description():
    node_table.register(ROW)
    return closed_loop_description("test_creep", scenario="wall_push", task_arg="speed_m_s",
                                   task_help="creep speed [m/s]")
"""

CELL = "arm:\n  arm_max_speed_m_s: 0.04\n"


@pytest.fixture
def registered(monkeypatch):
    monkeypatch.syspath_prepend(str(HELPERS))
    from aslip_ros import node_table
    from fake_controller import ROW
    node_table.register(ROW)
    yield ROW
    node_table.unregister(ROW.name)


def test_the_package_lists_are_the_node_tables():
    from aslip_ros import node_table
    from aslip_ros.runtime.child import node_exe
    rows = {s.name for s in node_table.BUILTIN if s.installed}
    installed = {p.name for p in Path(node_exe("slip_stop")).parent.iterdir()}
    assert installed == rows, "CMake installs one executable per row"
    out = subprocess.run([sys.executable, "-I", str(ROOT / "aslip_ros/node_table.py")],
                         capture_output=True, text=True, check=True).stdout
    assert set(out.split(";")) == rows
    assert set(node_table.controllers()) == {"slip_stop", "slip_track"}
    assert set(node_table.arm_nodes()) == {"slip_stop", "slip_track", "robot_sweeps"}


def test_a_registered_controller_gets_the_cells_arm_section(registered, tmp_path):
    from aslip_ros import node_table
    from aslip_ros.cell import load_cell
    from aslip_ros.nodes.introspect import declared_by_name
    assert registered.name in node_table.controllers()
    path = tmp_path / "cell.yaml"
    path.write_text(CELL + "test_creep:\n  speed_m_s: 0.01\n")
    cell = load_cell(str(path))
    assert cell.params("test_creep") == {"arm_max_speed_m_s": 0.04, "speed_m_s": 0.01}
    assert {"speed_m_s", "direction", "arm_max_speed_m_s"} <= set(declared_by_name("test_creep"))
    with pytest.raises(ValueError, match="belongs in the 'arm' section"):
        path.write_text("test_creep:\n  arm_max_speed_m_s: 0.01\n")
        load_cell(str(path))


def test_a_registered_controller_is_refused_a_package_name():
    from aslip_ros import node_table
    with pytest.raises(ValueError, match="node of the package"):
        node_table.register(node_table.spec("slip_stop").__class__(
            "slip_stop", "x", "X"))


#: What launch printed when its own SIGINT race ended it with 1 (see the test below).
LAUNCH_RACE = "Task was destroyed but it is pending!"


class _Output:
    """A child's merged output, read by a thread; :meth:`wait_for` waits on its lines."""

    def __init__(self, proc) -> None:
        self.lines: list = []
        self._cv = threading.Condition()
        self._proc = proc
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self._proc.stdout:
            with self._cv:
                self.lines.append(line)
                self._cv.notify_all()
        with self._cv:
            self.lines.append(None)
            self._cv.notify_all()

    def wait_for(self, *texts: str, timeout: float) -> bool:
        with self._cv:
            return self._cv.wait_for(
                lambda: all(any(ln and t in ln for ln in self.lines) for t in texts)
                or None in self.lines, timeout) and \
                all(any(ln and t in ln for ln in self.lines) for t in texts)

    def wait_end(self, timeout: float) -> bool:
        """Whether the whole output has been read (the child closed it) within ``timeout``."""
        with self._cv:
            return self._cv.wait_for(lambda: None in self.lines, timeout)

    @property
    def text(self) -> str:
        with self._cv:
            return "".join(ln for ln in self.lines if ln)


@pytest.mark.slow
def test_a_controller_from_test_code_runs_through_its_launch(ros_env, tmp_path):
    """ros2 launch of the test's launch file: the scene, slip_inference on the row's default
    model, mocap_bridge and the test controller, which creeps the simulated arm with the
    cell's speed limit; on SIGINT every node exits cleanly."""
    from shutil import which
    ros2 = which("ros2", path=ros_env.get("PATH"))
    if ros2 is None:
        pytest.skip("`ros2` is not on PATH")
    launch = tmp_path / "creep.launch.py"
    launch.write_text(LAUNCH)
    cell = tmp_path / "cell.yaml"
    cell.write_text(CELL)
    proc = subprocess.Popen([ros2, "launch", str(launch), f"cell:={cell}"], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    out = _Output(proc)
    try:
        assert out.wait_for("svm model", "creeping with arm sim, at most 0.04 m/s",
                            timeout=120), out.text[-4000:]
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=60)
        # The output read to its end: launch writes its last lines just before it exits.
        assert out.wait_end(timeout=10), out.text[-4000:]
        assert out.text.count("process has finished cleanly") == 4, out.text[-4000:]
        assert "process has died" not in out.text, out.text[-4000:]
        # launch's own exit status: 0, but for one race of launch itself (CI, 2026-11-30, on
        # 337b625): a SIGINT that lands while launch handles an event of a child's output
        # left its pending event task destroyed, and launch exited 1 with every node
        # finished cleanly and no error of its own. Where the 1 comes from: run_async
        # installs an asyncio exception handler that sets its return code to 1 on any call,
        # and asyncio calls it with "Task was destroyed but it is pending!" when a pending
        # task is garbage-collected (launch_service.py, _on_exception; not logged as a launch
        # error). That signature alone is let through.
        assert code == 0 or (code == 1 and LAUNCH_RACE in out.text
                             and "[ERROR]" not in out.text), out.text[-4000:]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
