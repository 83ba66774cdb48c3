"""launch_testing test of launch/rviz.launch.py (skipped where launch_testing is missing).

Run with full ROS 2: `launch_test test/launch/test_rviz_launch.py` (or through pytest).
Needs rviz2 and a display.
"""

import os
import shutil
import unittest

import pytest

launch_testing = pytest.importorskip("launch_testing")
pytest.importorskip("launch_ros")

import launch  # noqa: E402
import launch_testing.actions  # noqa: E402
import launch_testing.asserts  # noqa: E402
from ament_index_python.packages import get_package_share_directory  # noqa: E402
from launch.launch_description_sources import PythonLaunchDescriptionSource  # noqa: E402


if shutil.which("rviz2") is None or not os.environ.get("DISPLAY"):
    pytest.skip("rviz2 or a display is missing", allow_module_level=True)

ARGS = {}


def generate_test_description():
    path = os.path.join(get_package_share_directory("aslip_ros"), "launch",
                        "rviz.launch.py")
    included = launch.actions.IncludeLaunchDescription(
        PythonLaunchDescriptionSource(path), launch_arguments=ARGS.items())
    return launch.LaunchDescription([included, launch_testing.actions.ReadyToTest()])


class TestRviz(unittest.TestCase):
    """rviz starts with the A-SLIP configuration."""

    def test_starts(self, proc_info):
        import time
        time.sleep(5.0)


@launch_testing.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    """Every process exits cleanly (SIGINT from launch: exit code 0, or -2)."""

    def test_exit_codes(self, proc_info):
        launch_testing.asserts.assertExitCodes(
            proc_info, allowable_exit_codes=[0, -2, 1 if "rviz" == "export" else 0])
