"""slip_inference with a streaming checkpoint (``aslip_stream``), as a separate process.

Published estimates equal StreamingPredictor run offline on the same blocks (every hop, its
stamp and window_length); a gap, a time jump, a dropped block and a dead channel reset the
state; a mismatched stream is refused with an ERROR diagnostic, and an unusable streaming
checkpoint makes the node exit with the configuration code.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from node_support import SCENE_NAMES, Bus, NodeProcess, header_ns, refusal

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
STREAM_CKPT = ROOT / "results" / "lag" / "stream.pt"
SLIP = "/aslip/slip"
DIAG = "/aslip/diagnostics"
RATE, BLOCK = 48000.0, 480
BLOCK_NS = int(BLOCK / RATE * 1e9)


def stream_audio(n_blocks, seed=0):
    """Noise with loud bursts on one microphone at a time: the model's answer moves."""
    rng = np.random.default_rng(seed)
    a = 0.005 * rng.standard_normal((n_blocks * BLOCK, len(SCENE_NAMES)))
    burst = np.repeat(rng.integers(0, 4, n_blocks // 8 + 1), 8 * BLOCK)[:a.shape[0]]
    loud = np.repeat(rng.random(n_blocks // 8 + 1) < 0.5, 8 * BLOCK)[:a.shape[0]]
    a[np.arange(a.shape[0]), burst] *= np.where(loud, 20.0, 1.0)
    return a.astype(np.float32)


class Stream:
    """Publishes 480-frame blocks and keeps the AudioData the node will decode from them."""

    def __init__(self, pub, index=0, stamp_ns=1_000_000_000_000) -> None:
        self.pub = pub
        self.index, self.stamp_ns = index, stamp_ns

    def blocks(self, audio, names=SCENE_NAMES, rate=RATE) -> list:
        from aslip_ros.nodes import convert
        out = []
        for s in range(0, audio.shape[0], BLOCK):
            msg = convert.audio_to_msg(self.index, self.stamp_ns, rate, names,
                                       audio[s:s + BLOCK], "4mic")
            out.append((msg, convert.audio_from_msg(msg, require_finite=False)))
            self.index += BLOCK
            self.stamp_ns += BLOCK_NS
        return out

    def feed(self, audio, **kw) -> list:
        """Publish ``audio``; the decoded blocks, as the node sees them."""
        sent = self.blocks(audio, **kw)
        for msg, _ in sent:
            self.pub.publish(msg)
            time.sleep(0.003)
        return [a for _, a in sent]

    def skip(self, n_blocks: int) -> None:
        """Blocks lost upstream: index and stamp move on together (a gap)."""
        self.index += n_blocks * BLOCK
        self.stamp_ns += n_blocks * BLOCK_NS


@pytest.fixture(scope="module")
def live():
    import rclpy
    from domain_coordinator import domain_id
    from rclpy.context import Context
    from std_msgs.msg import String

    from aslip_ros.msg import AudioFrame, SlipVector
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
    assert STREAM_CKPT.is_file(), STREAM_CKPT
    with domain_id() as did:
        env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   PYTHONUNBUFFERED="1")
        ctx = Context()
        rclpy.init(context=ctx, domain_id=did)
        bus = Bus(ctx)
        bus.listen(SlipVector, SLIP, RELIABLE_QOS)
        bus.listen(String, DIAG, RELIABLE_QOS)
        pub = bus.node.create_publisher(AudioFrame, c.AUDIO_TOPIC, SENSOR_QOS)
        # threshold 0: every estimate is "slipping", so its velocity is published too.
        proc = NodeProcess("slip_inference", env, {"checkpoint": str(STREAM_CKPT),
                                                   "threshold": 0.0,
                                                   "diagnostics_period_s": 0.1})
        try:
            proc.wait_ready()
            assert bus.wait(lambda: pub.get_subscription_count() > 0, 10)
            stream = Stream(pub)
            # Until the node takes blocks: best-effort blocks sent before its reader matched
            # this writer are lost (the tests below start after a gap, from a fresh state).
            assert bus.wait(lambda: _settle(bus, stream), 30), proc.output[-3000:]
            yield bus, stream, proc
        finally:
            proc.stop()
            bus.close()
            rclpy.try_shutdown(context=ctx)


def _settle(bus, stream) -> bool:
    stream.feed(stream_audio(5, seed=99))
    time.sleep(0.2)
    return bool(bus.messages(SLIP))


def _resets_after(bus, before, n_blocks) -> int:
    """``stream_resets`` once the node has taken ``n_blocks`` more than at ``before``."""
    v = _diag(bus, lambda v: v["blocks_accepted"] >= before["blocks_accepted"] + n_blocks)
    assert v is not None
    return v["stream_resets"]


def _offline(blocks, continue_from=None, threshold=0.0):
    """StreamingPredictor over ``blocks`` (after ``continue_from`` ones, if given)."""
    from aslip_ros.learn.inference.stream_predictor import StreamingPredictor
    p = StreamingPredictor.from_checkpoint(STREAM_CKPT, threshold=threshold)
    for b in continue_from or []:
        p.push(b)
    return [e for b in blocks for e in p.push(b)]


def _published(bus, blocks, proc):
    """The SlipVectors stamped inside ``blocks``, once the last hop's one has arrived."""
    t0, t1 = blocks[0].stamp_ns, blocks[-1].end_stamp_ns
    want_last = _offline(blocks)[-1].stamp_ns
    assert bus.wait(lambda: any(header_ns(m) == want_last for m in bus.messages(SLIP)), 20), \
        proc.output[-3000:]
    return [m for m in bus.messages(SLIP) if t0 <= header_ns(m) <= t1]


def _assert_equal(msgs, ests):
    assert [header_ns(m) for m in msgs] == [e.stamp_ns for e in ests]   # every hop, in order
    for m, e in zip(msgs, ests):
        p = e.prediction
        assert m.probability == pytest.approx(p.probability, abs=1e-5)
        assert (m.velocity.x, m.velocity.z) == pytest.approx((p.vx, p.vz), abs=1e-6)
        assert m.slipping == p.slipping and m.threshold == 0.0
        assert m.window_length == pytest.approx(0.032)
        assert m.source == "aslip_stream" and m.direction_sigma == -1.0


def _diag(bus, predicate=lambda v: True):
    """slip_inference's newest diagnostics values once they satisfy ``predicate``."""
    return bus.latest_diagnostics("slip_inference", predicate)


def test_streaming_in_the_node_equals_offline(live):
    bus, stream, proc = live
    before = _diag(bus)
    assert before is not None, proc.output[-3000:]
    stream.skip(100)                        # a gap: the comparison starts from a zero state
    blocks = stream.feed(stream_audio(150, seed=1))
    msgs = _published(bus, blocks, proc)
    ests = _offline(blocks)
    assert len(ests) == 150 - 3             # the first frame needs 32 ms, then one per block
    _assert_equal(msgs, ests)
    probs = np.array([m.probability for m in msgs])
    assert probs.max() - probs.min() > 0.1, probs    # the outputs follow the audio
    # Stamped at each frame's last sample: the first after 1536 samples of the stream.
    assert header_ns(msgs[0]) == blocks[0].stamp_ns + round(1535 * 1e9 / RATE)
    v = _diag(bus, lambda v: v["blocks_accepted"] >= before["blocks_accepted"] + 150)
    assert v is not None and v["model"] == "aslip_stream", proc.output[-3000:]
    assert v["gaps"] == before["gaps"] + 1 and v["threshold"] == 0.0, v
    assert v["latency_p50_ms"] > 0


@pytest.mark.parametrize("fault", ["gap", "time_jump"])
def test_a_gap_or_a_time_jump_resets_the_state(live, fault):
    bus, stream, proc = live
    before = _diag(bus)
    stream.skip(100)
    first = stream.feed(stream_audio(40, seed=2))
    _published(bus, first, proc)
    n = _resets_after(bus, before, 40)
    if fault == "gap":
        stream.skip(3)
    else:                                   # a clock step at a contiguous sample index
        stream.stamp_ns += 5 * 10**9
    after = stream.feed(stream_audio(40, seed=3))
    # The node drops the block that revealed a time jump (as for window models) and starts
    # again from the next one; a gap's first block starts the new history itself.
    fresh_from = after if fault == "gap" else after[1:]
    msgs = _published(bus, fresh_from, proc)
    want = _offline(fresh_from)
    _assert_equal(msgs, want)
    v = _diag(bus, lambda v: v["stream_resets"] >= n + 1)
    assert v is not None and v["stream_resets"] == n + 1, v
    assert v["last_reset_reason"].startswith("gap" if fault == "gap" else "time jump"), v
    # Had the state carried on, the same blocks would have given other outputs.
    moved = [first[-1]]
    for b in fresh_from:
        moved.append(_moved(b, moved[-1]))
    carried = _offline(moved[1:], continue_from=first)
    assert not np.allclose([e.prediction.probability for e in carried[:10]],
                           [e.prediction.probability for e in want[:10]], atol=1e-4)


def _moved(b, last):
    """``b`` renumbered to follow ``last`` contiguously (a stream without the fault)."""
    from dataclasses import replace
    return replace(b, first_sample_index=last.first_sample_index + BLOCK,
                   stamp_ns=last.end_stamp_ns)


def test_a_dropped_block_and_a_dead_channel_reset_the_state(live):
    bus, stream, proc = live
    before = _diag(bus)
    stream.skip(100)
    first = stream.feed(stream_audio(30, seed=4))
    _published(bus, first, proc)
    n = _resets_after(bus, before, 30)
    bad = stream_audio(1, seed=5)
    bad[7, 2] = np.nan
    stream.feed(bad)                        # refused (non_finite): the next one follows a hole
    after = stream.feed(stream_audio(30, seed=6))
    _assert_equal(_published(bus, after, proc), _offline(after))
    v = _diag(bus, lambda v: v["stream_resets"] >= n + 1)
    assert v["stream_resets"] == n + 1 and "non_finite" in v["last_reset_reason"], v

    dead = stream_audio(1, seed=7)
    dead[:, 1] = 0.0                        # one microphone digitally silent for 10 ms
    dead_block = stream.feed(dead)[0]
    after = stream.feed(stream_audio(30, seed=8))
    _assert_equal(_published(bus, after, proc), _offline(after))
    assert not [m for m in bus.messages(SLIP)
                if dead_block.stamp_ns <= header_ns(m) < dead_block.end_stamp_ns]
    v = _diag(bus, lambda v: v["stream_resets"] >= n + 2)
    assert v["stream_resets"] == n + 2 and "dead channel" in v["last_reset_reason"], v
    assert v["dead_channel_windows"] >= 1


@pytest.mark.parametrize("case", ["channels", "sample_rate"])
def test_a_mismatched_stream_is_refused(live, case):
    bus, stream, proc = live
    stream.skip(100)
    kw = {"names": list(reversed(SCENE_NAMES))} if case == "channels" else {"rate": 44100.0}
    sent = stream.feed(stream_audio(20, seed=9), **kw)
    v = _diag(bus, lambda v: v.get(f"dropped_{case}", 0) >= 20 and
              v["last_reset_reason"].startswith("refused stream"))
    assert v is not None, proc.output[-3000:]
    docs = bus.diagnostics("slip_inference")
    assert any(d["level"] == 2 and "stream refused" in d["message"] for d in docs[-20:]), \
        docs[-1]
    assert not [m for m in bus.messages(SLIP)
                if sent[0].stamp_ns <= header_ns(m) <= sent[-1].end_stamp_ns]
    # The right stream again: estimates flow from a fresh state.
    after = stream.feed(stream_audio(10, seed=10))
    _assert_equal(_published(bus, after, proc), _offline(after))


def _bad_stream_checkpoint(path, **meta_changes):
    """The committed streaming checkpoint with ``meta_changes``, written without the save
    path's validation."""
    import json

    import torch
    payload = torch.load(STREAM_CKPT, weights_only=True)
    meta = json.loads(payload["meta"])
    meta.update(meta_changes)
    payload["meta"] = json.dumps(meta)
    torch.save(payload, path)
    return path


@pytest.mark.parametrize("change,words", [
    ({"sample_rate": 44100.0}, "integer multiple"),
    ({"label": {}}, "label")])
def test_an_unusable_streaming_checkpoint_is_refused_at_start(rclpy_context, tmp_path, change,
                                                              words):
    """In this process (the executable's exit 2 on a refusal: test_nodes_inference)."""
    ckpt = _bad_stream_checkpoint(tmp_path / "bad.pt", **change)
    assert words in refusal(rclpy_context, "slip_inference", {"checkpoint": str(ckpt)})
