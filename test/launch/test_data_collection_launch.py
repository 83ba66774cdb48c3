"""launch_testing test of launch/data_collection.launch.py.

Skipped where launch_testing is missing.

Run with full ROS 2: `launch_test test/launch/test_data_collection_launch.py` (or through pytest).
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


ARGS = {"duration_s": "3.0", "record": "false"}


def generate_test_description():
    path = os.path.join(get_package_share_directory("aslip_ros"), "launch",
                        "data_collection.launch.py")
    included = launch.actions.IncludeLaunchDescription(
        PythonLaunchDescriptionSource(path), launch_arguments=ARGS.items())
    return launch.LaunchDescription([included, launch_testing.actions.ReadyToTest()])


class TestTopics(unittest.TestCase):
    """The launched graph publishes its documented output."""

    def test_output_topic(self):
        from launch_testing_ros import WaitForTopics

        from aslip_ros.msg import SlipVector
        with WaitForTopics([("/aslip/slip_truth", SlipVector)], timeout=30.0):
            pass


@launch_testing.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    """Every process exits cleanly (SIGINT from launch: exit code 0, or -2)."""

    def test_exit_codes(self, proc_info):
        launch_testing.asserts.assertExitCodes(
            proc_info, allowable_exit_codes=[0, -2, 1 if "data_collection" == "export" else 0])
