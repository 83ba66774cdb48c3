"""launch_testing test of launch/export.launch.py (skipped where launch_testing is missing).

Run with full ROS 2: `launch_test test/launch/test_export_launch.py` (or through pytest).
"""

import os
import unittest

import pytest

launch_testing = pytest.importorskip("launch_testing")
pytest.importorskip("launch_ros")

import launch  # noqa: E402
import launch_testing.actions  # noqa: E402
import launch_testing.asserts  # noqa: E402
from ament_index_python.packages import get_package_share_directory  # noqa: E402
from launch.launch_description_sources import PythonLaunchDescriptionSource  # noqa: E402


ARGS = {"bag": "/nonexistent_bag", "out": "/tmp/aslip_launch_test_ds"}


def generate_test_description():
    path = os.path.join(get_package_share_directory("aslip_ros"), "launch",
                        "export.launch.py")
    included = launch.actions.IncludeLaunchDescription(
        PythonLaunchDescriptionSource(path), launch_arguments=ARGS.items())
    return launch.LaunchDescription([included, launch_testing.actions.ReadyToTest()])


class TestExport(unittest.TestCase):
    """`aslip export` runs and explains a missing bag instead of crashing silently."""

    def test_reports_missing_bag(self, proc_output):
        proc_output.assertWaitFor("nonexistent_bag", timeout=60, stream="stderr")


@launch_testing.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    """Every process exits cleanly (SIGINT from launch: exit code 0, or -2)."""

    def test_exit_codes(self, proc_info):
        launch_testing.asserts.assertExitCodes(
            proc_info, allowable_exit_codes=[0, -2, 1 if "export" == "export" else 0])
