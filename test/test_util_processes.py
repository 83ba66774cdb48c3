"""Child processes started with ``util.die_with_parent`` do not outlive their parent.

An orphaned node keeps publishing on a ROS domain that ``domain_coordinator`` then hands
to the next test; that made a whole test run fail once (a killed benchmark's nodes).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

PARENT = """
import subprocess, sys, time
from aslip_ros.util import die_with_parent
if sys.argv[1] == "hog":         # killed inside the block: the block's own cleanup never runs
    from aslip_ros.util import cpu_hogs
    with cpu_hogs(1) as hogs:
        print(hogs[0].pid, flush=True)
        time.sleep(60)
kw = {"preexec_fn": die_with_parent} if sys.argv[1] == "tied" else {}
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], **kw)
print(child.pid, flush=True)
time.sleep(60)
"""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state not in ("Z", "X")


def _orphan(mode: str) -> int:
    parent = subprocess.Popen([sys.executable, "-c", PARENT, mode], stdout=subprocess.PIPE,
                              text=True)
    pid = int(parent.stdout.readline())
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    return pid


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux only")
def test_a_tied_child_dies_with_its_parent_and_an_untied_one_does_not():
    tied, untied = _orphan("tied"), _orphan("untied")
    try:
        deadline = time.monotonic() + 5.0
        while _alive(tied) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(tied)
        assert _alive(untied)            # the control: without it the orphan lives on
    finally:
        for pid in (tied, untied):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux only")
def test_a_benchmarks_cpu_hog_dies_with_the_benchmark():
    """``make demo --hogs 2`` killed mid-run left its two ``yes`` hogs running (2026-11-29:
    the next ``make test`` ran beside them)."""
    hog = _orphan("hog")
    try:
        deadline = time.monotonic() + 5.0
        while _alive(hog) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(hog)
    finally:
        try:
            os.kill(hog, signal.SIGKILL)
        except ProcessLookupError:
            pass


def test_cpu_hogs_run_for_their_block_and_end_with_it():
    from aslip_ros.util import cpu_hogs
    with cpu_hogs(2) as hogs:
        assert len(hogs) == 2 and all(_alive(h.pid) for h in hogs)
    assert all(h.returncode is not None for h in hogs)
    with cpu_hogs(0) as none:
        assert none == []
