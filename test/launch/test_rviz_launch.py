"""rviz in the closed loop (slip_track.launch.py rviz:=true): what rviz shows is placeable.

    launch_test test/launch/test_rviz_launch.py        (or through pytest)

Checks what does not need a display: rviz2 is started where it is installed and, where it
is not, the graph runs on without it; every display of config/aslip.rviz gets messages
whose frames the graph's TF joins to the config's one Fixed Frame, so rviz can draw the
slip arrows beside the finger, object and TCP poses.
"""

import os
import sys
import unittest

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import launch_case as lc  # noqa: E402

TIMEOUT_S = 150.0
PROBE = {}


@pytest.mark.launch_test
@pytest.mark.skipif(lc.MISSING is not None, reason=str(lc.MISSING))
def generate_test_description():
    return lc.description("slip_track.launch.py",
                          {"rviz": "true", "input_timeout_s": lc.LOADED_INPUT_TIMEOUT_S})


class TestRvizView(unittest.TestCase):
    """The rviz configuration's displays are fed and joined by TF to its fixed frame."""

    def test_every_display_is_placed_in_the_fixed_frame(self, domain):
        fixed, displays = lc.rviz_config()
        probe = PROBE["probe"] = lc.Probe(domain, lc.rviz_topics(displays))
        for topic in displays:
            probe.wait_for(lambda: probe.messages(topic), TIMEOUT_S, f"message on {topic}")

        def unplaced() -> list:
            edges = lc.tf_edges(probe)
            return [(topic, frame) for topic in displays
                    for frame in lc.header_frames(probe.messages(topic))
                    if not lc.tf_connected(edges, frame, fixed)]
        # The static transforms come from two publishers (scene_sim, mocap_bridge), each
        # in its own time: wait for the tree to join every displayed frame.
        try:
            probe.wait_for(lambda: not unplaced(), TIMEOUT_S, "TF joining every display")
        except AssertionError:
            self.fail(f"frames not joined to the fixed frame {fixed!r} by TF: {unplaced()} "
                      f"(edges {sorted(lc.tf_edges(probe))})")
        # Still running, rviz or not: estimates keep coming.
        n = len(probe.messages("/aslip/slip_marker"))
        probe.wait_for(lambda: len(probe.messages("/aslip/slip_marker")) > n + 50, 30.0,
                       "50 more slip markers")


@lc.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    """rviz2 ran where installed; every process exited cleanly."""

    def test_rviz_runs_where_installed(self, proc_info):
        lc.assert_rviz_started_where_installed(proc_info)

    def test_exit_codes(self, proc_info, proc_output):
        try:
            lc.assert_clean_exit(proc_info, proc_output)
        finally:
            if "probe" in PROBE:
                PROBE["probe"].close()
