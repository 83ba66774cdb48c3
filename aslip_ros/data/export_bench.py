"""Export speed and memory, measured on a synthetic bag in a child ``aslip export`` process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def measure_export_speed(duration_s: float = 60.0, sample_rate: float = 48000.0,
                         n_channels: int = 4, workdir: str | os.PathLike | None = None
                         ) -> dict:
    """Export a synthetic bag in a child process; report speed against real time and peak RSS.

    The child is a fresh ``aslip export`` process, so ``peak_rss_mib`` is the export's own
    peak resident memory (interpreter and imports included), not this process's.
    """
    from aslip_ros.data.synthetic import write_synthetic_bag
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        bag = Path(tmp) / "bench_bag"
        names = [f"ch{k}" for k in range(n_channels)]
        write_synthetic_bag(bag, duration_s=duration_s, sample_rate=sample_rate,
                            channel_names=names, slip_velocity=(0.01, 0.0, 0.005))
        summary_path = Path(tmp) / "summary.json"
        cmd = [sys.executable, "-m", "aslip_ros.cli", "export", str(bag), "-o",
               str(Path(tmp) / "ds"), "--no-progress", "--summary-json", str(summary_path)]
        t = time.perf_counter()
        with open(Path(tmp) / "stderr.txt", "w+") as err:
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
            # wait4 gives this child's own peak RSS; RUSAGE_CHILDREN would report the
            # largest child this process ever waited for (a training job, a node...).
            _, status, usage = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            wall = time.perf_counter() - t
            if proc.returncode:
                err.seek(0)
                raise RuntimeError(f"benchmark export failed: {err.read().strip()}")
        summary = json.loads(summary_path.read_text())
        # The child's own address space (VmHWM); ru_maxrss of a child that Python started
        # with vfork holds this process's peak too (a test process that trained a model).
        peak_mib = summary.get("peak_rss_mib") or usage.ru_maxrss / 1024
        bag_mib = sum(f.stat().st_size for f in bag.iterdir()) / 2**20
    return {
        "audio_s": summary["audio_s"], "sample_rate": sample_rate, "n_channels": n_channels,
        "bag_mib": round(bag_mib, 1),
        "export_s": round(summary["elapsed_s"], 3),
        "realtime_factor": round(summary["realtime_factor"], 1),
        "process_wall_s": round(wall, 3),
        "realtime_factor_with_startup": round(summary["audio_s"] / wall, 1),
        "peak_rss_mib": round(peak_mib, 1),
        "windows": summary["kept"],
        "command": " ".join(cmd[:4] + ["<bag>", "-o", "<dataset>"]),
    }
