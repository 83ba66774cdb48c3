"""slip_inference with a per-grasp calibrated checkpoint, as a separate process.

Streaming equals offline over the same stream; the state resets on a gap, a new stream and
``~/recalibrate``; a checkpoint whose calibration cannot fit its stream is refused.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest

from node_support import (SCENE_NAMES, Bus, NodeProcess, header_ns, make_checkpoint, refusal)

pytestmark = pytest.mark.ros

SLIP = "/aslip/slip"
DIAG = "/aslip/diagnostics"
RATE, BLOCK = 48000.0, 480
GAINS = np.array([2.0, 1.0, 0.5, 1.4])             # per-microphone coupling of the test grasp
TRUST_DB = 1.0                                      # the live fixture's self-check threshold


def constants(names=SCENE_NAMES, **kw):
    """Permissive constants: every frame above -100 counts as background."""
    from aslip_ros.learn.calibration.grasp import CalibrationConstants
    m = 16                                          # make_checkpoint's n_mels
    d = dict(channel_names=tuple(names), n_mels=m, hop_s=0.01, gate_mean=(0.0,) * m,
             gate_std=(1.0,) * m, gate_coef=(0.0,) * m, gate_bias=-5.0, floor_level=-100.0,
             ref_offset=(0.0,) * len(names), prior_frames=5.0, converge_frames=60)
    d.update(kw)
    return CalibrationConstants(**d)


#: A direction-sigma model: 0.8 rad below 2 cm/s of predicted speed, 0.4 rad above.
OUTPUT_CALIBRATION = {"threshold": 0.5, "direction_sigma": {"model": {
    "speed_edges_m_s": [0.02], "sigma_rad": [0.8, 0.4]}}}


def calibrated_checkpoint(path, k=None, sample_rate=RATE):
    """make_checkpoint's untrained CNN (its answer depends on the audio) plus ``k`` and a
    direction-sigma model, written without the save path's validation (so a mismatched
    ``k`` can be written too)."""
    import json

    import torch
    plain = make_checkpoint(path.with_suffix(".plain.pt"), sample_rate=sample_rate)
    payload = torch.load(plain, weights_only=True)
    meta = json.loads(payload["meta"])
    meta["calibration"] = json.loads(json.dumps((k or constants()).to_dict()))
    meta["output_calibration"] = OUTPUT_CALIBRATION
    payload["meta"] = json.dumps(meta)
    torch.save(payload, path)
    return path


def stream_audio(n_blocks, seed=0):
    rng = np.random.default_rng(seed)
    a = 0.01 * rng.standard_normal((n_blocks * BLOCK, len(SCENE_NAMES)))
    # Bursts on one channel at a time, so the model's answer moves from window to window.
    burst = np.repeat(rng.integers(0, 4, n_blocks // 5 + 1), 5 * BLOCK)[:a.shape[0]]
    a[np.arange(a.shape[0]), burst] *= 3.0
    return (a * GAINS).astype(np.float32)


class Stream:
    def __init__(self, bus, pub, index=0, stamp_ns=1_000_000_000_000) -> None:
        self.bus, self.pub = bus, pub
        self.index, self.stamp_ns = index, stamp_ns

    def feed(self, audio) -> None:
        from aslip_ros.nodes import convert
        for s in range(0, audio.shape[0], BLOCK):
            self.pub.publish(convert.audio_to_msg(self.index, self.stamp_ns, RATE, SCENE_NAMES,
                                                  audio[s:s + BLOCK], "4mic"))
            self.index += BLOCK
            self.stamp_ns += int(BLOCK / RATE * 1e9)
            time.sleep(0.003)


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    import rclpy
    from domain_coordinator import domain_id
    from rclpy.context import Context
    from std_msgs.msg import String

    from aslip_ros.msg import AudioFrame, SlipVector
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import RELIABLE_QOS, SENSOR_QOS
    # With the self-check at 1 dB: stream_audio's bursts on one channel at a time are a
    # background whose balance keeps changing, so the node reports it untrusted.
    ckpt = calibrated_checkpoint(tmp_path_factory.mktemp("cal") / "cal.pt",
                                 constants(trust_spread_db=TRUST_DB))
    with domain_id() as did:
        env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   PYTHONUNBUFFERED="1")
        ctx = Context()
        rclpy.init(context=ctx, domain_id=did)
        bus = Bus(ctx)
        bus.listen(SlipVector, SLIP, RELIABLE_QOS)
        bus.listen(String, DIAG, RELIABLE_QOS)
        pub = bus.node.create_publisher(AudioFrame, c.AUDIO_TOPIC, SENSOR_QOS)
        proc = NodeProcess("slip_inference", env, {"checkpoint": str(ckpt), "threshold": 0.0,
                                                   "diagnostics_period_s": 0.1})
        try:
            proc.wait_ready()
            assert bus.wait(lambda: pub.get_subscription_count() > 0, 10)
            yield bus, Stream(bus, pub), proc, ckpt
        finally:
            proc.stop()
            bus.close()
            rclpy.try_shutdown(context=ctx)


def _diag(bus, predicate=lambda v: True):
    """slip_inference's newest diagnostics values once they satisfy ``predicate``."""
    return bus.latest_diagnostics("slip_inference", predicate)


