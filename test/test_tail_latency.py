"""The tail-latency figures: the bench's pairing of estimates with the blocks that completed
them (pure numpy), the node's per-step figures in its diagnostics, the benchmark's rows."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from benchmarks.node_bench import pair_estimates, paired_latency_ms, tail_stats
from node_support import SCENE_NAMES, make_checkpoint

BLOCK_NS = 10_000_000                 # 480 frames at 48 kHz
T0 = 1_000_000_000_000


def _blocks(n: int, skip=()):
    starts = np.array([T0 + i * BLOCK_NS for i in range(n) if i not in skip], np.int64)
    return starts, starts + BLOCK_NS


def test_a_window_estimate_pairs_with_the_block_that_ends_at_its_stamp():
    starts, ends = _blocks(10)
    assert pair_estimates(starts, ends, ends).tolist() == list(range(10))


def test_streaming_hops_pair_with_the_block_holding_their_last_sample():
    starts, ends = _blocks(10)
    # The shipped streaming model: a 10 ms hop whose last sample lies 95 samples into each
    # block (from a reset), stamped with that sample; also the first and the last sample.
    per = BLOCK_NS / 480
    stamps = np.concatenate([starts + round(95 * per), starts + round(479 * per),
                             starts[1:]])
    want = list(range(10)) * 2 + list(range(0, 9))    # a block's first sample: the block
    assert pair_estimates(starts, ends, stamps).tolist() == want[:20] + list(range(0, 9))


def test_a_lost_block_leaves_its_estimates_unpaired_and_order_does_not_matter():
    starts, ends = _blocks(10, skip=(4,))
    stamps = np.array([T0 + 4 * BLOCK_NS + 2_000_000, T0 + 5 * BLOCK_NS + 2_000_000,
                       T0 - 1, T0 + 10 * BLOCK_NS + 1])
    rev = slice(None, None, -1)
    got = pair_estimates(starts[rev], ends[rev], stamps)
    assert got[0] == -1 and got[2] == -1 and got[3] == -1     # lost, before, after
    assert ends[rev][got[1]] == T0 + 6 * BLOCK_NS             # block 5, wherever it is


def test_paired_latency_is_the_difference_of_the_two_arrivals():
    starts, ends = _blocks(3)
    blocks = [(int(s), int(e), int(e) + 1_000_000) for s, e in zip(starts, ends)]
    slips = [(int(ends[0]), int(ends[0]) + 3_500_000),            # window: 2.5 ms
             (int(starts[2]) + 1_979_166, int(ends[2]) + 1_250_000),  # stream: 0.25 ms
             (int(ends[2]) + 5, int(ends[2]) + 9_000_000)]        # no block: unpaired
    assert np.allclose(paired_latency_ms(blocks, slips), [2.5, 0.25])
    assert paired_latency_ms([], slips).size == 0


def test_tail_stats_name_every_statistic():
    got = tail_stats(np.arange(1, 1001, dtype=float), "step_x")
    assert got["step_x_p50_ms"] == pytest.approx(500.5)
    assert got["step_x_max_ms"] == 1000.0
    assert got["step_x_p99_ms"] < got["step_x_p999_ms"] < got["step_x_max_ms"]
    assert tail_stats([], "e")["e_p999_ms"] is None


def test_the_benchmark_rows_read_the_node_steps_and_the_listener():
    from benchmarks.tail_latency import STATS, STEPS, rows
    res = {"latency_p50_ms": 1.0, "latency_p99_ms": 2.0, "latency_p999_ms": 3.0,
           "latency_max_ms": 4.0,
           "node": {f"step_{s}_{k}_ms": 0.5 for s in STEPS for k in STATS}}
    t = rows(res)
    assert t["end_to_end"] == {"p50": 1.0, "p99": 2.0, "p999": 3.0, "max": 4.0}
    assert all(t[s]["p999"] == 0.5 for s in STEPS)
    assert t["node_total"]["max"] is None


# --- the node's diagnostics ----------------------------------------------------------------

TIMED = ("input_age", "step_queue", "step_features", "step_forward", "step_publish",
         "latency")
STEP_KEYS = [f"{pre}_{k}_ms" for pre in TIMED for k in ("p50", "p99", "p999", "max")]


@pytest.fixture(scope="module")
def window_ckpt(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("tail") / "cnn.pt")


def _diagnostics_after_estimates(context, ckpt, n_estimates: int = 5) -> dict:
    """An in-process slip_inference fed 10 ms blocks until it has published
    ``n_estimates``; the values of its next diagnostics message."""
    import json

    from rclpy.executors import MultiThreadedExecutor
    from rclpy.parameter import Parameter
    from std_msgs.msg import String

    from aslip_ros import topics
    from aslip_ros.msg import AudioFrame, SlipVector
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
    from aslip_ros.nodes import convert
    from aslip_ros.nodes.slip_inference import SlipInference
    from node_support import Bus, deep

    bus = Bus(context)
    cond = threading.Condition()
    got: dict = {"slips": 0, "diag": None}

    def on_slip(_msg):
        with cond:
            got["slips"] += 1
            cond.notify_all()

    def on_diag(msg):
        doc = json.loads(msg.data)
        with cond:
            if got["slips"] >= n_estimates and "step_forward_p999_ms" in doc["values"]:
                got["diag"] = doc["values"]
                cond.notify_all()

    bus.node.create_subscription(SlipVector, c.SLIP_TOPIC, on_slip, deep(RELIABLE_QOS))
    bus.node.create_subscription(String, topics.DIAGNOSTICS_JSON, on_diag,
                                 deep(RELIABLE_QOS))
    pub = bus.node.create_publisher(AudioFrame, c.AUDIO_TOPIC, SENSOR_QOS)
    node = SlipInference(context=context, parameter_overrides=[
        Parameter("checkpoint", value=str(ckpt)), Parameter("diagnostics_period_s", value=0.1)])
    ex = MultiThreadedExecutor(context=context)
    ex.add_node(node)
    spin = threading.Thread(target=ex.spin, daemon=True)
    spin.start()
    rng = np.random.default_rng(0)
    try:
        assert bus.wait(lambda: pub.get_subscription_count() > 0, 30)
        index, stamp = 0, T0
        # One block at a time, each once the previous one was taken (best effort: a block
        # lost before the reader matched is sent again; the gate drops a repeat).
        for _ in range(2000):
            with cond:
                if got["diag"] is not None:
                    return got["diag"]
            block = (0.01 * rng.standard_normal((480, len(SCENE_NAMES)))).astype(np.float32)
            ok0 = node.est.stats.blocks_ok
            msg = convert.audio_to_msg(index, stamp, 48000.0, SCENE_NAMES, block, "4mic")
            for _ in range(50):
                pub.publish(msg)
                with cond:
                    if cond.wait_for(lambda: node.est.stats.blocks_ok > ok0
                                     or got["diag"] is not None, timeout=0.2):
                        break
            index, stamp = index + 480, stamp + BLOCK_NS
        raise AssertionError(f"no diagnostics with step figures; {got['slips']} estimates")
    finally:
        ex.shutdown()
        spin.join(5)            # not under a wait on the node's entities (see test_live_estimator)
        node.destroy_node()
        bus.close()


@pytest.mark.ros
def test_the_node_reports_every_step_to_p999_and_max(rclpy_context, window_ckpt):
    values = _diagnostics_after_estimates(rclpy_context, window_ckpt)
    missing = [k for k in STEP_KEYS if k not in values]
    assert not missing
    for pre in TIMED[1:]:      # the input's age compares wall time with the test's stamps
        p50, p99, p999, mx = (values[f"{pre}_{k}_ms"] for k in ("p50", "p99", "p999", "max"))
        assert 0.0 <= p50 <= p99 <= p999 <= mx


@pytest.mark.ros
def test_a_streaming_node_reports_every_step_too(rclpy_context):
    from pathlib import Path
    ckpt = Path(__file__).resolve().parents[1] / "models" / "aslip_stream.pt"
    values = _diagnostics_after_estimates(rclpy_context, ckpt)
    assert not [k for k in STEP_KEYS if k not in values]
    assert values["step_forward_max_ms"] > 0.0
