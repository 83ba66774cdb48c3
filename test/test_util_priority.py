"""Node processes run above ordinary CPU-bound work (util.raise_cpu_priority).

Beside two CPU-busy processes on 2 cores the stale-input watchdogs stopped closed-loop
trials without a fault at normal priority; the nodes now ask for nice -10 before any thread
starts, so every thread (DDS, executor, torch) inherits it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from aslip_ros import util

CAN_RAISE = os.geteuid() == 0


def _nice_in_child(code: str, env: dict | None = None) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, **(env or {})}, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


@pytest.mark.skipif(not CAN_RAISE, reason="raising CPU priority needs root or CAP_SYS_NICE")
def test_raises_the_priority_of_the_calling_process():
    got = _nice_in_child("import os; from aslip_ros.util import raise_cpu_priority as r; "
                         "print(r(-5), os.getpriority(os.PRIO_PROCESS, 0))")
    assert got == "None -5"


def test_env_overrides_and_zero_leaves_the_priority_alone():
    got = _nice_in_child("import os; from aslip_ros.util import raise_cpu_priority as r; "
                         "print(r(), os.getpriority(os.PRIO_PROCESS, 0))", {"ASLIP_NICE": "0"})
    assert got == "None 0"


def test_refusal_says_what_it_needs(monkeypatch):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "getpriority", lambda *_: 0)
    monkeypatch.setattr(os, "setpriority", refuse)
    why = util.raise_cpu_priority(-10)
    assert "CAP_SYS_NICE" in why and "RLIMIT_NICE of at least 30" in why


@pytest.mark.parametrize("raw", ["fast", "-40"])
def test_bad_setting_is_reported_not_raised(monkeypatch, raw):
    monkeypatch.setenv("ASLIP_NICE", raw)
    assert "[-20, 19]" in util.raise_cpu_priority()


def _thread_nices(pid: int) -> list:
    nices = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        stat = (task / "stat").read_text()
        nices.append(int(stat[stat.rindex(")") + 2:].split()[16]))   # field 19: nice
    return nices


@pytest.mark.ros
@pytest.mark.skipif(not CAN_RAISE, reason="raising CPU priority needs root or CAP_SYS_NICE")
@pytest.mark.parametrize("setting, expected", [(None, util.DEFAULT_NICE), ("0", 0)])
def test_node_process_and_all_its_threads_run_at_the_node_priority(ros_env, setting,
                                                                   expected):
    from node_support import NodeProcess
    env = dict(ros_env)
    env.pop("ASLIP_NICE", None)
    if setting is not None:
        env["ASLIP_NICE"] = setting
    with NodeProcess("mocap_bridge", env) as node:
        node.wait_ready()
        nices = _thread_nices(node.proc.pid)
    assert len(nices) > 3, nices              # DDS and executor threads, not just main
    assert set(nices) == {expected}, nices
