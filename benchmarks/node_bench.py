"""Benchmarks of the live node graph (latency, rates, CPU), run by ``make bench``.

``measure_node_latency``: ``audio_capture`` (simulated scene, 4 channels at 48 kHz) and
``slip_inference`` run as separate processes, exactly as ``ros2 run`` starts them, on an
isolated ROS domain. A listener in this process timestamps every ``AudioFrame`` and every
``SlipVector`` on arrival (the middleware's reception time, so the listener's own executor
delays stay out; the callback's clock where the middleware gives none). Each SlipVector is
paired with the AudioFrame that completed it (``pair_estimates``): a window model stamps
its estimate with the end of its window, the end of that block; a streaming model stamps
each 10 ms hop with its last sample, inside that block. The difference of the two arrivals
is the end-to-end latency "AudioFrame received -> SlipVector published" plus one DDS hop
on each side (which cancel to first order); p50, p99, p99.9 and max are reported. The
node's own figures (end-to-end and per step of the live path: queue, features and
calibration, model forward, publish) come from its last diagnostics message. CPU use is
read from ``/proc/<pid>/stat``.

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
from aslip_ros.runtime.child import NodeProcess

_CLK_TCK = os.sysconf("SC_CLK_TCK")


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _CLK_TCK  # utime + stime


def _env(domain: int) -> dict:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    return env


def _arrival_ns(info) -> int:
    """The middleware's reception time of a message [ns, system clock], else now."""
    rx = info.get("received_timestamp", 0) if isinstance(info, dict) else 0
    return int(rx) if rx else time.time_ns()


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
    blocks: list[tuple[int, int, int]] = []      # start, end [ns of stamp], arrival [ns]
    indices: list[tuple[int, int]] = []
    ages: list[float] = []
    slips: list[tuple[int, int]] = []             # stamp [ns], arrival [ns]
    diags: list[dict] = []

    def on_audio(msg, info):
        now = _arrival_ns(info)
        frames = len(msg.data) // max(1, len(msg.channel_names))
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        # The node's AudioData.end_stamp_ns, to the nanosecond.
        end_ns = stamp + int(round(frames * 1e9 / msg.sample_rate))
        blocks.append((stamp, end_ns, now))
        ages.append(time.time() - end_ns * 1e-9)
        indices.append((int(msg.first_sample_index), frames))

    def on_slip(msg, info):
        slips.append((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec,
                      _arrival_ns(info)))

    node.create_subscription(AudioFrame, topics.AUDIO, on_audio,
                             QoSProfile(depth=1000,
                                        reliability=qos_profile_sensor_data.reliability))
    if want_slip:
        rel = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(SlipVector, topics.SLIP, on_slip, rel)
        node.create_subscription(String, topics.DIAGNOSTICS_JSON,
                                 lambda m: diags.append(json.loads(m.data)), rel)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    t_end = None
    give_up = time.monotonic() + 60.0        # a node that died must not hang the bench
    try:
        while True:
            ex.spin_once(timeout_sec=0.05)
            if t_end is None and time.monotonic() > give_up:
                raise RuntimeError(f"nothing to measure within 60 s: {len(indices)} "
                                   f"AudioFrames, {len(slips)} SlipVectors")
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
    return {"blocks": blocks, "indices": indices, "slips": slips, "diags": diags,
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


def pair_estimates(block_starts_ns, block_ends_ns, stamps_ns) -> np.ndarray:
    """For each estimate stamp, the index of the block that completed it, -1 for none.

    The block that completed an estimate is the first one (in stream order) whose end is
    at or after the estimate's stamp: a window model's estimate is stamped with the end of
    its window (a block's end), a streaming model's hop with its last sample (inside a
    block). An estimate whose block is missing (not received, or the stamp before the
    first block or after the last) is unpaired: a later block did not complete it.
    Blocks may come in any order; indices refer to the arguments' order."""
    starts = np.asarray(block_starts_ns, dtype=np.int64)
    ends = np.asarray(block_ends_ns, dtype=np.int64)
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    out = np.full(stamps.shape, -1, dtype=np.int64)
    if not ends.size or not stamps.size:
        return out
    order = np.argsort(ends, kind="stable")
    k = np.searchsorted(ends[order], stamps, side="left")
    ok = k < ends.size
    j = order[np.minimum(k, ends.size - 1)]
    # The stamp must lie inside the block found (start, end]: else the block that held it
    # was not received and a later one would pass for it.
    ok &= (starts[j] < stamps) & (stamps <= ends[j])
    out[ok] = j[ok]
    return out


def tail_stats(values_ms, prefix: str = "latency") -> dict:
    """``<prefix>_p50_ms``, ``_p99_ms``, ``_p999_ms`` (p99.9) and ``_max_ms`` (None when
    empty)."""
    a = np.asarray(values_ms, dtype=float)
    keys = ("p50", "p99", "p999", "max")
    if not a.size:
        return {f"{prefix}_{k}_ms": None for k in keys}
    q = np.percentile(a, [50.0, 99.0, 99.9])
    return {f"{prefix}_p50_ms": float(q[0]), f"{prefix}_p99_ms": float(q[1]),
            f"{prefix}_p999_ms": float(q[2]), f"{prefix}_max_ms": float(a.max())}


def paired_latency_ms(blocks: list, slips: list) -> np.ndarray:
    """End-to-end latencies [ms] of the estimates ``(stamp_ns, arrival_ns)`` paired with the
    blocks ``(start_ns, end_ns, arrival_ns)`` that completed them."""
    if not blocks or not slips:
        return np.zeros(0)
    b = np.asarray(blocks, dtype=np.int64).reshape(-1, 3)
    s = np.asarray(slips, dtype=np.int64).reshape(-1, 2)
    j = pair_estimates(b[:, 0], b[:, 1], s[:, 0])
    ok = j >= 0
    return (s[ok, 1] - b[j[ok], 2]) * 1e-6


def _node_figures(diags: list) -> dict:
    """The node's own latency and per-step figures from its last diagnostics message."""
    for d in reversed(diags):
        values = d.get("values", {})
        if "latency_p99_ms" in values:
            return {k: v for k, v in values.items()
                    if k.startswith(("latency_", "step_", "input_age_"))
                    or k == "hops_superseded"}
    return {}


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
    lat_ms = paired_latency_ms(got["blocks"], got["slips"])
    node = _node_figures(got["diags"])
    n_slip = len(got["slips"])
    # Estimates of audio the listener received at all (its subscription may match after
    # the SlipVector one): those that stay unpaired lost their block on the way here.
    span = (min(b[0] for b in got["blocks"]), max(b[1] for b in got["blocks"])) \
        if got["blocks"] else (0, -1)
    in_span = sum(span[0] < s <= span[1] for s, _ in got["slips"])
    return {
        "duration_s": duration_s, "checkpoint": str(checkpoint),
        "slip_rate_hz": n_slip / duration_s, "paired": int(lat_ms.size),
        "unpaired": int(in_span - lat_ms.size),
        **tail_stats(lat_ms),
        "node_reported_p99_ms": node.get("latency_p99_ms"),
        "node": node,
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
