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
           "from aslip_ros.nodes import common\n"
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
    rc, _ = _run_with_broken_pipes("common._leave(3)\n", ros_env)
    assert rc == 3


def test_the_forced_exit_survives_a_broken_stderr(ros_env):
    # A shutdown that hangs: only the forced exit can end the process.
    rc, took = _run_with_broken_pipes("common._exit_after(0.5, 'x')\ntime.sleep(120)\n",
                                      ros_env)
    assert rc == 0, f"the process did not exit by itself ({took:.0f} s)"
