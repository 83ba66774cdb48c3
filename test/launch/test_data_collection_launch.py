"""launch/data_collection.launch.py: a finite simulated run is recorded and ends the launch.

    launch_test test/launch/test_data_collection_launch.py        (or through pytest)

With ``duration_s:=4`` and the package's own recorder (rosbag2 is not needed), the scene
must end by itself once it has run, and the recording leave a bag with every recorded
stream, TF included. That the launch then ends by itself is shown by
test/test_launch_files.py, which runs `ros2 launch` to its end.
"""

import os
import shutil
import sys
import unittest

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import launch_case as lc  # noqa: E402

OUT = lc.scratch_dir("aslip_launch_dc_")
BAG = os.path.join(OUT, "bag")


@pytest.mark.launch_test
@pytest.mark.skipif(lc.MISSING is not None, reason=str(lc.MISSING))
def generate_test_description():
    return lc.description("data_collection.launch.py",
                          {"duration_s": "4.0", "recorder": "aslip", "bag": BAG})


class TestCollection(unittest.TestCase):
    """The scene runs its duration and ends by itself; the launch then ends the recording.

    The active test waits for the scene's own exit, not the recorder's: the recorder stops
    only when the launch itself ends, and a test still waiting at that moment races
    launch_testing's check that the tests completed before the launch did."""

    def test_scene_ends_after_its_duration(self, proc_info):
        import launch_testing.asserts
        proc_info.assertWaitForShutdown(process="scene_sim", timeout=180)
        launch_testing.asserts.assertExitCodes(proc_info, process="scene_sim")


@lc.post_shutdown_test()
class TestBag(unittest.TestCase):
    """Clean exits, and a readable bag of every stream."""

    def test_exit_codes(self, proc_info, proc_output):
        lc.assert_clean_exit(proc_info, proc_output)

    def test_bag_holds_every_stream(self):
        from aslip_ros.data.bags import BagReader
        from aslip_ros.nodes.bag_recorder import RECORDED_TOPICS
        try:
            self.assertTrue(os.path.isdir(BAG), f"no bag at {BAG}")
            with BagReader(BAG) as reader:
                counts = dict(reader.info.counts)
                meta = reader.metadata
            print(f"bag topics: {counts}", flush=True)
            for topic in RECORDED_TOPICS:
                if topic == "/tf":       # dynamic TF: published only where something moves
                    continue
                self.assertGreater(counts.get(topic, 0), 0, topic)
            # Audio blocks are 10 ms: at least half of the recorded scene seconds.
            self.assertGreater(counts["/aslip/audio"], 150)
            self.assertEqual(meta["scenario"]["kind"] if isinstance(meta.get("scenario"), dict)
                             else meta.get("scenario"), "external_induced")
        finally:
            shutil.rmtree(OUT, ignore_errors=True)
