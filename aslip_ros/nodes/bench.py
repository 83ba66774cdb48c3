"""Benchmarks of the live node graph (latency, rates, CPU), run by ``make bench``.

``measure_node_latency``: ``audio_capture`` (simulated scene, 4 channels at 48 kHz) and
``slip_inference`` run as separate processes, exactly as ``ros2 run`` starts them, on an
isolated ROS domain. A listener in this process timestamps every ``AudioFrame`` and every
``SlipVector`` on arrival; a SlipVector is stamped with the end of its window, which is
the end of the AudioFrame that completed the window, so the two arrivals pair up and their
difference is the end-to-end latency "AudioFrame received -> SlipVector published" plus
one DDS hop on each side (which cancel to first order). The node's own measurement of the
same interval comes from its diagnostics. CPU use is read from ``/proc/<pid>/stat``.

``measure_capture_stream``: ``audio_capture`` alone for ``duration_s`` (10 minutes in
``make bench``), every block's ``first_sample_index`` checked for continuity on loopback,
and the capture latency: from the acquisition of a block's last sample (its stamp plus its
duration) to its arrival here, one DDS hop included.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from aslip_ros import topics
from aslip_ros.nodes.process import NodeProcess

_CLK_TCK = os.sysconf("SC_CLK_TCK")


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _CLK_TCK  # utime + stime


def _env(domain: int) -> dict:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    return env


def _listen(domain: int, duration_s: float, want_slip: bool, on_start=None) -> dict:
    """Collect arrival times of audio, slip and diagnostics for ``duration_s``."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from std_msgs.msg import String

    from aslip_ros.msg import AudioFrame, SlipVector

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("aslip_bench_listener", context=ctx)
    audio_end: dict[int, float] = {}
    indices: list[tuple[int, int]] = []
    ages: list[float] = []
    slips: list[tuple[int, float]] = []
    diags: list[dict] = []

    def on_audio(msg):
        now = time.perf_counter()
        frames = len(msg.data) // max(1, len(msg.channel_names))
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        end_ns = stamp + int(round(frames / msg.sample_rate * 1e9))
        audio_end[end_ns] = now
        ages.append(time.time() - end_ns * 1e-9)
        indices.append((int(msg.first_sample_index), frames))

    node.create_subscription(AudioFrame, topics.AUDIO, on_audio,
                             QoSProfile(depth=1000,
                                        reliability=qos_profile_sensor_data.reliability))
    if want_slip:
        rel = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(
            SlipVector, topics.SLIP,
            lambda m: slips.append((m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                                    time.perf_counter())), rel)
        node.create_subscription(String, topics.DIAGNOSTICS_JSON,
                                 lambda m: diags.append(json.loads(m.data)), rel)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    t_end = None
    try:
        while True:
            ex.spin_once(timeout_sec=0.05)
            if t_end is None and indices and (slips or not want_slip):
                t_end = time.monotonic() + duration_s
                if on_start:
                    on_start()
            if t_end is not None and time.monotonic() > t_end:
                break
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return {"audio_end": audio_end, "indices": indices, "slips": slips, "diags": diags,
            "ages": ages}


def _capture_latency(ages: list[float]) -> dict:
    """p50 / p99 / max of block ages on arrival [ms] (None without blocks)."""
    a = np.asarray(ages, dtype=float) * 1e3
    if not a.size:
        return {"capture_latency_p50_ms": None, "capture_latency_p99_ms": None,
                "capture_latency_max_ms": None}
    return {"capture_latency_p50_ms": float(np.percentile(a, 50)),
            "capture_latency_p99_ms": float(np.percentile(a, 99)),
            "capture_latency_max_ms": float(a.max())}


