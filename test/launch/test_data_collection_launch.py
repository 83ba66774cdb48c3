"""launch/data_collection.launch.py: a finite simulated run is recorded and ends the launch.

    launch_test test/launch/test_data_collection_launch.py        (or through pytest)

With ``duration_s:=4`` and the package's own recorder (rosbag2 is not needed), the launch
must end by itself once the scene has run, and leave a bag with every recorded stream,
TF included.
"""

import os
import shutil
import sys
import tempfile
import unittest

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import launch_case as lc  # noqa: E402

OUT = tempfile.mkdtemp(prefix="aslip_launch_dc_")
BAG = os.path.join(OUT, "bag")


@pytest.mark.launch_test
@pytest.mark.skipif(lc.MISSING is not None, reason=str(lc.MISSING))
def generate_test_description():
    return lc.description("data_collection.launch.py",
                          {"duration_s": "4.0", "recorder": "aslip", "bag": BAG})


class TestCollection(unittest.TestCase):
    """The launch ends by itself when the scene's duration has run."""

    def test_launch_ends_after_the_scene_run(self, proc_info):
        # Only the launch's shutdown stops the recorder: its exit shows the launch ended.
        proc_info.assertWaitForShutdown(process="bag_recorder", timeout=180)


@lc.post_shutdown_test()
class TestBag(unittest.TestCase):
    """Clean exits, and a readable bag of every stream."""

    def test_exit_codes(self, proc_info):
        lc.assert_clean_exit(proc_info)

    def test_bag_holds_every_stream(self):
        from aslip_ros.data.bags import BagReader
        from aslip_ros.nodes.bag_recorder import DEFAULT_TOPICS
        try:
            self.assertTrue(os.path.isdir(BAG), f"no bag at {BAG}")
            with BagReader(BAG) as reader:
                counts = dict(reader.info.counts)
                meta = reader.metadata
            print(f"bag topics: {counts}", flush=True)
            for topic in DEFAULT_TOPICS:
                if topic == "/tf":       # dynamic TF: published only where something moves
                    continue
                self.assertGreater(counts.get(topic, 0), 0, topic)
            # Audio blocks are 10 ms: at least half of the recorded scene seconds.
            self.assertGreater(counts["/aslip/audio"], 150)
            self.assertEqual(meta["scenario"]["kind"] if isinstance(meta.get("scenario"), dict)
                             else meta.get("scenario"), "external_induced")
        finally:
            shutil.rmtree(OUT, ignore_errors=True)
