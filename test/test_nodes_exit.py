"""A node process exits even when its output pipes are broken.

``ros2 launch`` ends on SIGTERM without stopping its nodes; the nodes then get SIGTERM from
the kernel (tied to their parent) while their stdout and stderr lead nowhere. The forced
exit and the final flush must not fail on the broken pipe: they did, and a node stayed
running after its launch (``test_launch_files.py -k leaves_no_node_behind[SIGTERM]``, once
in a fresh-clone CI run).
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.ros

PRELUDE = ("import sys, time\n"
           "from aslip_ros.runtime import process\n"
           "time.sleep(1.0)                 # the parent closes our pipes meanwhile\n"
           "sys.stdout.write('x' * 100)     # buffered: the exit's flush meets the broken pipe\n")


def _run_with_broken_pipes(code: str, env) -> tuple[int, float]:
    # Buffered output, so the final flush has something to write into the broken pipe.
    env = {k: v for k, v in env.items() if k != "PYTHONUNBUFFERED"}
    proc = subprocess.Popen([sys.executable, "-c", PRELUDE + code], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    proc.stderr.close()
    t0 = time.monotonic()
    try:
        rc = proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)
        return None, time.monotonic() - t0
    return rc, time.monotonic() - t0


def test_the_final_exit_survives_a_broken_stdout(ros_env):
    rc, _ = _run_with_broken_pipes("process._leave(3)\n", ros_env)
    assert rc == 3


def test_the_forced_exit_survives_a_broken_stderr(ros_env):
    # A shutdown that hangs: only the forced exit can end the process.
    rc, took = _run_with_broken_pipes("process._exit_after(0.5, 'x')\ntime.sleep(120)\n",
                                      ros_env)
    assert rc == 0, f"the process did not exit by itself ({took:.0f} s)"


def test_every_thread_of_a_node_executable_leaves_the_signals_to_the_signal_thread(ros_env):
    """A node's threads, numpy's OpenBLAS thread among them, block SIGINT and SIGTERM, so a
    launch's signal always reaches the signal thread that arms the forced exit. (The
    executables once imported the node module first: the thread that ``import numpy``
    starts had an empty mask, and mocap_bridge ignored SIGINT and SIGTERM in CI.) The
    signal thread itself shows them open: the kernel unblocks them while it waits in
    ``sigwait``."""
    import signal

    from aslip_ros.runtime import process
    from node_support import NodeProcess
    with NodeProcess("mocap_bridge", ros_env) as node:
        node.wait_ready()
        pid = node.proc.pid
        threads = process.threads_receiving({signal.SIGINT, signal.SIGTERM}, str(pid))
        n_threads = len(list(__import__("pathlib").Path(f"/proc/{pid}/task").iterdir()))
        assert n_threads > 2
        signals = [t for t in threads if _thread_name(pid, t) == process.SIGNAL_THREAD]
        assert threads == signals and len(signals) == 1, \
            [(t, _thread_name(pid, t)) for t in threads]


def _thread_name(pid: int, tid: int) -> str:
    try:
        with open(f"/proc/{pid}/task/{tid}/comm") as f:
            return f.read().strip()
    except OSError:
        return ""


def _run_stuck_node(env, *args: str) -> tuple[int, str, float]:
    """Start test/helpers/stuck_node.py with ``args``, SIGINT it once ready; its exit code,
    output and the seconds from the signal to its exit."""
    import signal

    from conftest import HELPERS

    from aslip_ros.util import die_with_parent
    proc = subprocess.Popen([sys.executable, str(HELPERS / "stuck_node.py"), *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=die_with_parent)
    try:
        lines = []
        for line in proc.stdout:
            lines.append(line)
            if "ready" in line:
                break
        assert any("ready" in ln for ln in lines), "".join(lines)
        proc.send_signal(signal.SIGINT)
        t0 = time.monotonic()
        try:
            out, _ = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise AssertionError("the stuck node did not exit within 60 s of SIGINT")
        return proc.returncode, "".join(lines) + out, time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_a_shutdown_stuck_in_c_with_the_gil_still_exits_with_a_stack_dump(ros_env):
    """The forced exit is armed in C (faulthandler): a cleanup that holds the GIL, where the
    Python timer can never run, still ends the process, and the dump says where it hung.
    The node's own shutdown work (``before_shutdown``) did not finish: exit code 1."""
    from aslip_ros.runtime.process import C_EXIT_MARGIN_S, EXIT_GRACE_S
    rc, out, took = _run_stuck_node(ros_env)
    assert "before_shutdown: sleeping with the GIL held" in out, out
    assert rc == 1, out                            # faulthandler's exit, not the timer's 0
    assert "most recent call first" in out and "before_shutdown" in out, out
    assert took >= EXIT_GRACE_S, took
    assert took < EXIT_GRACE_S + C_EXIT_MARGIN_S + 30.0, took


@pytest.mark.parametrize("code", [0, 3])
def test_a_teardown_stuck_after_the_nodes_work_exits_with_the_nodes_code(ros_env, code):
    """Once ``before_shutdown`` is done, a hang in the middleware's teardown (CI: mocap_bridge
    held the GIL in ``destroy_node`` past the grace, exited 1 and failed a launch test) ends
    in the node's own exit code, with the stack dump still on stderr."""
    from aslip_ros.runtime.process import C_EXIT_MARGIN_S, EXIT_GRACE_S
    rc, out, took = _run_stuck_node(ros_env, "teardown", str(code))
    assert "before_shutdown: done" in out and "teardown: sleeping with the GIL held" in out, out
    assert rc == code, out
    assert "most recent call first" in out and "destroy_node" in out, out
    assert took >= EXIT_GRACE_S, took
    assert took < EXIT_GRACE_S + C_EXIT_MARGIN_S + 30.0, took


def test_a_teardown_waiting_with_the_gil_free_exits_with_the_nodes_code_and_names_the_step(
        ros_env):
    """The Python timer's exit, once the node's work is done: the node's code, and the line
    says which step of the shutdown hung."""
    from aslip_ros.runtime.process import EXIT_GRACE_S
    rc, out, took = _run_stuck_node(ros_env, "teardown_waits", "3")
    assert "teardown_waits: sleeping with the GIL free" in out, out
    assert rc == 3, out
    assert "shutdown took over" in out and "in destroy_node" in out, out
    assert took >= EXIT_GRACE_S, took


def test_a_slow_shutdown_says_where_its_time_went(ros_env):
    """A shutdown over ``SLOW_SHUTDOWN_S`` that still ends by itself writes one line with
    each step's seconds: where CI's launch logs showed nodes taking 2-4 s to exit, they did
    not say in which step."""
    import re
    rc, out, took = _run_stuck_node(ros_env, "teardown_slow")
    assert rc == 0, out
    line = next((ln for ln in out.splitlines() if "shutdown took" in ln), "")
    steps = {name: float(sec) for name, sec in
             re.findall(r"([\w.]+) (\d+\.\d+) s", line.partition(": ")[2])}
    assert set(steps) >= {"before_shutdown", "executor.shutdown", "destroy_node",
                          "rclpy.try_shutdown"}, out
    assert steps["destroy_node"] >= 1.5 and max(steps, key=steps.get) == "destroy_node", out
