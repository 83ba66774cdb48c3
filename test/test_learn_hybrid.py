"""The hybrid estimator (learn/models/aslip_hybrid.py, learn/inference/hybrid_estimator.py):
the checkpoint, what each hop takes from each part, and the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aslip_ros.learn.checkpoint import load_checkpoint, save_checkpoint
from aslip_ros.learn.inference.hybrid_estimator import HybridEstimator, open_estimator
from aslip_ros.learn.inference.live import LiveConfig, LiveEstimator, load_predictor
from aslip_ros.learn.models.aslip_hybrid import HybridConfig, assemble
from node_support import make_checkpoint
from test_live_estimator import STREAM_NAMES, recorded_stream
from test_learn_streaming_model import make_checkpoint as make_stream

FIXED_P = 1.0 / (1.0 + math.exp(-2.0))      # the fixed window model's p(slip)


@pytest.fixture(scope="module")
def parts(tmp_path_factory):
    """A streaming model that always says slip (threshold 0), one that never does
    (threshold 1), and a window CNN whose answer is fixed: p(slip) sigmoid(2), velocity
    (0, 0.02) m/s, threshold 0.5."""
    where = tmp_path_factory.mktemp("hybrid")
    return {"always": load_checkpoint(make_stream(where / "always.pt", threshold=0.0,
                                                  angular=True)),
            "never": load_checkpoint(make_stream(where / "never.pt", threshold=1.0,
                                                 angular=True)),
            "fixed": load_checkpoint(make_checkpoint(
                where / "fixed.pt", channel_names=STREAM_NAMES, slip_logit=2.0,
                velocity=(0.0, 0.02), seed=5))}


def _hybrid(parts, tmp_path, stream="always", **config):
    ck = assemble(parts[stream], parts["fixed"], HybridConfig(**config))
    return save_checkpoint(tmp_path / "hybrid.pt", ck.meta, ck.tensors)


def _run(path, blocks, **config):
    est = open_estimator(path, LiveConfig(**config))
    return est, [e for b in blocks for e in est.feed(b)]


def test_a_hybrid_checkpoint_round_trips_and_opens_as_one_estimator(parts, tmp_path):
    path = _hybrid(parts, tmp_path)
    ck = load_checkpoint(path)
    assert ck.model_type == "aslip_hybrid" and sorted(ck.meta["parts"]) == ["stream", "window"]
    assert ck.meta["model_config"]["detection"] == "latched"
    assert ck.meta["threshold"] == 0.0                      # the stream part's
    est = open_estimator(path)
    assert isinstance(est, HybridEstimator) and est.streaming and est.runs_windows
    assert est.predictor.model_type == "aslip_hybrid"
    assert est.predictor.channel_names == STREAM_NAMES
    # Any other checkpoint opens as it always did.
    assert isinstance(open_estimator(parts["fixed"]), LiveEstimator)
    with pytest.raises(ValueError, match="open_estimator"):
        load_predictor(path)


def test_the_window_part_gives_speed_and_direction_once_it_has_a_window(parts, tmp_path):
    blocks = recorded_stream(STREAM_NAMES, seconds=0.3)
    est, got = _run(_hybrid(parts, tmp_path), blocks)
    assert len(got) > 20 and all(e.prediction.slipping for e in got)   # stream: always
    # The window is 50 ms: the first hops have no window estimate, then every hop has one.
    first = next(i for i, e in enumerate(got)
                 if e.prediction.vx == pytest.approx(0.0, abs=1e-6)
                 and e.prediction.vz == pytest.approx(0.02, abs=1e-5))
    assert first > 0
    for e in got[first:]:
        assert (e.prediction.vx, e.prediction.vz) == pytest.approx((0.0, 0.02), abs=1e-5)
        assert e.prediction.threshold == 0.0                 # the stream part decided
    assert est.merged == len(got) - first
    # Before it, the stream part's own velocity, which the fixed window never gives.
    assert all(abs(e.prediction.vz - 0.02) > 1e-4 for e in got[:first])
    # The rotation is the stream part's, every hop.
    _, alone = _run(parts["always"], blocks)
    assert len(alone) == len(got)
    assert [e.prediction.angular_velocity for e in got] == pytest.approx(
        [e.prediction.angular_velocity for e in alone], abs=1e-6)
    assert any(abs(e.prediction.angular_velocity) > 1e-4 for e in got)


def test_either_part_may_say_slip_at_its_own_threshold(parts, tmp_path):
    blocks = recorded_stream(STREAM_NAMES, seconds=0.3)
    est, got = _run(_hybrid(parts, tmp_path, stream="never", detection="either"), blocks)
    merged = [e for e in got if e.prediction.slipping]
    assert merged and len(merged) == est.merged                # the window part said it
    for e in merged:
        assert e.prediction.probability == pytest.approx(FIXED_P, abs=1e-5)
        assert e.prediction.threshold == 0.5
    assert all(e.prediction.threshold == 1.0 for e in got if not e.prediction.slipping)
    # Detection by the stream part alone: it never says slip, whatever the window says.
    _, alone = _run(_hybrid(parts, tmp_path, stream="never", detection="stream"), blocks)
    assert len(alone) == len(got) and not any(e.prediction.slipping for e in alone)
    assert all(e.prediction.vx == 0.0 and e.prediction.vz == 0.0 for e in alone)


def test_latched_the_stream_part_starts_a_slip_and_either_part_keeps_it(parts, tmp_path):
    blocks = recorded_stream(STREAM_NAMES, seconds=0.4)
    half = len(blocks) // 2

    def run(detection, stream="always"):
        est = open_estimator(_hybrid(parts, tmp_path, stream=stream, detection=detection))
        first = [e for b in blocks[:half] for e in est.feed(b)]
        est.set_threshold(1.0)              # from here the stream part never says slip
        return est, first, [e for b in blocks[half:] for e in est.feed(b)]

    est, first, then = run("latched")
    assert first and all(e.prediction.slipping for e in first)
    assert first[-1].prediction.threshold == 0.0            # the stream part's slip
    # The window part keeps it: its p(slip) and threshold, its velocity.
    assert then and all(e.prediction.slipping for e in then)
    for e in then:
        assert e.prediction.probability == pytest.approx(FIXED_P, abs=1e-5)
        assert e.prediction.threshold == 0.5
        assert (e.prediction.vx, e.prediction.vz) == pytest.approx((0.0, 0.02), abs=1e-5)
    # Once the slip ends (a new grasp here), the window alone starts none.
    est.new_grasp("test")
    assert not any(e.prediction.slipping for b in blocks for e in est.feed(b))
    # Nor did it ever, with a stream part that never says slip; the stream part alone
    # ends the slip when it stops saying it.
    _, first, then = run("latched", stream="never")
    assert not any(e.prediction.slipping for e in first + then)
    _, first, then = run("stream")
    assert all(e.prediction.slipping for e in first)
    assert not any(e.prediction.slipping for e in then)


def test_a_window_estimate_older_than_the_limit_is_not_used(parts, tmp_path):
    blocks = recorded_stream(STREAM_NAMES, seconds=0.3)
    # Here each hop falls 1.98 ms after the end of the newest window (10 ms blocks, the
    # stream part's frames): a limit of 1 ms refuses every window, 3 ms takes them all.
    est, got = _run(_hybrid(parts, tmp_path, max_window_age_s=0.001), blocks)
    assert got and est.merged == 0
    assert all(abs(e.prediction.vz - 0.02) > 1e-4 for e in got)
    est, got = _run(_hybrid(parts, tmp_path, max_window_age_s=0.003), blocks)
    assert est.merged > 0.5 * len(got)


def test_a_hop_never_reads_a_window_that_ends_after_it(parts, tmp_path):
    est = open_estimator(_hybrid(parts, tmp_path))
    seen = []
    real = est._merge

    def spy(hop):
        seen.append((hop.stamp_ns, None if est._latest is None else est._latest.stamp_ns))
        return real(hop)
    est._merge = spy
    for b in recorded_stream(STREAM_NAMES, seconds=0.2):
        est.feed(b)
    assert seen and all(w is None or w <= h for h, w in seen)
    assert any(w is not None for _, w in seen)


def test_parts_that_do_not_fit_together_make_no_hybrid(parts, tmp_path):
    with pytest.raises(ValueError, match="streaming"):
        assemble(parts["fixed"], parts["fixed"])            # two window models
    other = load_checkpoint(make_checkpoint(tmp_path / "other.pt", channel_names=["a", "b"]))
    with pytest.raises(ValueError, match="channel_names"):
        assemble(parts["always"], other)
    planar = load_checkpoint(make_stream(tmp_path / "planar.pt", threshold=0.0))
    with pytest.raises(ValueError, match="rotation"):
        assemble(planar, parts["fixed"])                   # neither estimates rotation
    assert assemble(planar, parts["fixed"], HybridConfig(rotation=None)).meta["outputs"] == \
        ["slip", "vx", "vz"]
    with pytest.raises(ValueError, match="detection"):
        HybridConfig(detection="stream+window")
    with pytest.raises(ValueError, match="max_window_age_s"):
        HybridConfig(max_window_age_s=0.0)


def test_a_damaged_hybrid_checkpoint_is_refused_on_load(parts, tmp_path):
    ck = assemble(parts["always"], parts["fixed"])
    extra = dict(ck.tensors, **{"stray/weight": np.zeros(1, np.float32)})
    import torch
    extra = {k: torch.as_tensor(v) for k, v in extra.items()}
    path = save_checkpoint(tmp_path / "stray.pt", ck.meta, extra)
    with pytest.raises(ValueError, match="belong to no part"):
        open_estimator(path)
    meta = dict(ck.meta, parts={"stream": ck.meta["parts"]["stream"]})
    with pytest.raises(ValueError, match="parts must hold"):
        save_checkpoint(tmp_path / "one.pt", meta, ck.tensors)
        load_checkpoint(tmp_path / "one.pt")


def test_aslip_hybrid_writes_a_checkpoint_slip_inference_runs(parts, tmp_path, capsys):
    from aslip_ros import cli
    for name in ("always", "fixed"):
        save_checkpoint(tmp_path / f"{name}.pt", parts[name].meta, parts[name].tensors)
    argv = ["hybrid", "--stream", str(tmp_path / "always.pt"), "--window",
            str(tmp_path / "fixed.pt"), "--out", str(tmp_path / "h.pt")]
    assert cli.main(argv + ["--direction", "stream+window"]) == 0
    assert "direction stream+window" in capsys.readouterr().out
    est = open_estimator(tmp_path / "h.pt")
    assert isinstance(est, HybridEstimator) and est.cfg.direction == "stream+window"
    # It names its parts by their content, so a copy elsewhere is known as theirs.
    import hashlib
    from aslip_ros.learn.models.aslip_hybrid import assembled_from
    assert assembled_from(tmp_path / "h.pt") == {
        n: hashlib.sha256((tmp_path / f).read_bytes()).hexdigest()
        for n, f in (("stream", "always.pt"), ("window", "fixed.pt"))}
    assert assembled_from(tmp_path / "always.pt") is None
    # Parts the wrong way round: one line, exit 1, nothing written.
    wrong = ["hybrid", "--stream", str(tmp_path / "fixed.pt"), "--window",
             str(tmp_path / "always.pt"), "--out", str(tmp_path / "bad.pt")]
    assert cli.main(wrong) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("aslip hybrid: error:") and "\n" not in err
    assert not (tmp_path / "bad.pt").exists()


def test_the_shipped_hybrid_cuts_its_calibration_frames_once():
    """models/aslip.pt: both parts calibrate on the same frames; the window part reads the
    stream part's, and each part's offsets are those it computes alone."""
    from pathlib import Path

    from aslip_ros.audio_frame import AudioData
    from aslip_ros.learn.calibration.frames import StreamCalibration
    path = Path(__file__).resolve().parents[1] / "models" / "aslip.pt"
    est = open_estimator(path)
    parts = (est.stream.predictor, est.window.predictor)
    cals = [p._stream_cal for p in parts]
    assert cals[0].cutter is cals[1].cutter
    alone = [StreamCalibration(p.calibration, p.feature_config, p.sample_rate) for p in parts]
    rng = np.random.default_rng(0)
    names, fs = list(parts[1].channel_names), parts[1].sample_rate
    for i in range(60):
        block = (0.01 * rng.standard_normal((480, len(names)))).astype(np.float32)
        est.feed(AudioData(i * 480, 10**9 + int(i * 480 / fs * 1e9), fs, names, "4mic",
                           "aslip_sensor", block))
        for s in alone:
            s.push(block)
    for c, s in zip(cals, alone):
        assert c.state.n_frames == s.state.n_frames > 50
        np.testing.assert_array_equal(c.offsets, s.offsets)
    assert cals[0].cutter.reused == cals[0].state.n_frames