def _dropped_blocks(indices: list[tuple[int, int]]) -> int:
    """Blocks missing between the first and last received block (index continuity)."""
    if not indices:
        return 0
    idx = np.array(sorted(indices))
    gaps = idx[1:, 0] - (idx[:-1, 0] + idx[:-1, 1])
    block = int(np.median(idx[:, 1]))
    return int(np.sum(np.maximum(gaps, 0)) // max(block, 1))


def measure_node_latency(checkpoint: str, duration_s: float = 30.0,
                         warmup_s: float = 3.0) -> dict:
    """End-to-end latency and CPU of ``slip_inference`` on a live 4 ch 48 kHz stream."""
    from domain_coordinator import domain_id

    with domain_id() as dom:
        env = _env(dom)
        capture = NodeProcess("audio_capture", env, {"source": "sim"})
        infer = NodeProcess("slip_inference", env, {"checkpoint": str(checkpoint)})
        cpu0: list[float] = []
        try:
            for n in (capture, infer):
                if not n.ready.wait(120):
                    raise RuntimeError("node did not start:\n" + "\n".join(n.lines[-20:]))
            time.sleep(warmup_s)
            t0 = [0.0]

            def start():
                t0[0] = time.perf_counter()
                cpu0.append(_cpu_seconds(infer.proc.pid))
            got = _listen(dom, duration_s, want_slip=True, on_start=start)
            cpu = (_cpu_seconds(infer.proc.pid) - cpu0[0]) / (time.perf_counter() - t0[0])
        finally:
            infer.stop()
            capture.stop()
    lat = []
    keys = np.array(sorted(got["audio_end"]), dtype=np.int64)
    for stamp, t_slip in got["slips"]:
        j = np.searchsorted(keys, stamp)
        best = min((k for k in (j - 1, j) if 0 <= k < keys.size),
                   key=lambda k: abs(int(keys[k]) - stamp), default=None)
        if best is not None and abs(int(keys[best]) - stamp) < 500_000:
            lat.append(t_slip - got["audio_end"][int(keys[best])])
    lat_ms = np.array(lat) * 1e3
    internal = [d["values"] for d in got["diags"]
                if "latency_p99_ms" in d.get("values", {})]
    n_slip = len(got["slips"])
    return {
        "duration_s": duration_s, "checkpoint": str(checkpoint),
        "slip_rate_hz": n_slip / duration_s, "paired": int(lat_ms.size),
        "latency_p50_ms": float(np.percentile(lat_ms, 50)) if lat_ms.size else None,
        "latency_p99_ms": float(np.percentile(lat_ms, 99)) if lat_ms.size else None,
        "latency_max_ms": float(lat_ms.max()) if lat_ms.size else None,
        "node_reported_p99_ms": internal[-1]["latency_p99_ms"] if internal else None,
        "slip_inference_cpu_cores": float(cpu),
        "audio_blocks_dropped": _dropped_blocks(got["indices"]),
        "load_average": list(os.getloadavg()),
    }


def measure_capture_stream(duration_s: float = 600.0) -> dict:
    """``audio_capture`` (sim source, 4 ch 48 kHz, 10 ms blocks) for ``duration_s``:
    blocks received on loopback and blocks missing from the index sequence."""
    from domain_coordinator import domain_id

    with domain_id() as dom:
        env = _env(dom)
        capture = NodeProcess("audio_capture", env, {"source": "sim"})
        try:
            if not capture.ready.wait(120):
                raise RuntimeError("audio_capture did not start:\n"
                                   + "\n".join(capture.lines[-20:]))
            got = _listen(dom, duration_s, want_slip=False)
        finally:
            capture.stop()
    blocks = len(got["indices"])
    frames = sum(f for _, f in got["indices"])
    return {"duration_s": duration_s, "blocks_received": blocks,
            "audio_s_received": frames / 48000.0,
            "blocks_dropped": _dropped_blocks(got["indices"]),
            **_capture_latency(got["ages"]),
            "load_average": list(os.getloadavg())}


def measure(checkpoint: str | None = None, latency_s: float = 30.0,
            stream_s: float = 600.0) -> dict:
    """Both node benchmarks (the entry point ``make bench`` looks for)."""
    if checkpoint is None:
        checkpoint = str(Path(__file__).resolve().parents[2] / "models" / "aslip_cnn.pt")
    return {"slip_inference": measure_node_latency(checkpoint, latency_s),
            "audio_capture": measure_capture_stream(stream_s)}


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--latency-s", type=float, default=30.0)
    ap.add_argument("--stream-s", type=float, default=600.0)
    a = ap.parse_args()
    print(json.dumps(measure(a.checkpoint, a.latency_s, a.stream_s), indent=2))