def test_streaming_calibration_in_the_node_equals_offline(live):
    """Every published estimate equals the offline computation over the same stream:
    the window ending at its stamp, with the offsets of the frames complete by then."""
    from aslip_ros.learn.calibration.grasp import CalibrationState
    from aslip_ros.learn.calibration.frames import FrameCutter, window_offsets
    from aslip_ros.learn.inference.predictor import Predictor
    bus, stream, proc, ckpt = live
    audio = stream_audio(150)
    before = _diag(bus)
    assert before is not None, proc.output[-3000:]
    new_grasp = before["blocks_accepted"] > 0
    if new_grasp:                          # after other tests: a gap starts a new grasp
        stream.index += 48000
        stream.stamp_ns += 10**9
    t0 = stream.stamp_ns
    stream.feed(audio)
    end = stream.stamp_ns
    assert bus.wait(lambda: any(header_ns(m) == end for m in bus.messages(SLIP)), 20), \
        proc.output[-3000:]
    total = FrameCutter(Predictor.from_checkpoint(ckpt).feature_config, RATE).count(
        audio.shape[0])
    values = _diag(bus, lambda v: v["calibration_frames"] == total)
    assert values is not None, proc.output[-3000:]
    assert values["gaps"] == before["gaps"] + new_grasp, values
    assert values["blocks_accepted"] == before["blocks_accepted"] + 150, values

    p = Predictor.from_checkpoint(ckpt, threshold=0.0)
    k = p.calibration
    cutter = FrameCutter(p.feature_config, RATE)
    frames = cutter.frames(audio)
    msgs = [m for m in bus.messages(SLIP) if t0 < header_ns(m) <= end]
    assert len(msgs) >= 20                     # superseded hops are skipped, not wrong
    ends = np.array([round((header_ns(m) - t0) * RATE / 1e9) for m in msgs])
    offs = window_offsets(frames, ends, cutter, k)
    assert np.abs(offs[-1]).max() > 0.5        # the calibration moves the features
    sigmas, moved = set(), 0.0
    for m, e, off in zip(msgs, ends, offs):
        want = p.predict(audio[e - p.window_samples:e], off)
        raw = p.predict(audio[e - p.window_samples:e])
        assert m.probability == pytest.approx(want.probability, abs=1e-5)
        assert (m.velocity.x, m.velocity.z) == pytest.approx((want.vx, want.vz), abs=1e-6)
        moved = max(moved, abs(want.vx - raw.vx), abs(want.vz - raw.vz))
        state = CalibrationState(k)
        state.update(frames[:, :, :cutter.count(e)])
        # Uninformative until converged; then the checkpoint's sigma at the raw speed.
        want_sigma = math.pi if not state.converged else want.direction_sigma
        assert m.direction_sigma == pytest.approx(want_sigma, abs=1e-6)
        sigmas.add(round(m.direction_sigma, 3))
    assert round(math.pi, 3) in sigmas                  # both before and after convergence
    assert sigmas - {round(math.pi, 3)} and sigmas - {round(math.pi, 3)} <= {0.8, 0.4}
    # The uncalibrated answer would have differed, by far more than the comparison's 1e-6
    # tolerance (which hops are published depends on the load: the bound is 10x the
    # tolerance, not a size of the shift; seen at 9.7e-5 m/s on a loaded run).
    assert moved > 1e-5
    final = CalibrationState(k)
    final.update(frames)
    for name, g in zip(SCENE_NAMES, final.gain_db):
        assert values[f"gain_db_{name}"] == pytest.approx(g, abs=1e-3)
    assert values["calibration_converged"] is True
    assert values["calibration_accepted_frames"] == total
    # The self-check, as offline: the bursts move one channel at a time, not common mode.
    assert values["calibration_spread_db"] == pytest.approx(final.spread_db, abs=1e-3)
    assert final.trusted is False and values["calibration_trusted"] is False
    assert values["calibration_trust_spread_db"] == TRUST_DB
    doc = [d for d in bus.diagnostics("slip_inference")
           if d["values"].get("calibration_frames") == total][0]
    assert doc["level"] == 1 and "calibration not trusted" in doc["message"], doc


