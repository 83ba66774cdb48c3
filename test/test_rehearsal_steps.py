"""The hardware rehearsal's step runner (test_hardware_rehearsal._run_on_rig), in one process:
a step that fails runs again only when its stand-in rig stalled, never otherwise."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from test_hardware_rehearsal import _run_on_rig

#: Fails on its first run and passes on the next: the marker file counts the runs.
FAILS_ONCE = 'if [ -e ran ]; then exit 0; fi; touch ran; mkdir -p bags/robot/probe_1; exit 1'
FAILS = "exit 1"


class FakeRig:
    def __init__(self, stalls: list) -> None:
        self._stalls = stalls
        self.stopped = False

    def stalls(self) -> list:
        return self._stalls

    def stop(self) -> None:
        self.stopped = True


def _starter(stalls: list):
    started: list = []

    def start(attempt: int) -> FakeRig:
        started.append(FakeRig(stalls))
        return started[-1]
    return start, started


def _env() -> dict:
    return {"PATH": os.environ["PATH"]}


def test_a_failure_without_a_rig_stall_fails_at_once(tmp_path: Path):
    start, started = _starter(stalls=[])
    with pytest.raises(AssertionError, match="step record-robot failed"):
        _run_on_rig("record-robot", FAILS_ONCE, _env(), tmp_path, start, timeout=30)
    assert len(started) == 1 and started[0].stopped


def test_a_failure_in_a_rig_stall_runs_once_more_on_a_new_rig_without_its_bags(
        tmp_path: Path, capsys):
    start, started = _starter(stalls=[{"event": "stall", "skipped_blocks": 80}])
    rig = _run_on_rig("record-robot", FAILS_ONCE, _env(), tmp_path, start, timeout=30)
    assert len(started) == 2 and rig is started[1]
    assert all(r.stopped for r in started)
    assert not (tmp_path / "bags" / "robot").exists()      # the failed run's bag is gone
    assert "the stand-in rig stalled" in capsys.readouterr().out


def test_a_second_failure_fails_even_in_a_rig_stall(tmp_path: Path):
    start, started = _starter(stalls=[{"event": "stall", "skipped_blocks": 80}])
    with pytest.raises(AssertionError, match="step slip-stop failed") as err:
        _run_on_rig("slip-stop", FAILS, _env(), tmp_path, start, timeout=30)
    assert len(started) == 2
    assert "stalled in this run too" in str(err.value) and "skipped_blocks" in str(err.value)
