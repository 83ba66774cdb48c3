"""launch/export.launch.py: a recorded bag becomes a windowed dataset.

    launch_test test/launch/test_export_launch.py        (or through pytest)

A 3 s simulated bag is written first (the project's own writer); the launch must run
`aslip export` on it to the end and leave a dataset of its windows.
"""

import os
import shutil
import sys
import unittest
from pathlib import Path

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import launch_case as lc  # noqa: E402

OUT = Path(lc.scratch_dir("aslip_launch_export_"))


@pytest.mark.launch_test
@pytest.mark.skipif(lc.MISSING is not None, reason=str(lc.MISSING))
def generate_test_description():
    from aslip_ros.scene.simulate import simulate
    summary = simulate(OUT / "bags", "external", duration_s=3.0, progress=False)
    assert summary["bags"], summary
    return lc.description("export.launch.py", {"bag": OUT / "bags", "out": OUT / "ds",
                                               "window": "0.2", "hop": "0.1"},
                          keep_alive=True)


class TestExport(unittest.TestCase):
    """The export runs to its end."""

    def test_export_finishes(self, proc_info):
        proc_info.assertWaitForShutdown(process="aslip_export", timeout=240)


@lc.post_shutdown_test()
class TestDataset(unittest.TestCase):
    """`aslip export` succeeded and wrote the dataset."""

    def test_exit_codes(self, proc_info, proc_output):
        lc.assert_clean_exit(proc_info, proc_output)

    def test_dataset_written(self):
        try:
            files = sorted(p.name for p in (OUT / "ds").rglob("*") if p.is_file())
            print(f"dataset files: {files}", flush=True)
            self.assertIn("manifest.json", files, f"no dataset at {OUT / 'ds'}")
            self.assertIn("windows.npy", files)
        finally:
            shutil.rmtree(OUT, ignore_errors=True)
