"""The closed-loop checks fail when the controller never commands the arm.

    launch_test test/launch/test_closed_loop_idle_launch.py        (or through pytest)

slip_stop.launch.py with ``autostart:=false``: the whole graph runs (slip estimates flow),
but the controller stays unconfigured and sends nothing. The checks the slip-stop and
slip-track launch tests rely on must then fail, and no result may appear.
"""

import os
import sys
import unittest

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import launch_case as lc  # noqa: E402

PROBE = {}


@pytest.mark.launch_test
@pytest.mark.skipif(lc.MISSING is not None, reason=str(lc.MISSING))
def generate_test_description():
    return lc.description("slip_stop.launch.py", {"autostart": "false"})


class TestIdleController(unittest.TestCase):
    """With the loop otherwise running, an idle controller fails the closed-loop checks."""

    def test_closed_loop_checks_fail_without_arm_commands(self, domain):
        probe = PROBE["probe"] = lc.Probe(domain, lc.closed_loop_topics())
        probe.wait_for(lambda: len(probe.messages("slip")) >= 300, 150.0,
                       "300 slip estimates")
        # 3 s more of the stream: slip_stop would have started its trial well within them
        # (test_slip_stop), counted in estimates so a slow machine waits longer.
        n = len(probe.messages("slip"))
        probe.wait_for(lambda: len(probe.messages("slip")) >= n + 300, 150.0,
                       "300 more slip estimates")
        with self.assertRaises(AssertionError):
            lc.assert_arm_commanded(probe)
        self.assertEqual(lc.moving_commands(probe), [])
        self.assertIsNone(lc.final_slip_stop_result(probe))
        status = probe.wait_for(lambda: lc.controller_status(probe, "slip_stop"), 10.0,
                                "slip_stop diagnostics")
        self.assertEqual(status[-1]["message"], "not active")


@lc.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    """Every node exits cleanly on SIGINT."""

    def test_exit_codes(self, proc_info, proc_output):
        try:
            lc.assert_clean_exit(proc_info, proc_output)
        finally:
            if "probe" in PROBE:
                PROBE["probe"].close()
