"""The launch tests' "no moving arm command after the stop" check judges the commands by
their own stamps, not by when the probe's executor got round to them (a fresh clone's run
beside other work failed with "210 moving arm commands after the stop", every one of them
sent before the stop and taken from the probe's queue after the result)."""

from __future__ import annotations

import importlib.util
import json
import threading
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

LAUNCH_CASE = Path(__file__).resolve().parent / "launch" / "launch_case.py"


def _launch_case():
    spec = importlib.util.spec_from_file_location("launch_case_under_test", LAUNCH_CASE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class _Probe:
    """What assert_no_motion_after_stop reads of a Probe, filled by hand."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.received = {"cmd": [], "result": []}
        self.received_wall = {"cmd": [], "result": []}

    def messages(self, name: str) -> list:
        return list(self.received[name])

    def add(self, name: str, msg, receipt_ns: int) -> None:
        self.received[name].append((receipt_ns * 1e-9, msg))
        self.received_wall[name].append(receipt_ns)


def _twist(vx: float, stamp_ns: int):
    from geometry_msgs.msg import TwistStamped
    m = TwistStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    m.twist.linear.x = vx
    return m


def _result():
    from std_msgs.msg import String
    return String(data=json.dumps({"final": False, "reason": "slip"}))


def test_commands_sent_before_the_stop_but_taken_late_are_not_motion_after_it():
    lc = _launch_case()
    probe = _Probe()
    t_stop = 5 * 10**9
    probe.add("result", _result(), t_stop + 1_000_000)
    for k in range(210):           # a backlog sent before the stop, taken after the result
        probe.add("cmd", _twist(0.01, t_stop - (210 - k) * 10_000_000), t_stop + 2_000_000)
    lc.assert_no_motion_after_stop(probe)


def test_a_moving_command_sent_after_the_stop_fails_the_check():
    lc = _launch_case()
    probe = _Probe()
    t_stop = 5 * 10**9
    probe.add("result", _result(), t_stop + 1_000_000)
    probe.add("cmd", _twist(0.01, t_stop + 50_000_000), t_stop + 51_000_000)
    with pytest.raises(AssertionError, match="1 moving arm commands sent after the stop"):
        lc.assert_no_motion_after_stop(probe)


class _Exited:
    def __init__(self, name: str, code: int) -> None:
        self.process_name, self.returncode = name, code


class _Output:
    def __init__(self, text: bytes) -> None:
        self.text = text


def test_an_unclean_exit_names_the_process_its_code_and_its_last_output():
    lc = _launch_case()
    lc.assert_clean_exit([_Exited("scene_sim-1", 0), _Exited("aslip-2", -2)], {})
    output = {"slip_inference-3": [_Output(b"ready\n"), _Output(b"shutdown took over 4 s\n")]}
    with pytest.raises(AssertionError) as err:
        lc.assert_clean_exit([_Exited("scene_sim-1", 0), _Exited("slip_inference-3", 1)],
                             output)
    text = str(err.value)
    assert "slip_inference-3 (1)" in text and "scene_sim-1" not in text
    assert "shutdown took over 4 s" in text