def test_calibration_resets_on_gap_restart_time_jump_and_service(live):
    from std_srvs.srv import Trigger
    bus, stream, proc, _ = live
    stream.feed(stream_audio(20, seed=1))
    before = _diag(bus, lambda v: v["calibration_frames"] >= 17)
    assert before is not None, proc.output[-3000:]
    n = before["calibration_resets"]
    after_five = 4                          # frames complete after 5 blocks: (2400-768)//480+1

    stream.index += 4800                    # a gap: ten blocks lost upstream
    stream.stamp_ns += 100_000_000
    stream.feed(stream_audio(5, seed=2))
    v = _diag(bus, lambda v: v["calibration_resets"] == n + 1
              and v["calibration_frames"] == after_five)
    assert v is not None and v["gaps"] > before["gaps"], proc.output[-3000:]
    assert v["calibration_converged"] is False

    stream.feed(stream_audio(20, seed=3))
    assert _diag(bus, lambda v: v["calibration_frames"] >= 17) is not None
    stream.index = 0                        # the source restarted its sample counter
    stream.feed(stream_audio(5, seed=4))
    v = _diag(bus, lambda v: v["calibration_resets"] == n + 2
              and v["calibration_frames"] == after_five)
    assert v is not None and v["stream_restarts"] >= 1, proc.output[-3000:]

    stream.feed(stream_audio(20, seed=5))
    assert _diag(bus, lambda v: v["calibration_frames"] >= 17) is not None
    stream.stamp_ns += 5 * 10**9            # a clock step at a contiguous index: dropped,
    stream.feed(stream_audio(6, seed=6))    # re-anchored, then 5 blocks of the new grasp
    v = _diag(bus, lambda v: v["calibration_resets"] == n + 3
              and v["calibration_frames"] == after_five)
    assert v is not None and v.get("dropped_time_jump", 0) >= 1, proc.output[-3000:]

    cli = bus.node.create_client(Trigger, "/slip_inference/recalibrate")
    assert cli.wait_for_service(timeout_sec=10)
    fut = cli.call_async(Trigger.Request())
    assert bus.wait(fut.done, 10)
    assert fut.result().success and "reset" in fut.result().message
    v = _diag(bus, lambda v: v["calibration_resets"] == n + 4)
    assert v is not None and v["calibration_frames"] == 0
    assert v["calibration_accepted_frames"] == 0
    assert all(v[f"gain_db_{name}"] == 0.0 for name in SCENE_NAMES)


class _LoggedNode:
    """The bus node, with what is logged through it kept (GraspCalibration reports there)."""

    def __init__(self, node) -> None:
        self.node, self.lines = node, []

    def __getattr__(self, name):
        return getattr(self.node, name)

    def get_logger(self):
        lines = self.lines

        class Logger:
            def info(self, text, **kw):
                lines.append(("info", text))

            def warning(self, text, **kw):
                lines.append(("warning", text))
        return Logger()


def test_a_controller_restarts_the_calibration_at_a_grasp_and_says_when_it_converged(live):
    """What a controller does at each task start (nodes/grasp_calibration.py), against the
    real slip_inference: the service starts a new grasp, /aslip/calibration announces it
    and then its convergence, and the user is told to hold still, then that it converged."""
    from aslip_ros.nodes.grasp_calibration import GraspCalibration
    bus, stream, proc, _ = live
    node = _LoggedNode(bus.node)
    cal = GraspCalibration(node)
    assert cal.client.wait_for_service(timeout_sec=10)
    assert bus.wait(lambda: cal.calibrated is True, 10), proc.output[-3000:]
    grasp = cal.grasp
    cal.begin()
    assert bus.wait(lambda: cal.grasp == grasp + 1, 10), proc.output[-3000:]
    assert cal.values() == {"calibration": "calibrating"}
    assert any("hold the grasped object still" in t for _, t in node.lines), node.lines
    stream.feed(stream_audio(90, seed=7))        # converge_frames=60 frames of 10 ms
    assert bus.wait(lambda: cal.values()["calibration"] == "converged", 20), \
        proc.output[-3000:]
    assert cal.values()["calibration_converged_after_s"] > 0
    assert any(t.startswith("calibration converged") for _, t in node.lines), node.lines
    # The grasp's background is not common mode: /aslip/calibration says so once, and the
    # controller warns the user.
    assert bus.wait(lambda: cal.values().get("calibration_trusted") is False, 20), \
        proc.output[-3000:]
    assert any(level == "warning" and "calibration not trusted" in t
               for level, t in node.lines), node.lines
    # The controller's output is read by a thread: wait for the line, do not just look.
    assert proc.wait_for("per-grasp calibration not trusted", 10), proc.output[-3000:]


def test_calibration_for_another_stream_is_refused_at_start(rclpy_context, tmp_path):
    """Constants fitted for other microphones: refused, naming the problem (in this
    process; the executable's exit 2 on a refusal: test_nodes_inference)."""
    ckpt = calibrated_checkpoint(tmp_path / "other.pt",
                                 constants(names=["a", "b", "c", "d"]))
    assert "calibration" in refusal(rclpy_context, "slip_inference", {"checkpoint": str(ckpt)})


def test_calibration_that_cannot_follow_the_stream_rate_is_refused(rclpy_context, tmp_path):
    """A 22.05 kHz checkpoint: the 10 ms feature hop is no whole number of its samples, so
    its stream cannot be cut into the calibration's frames."""
    ckpt = calibrated_checkpoint(tmp_path / "odd.pt", sample_rate=22050.0)
    assert "whole number" in refusal(rclpy_context, "slip_inference",
                                     {"checkpoint": str(ckpt)})
