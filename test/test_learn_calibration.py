"""Per-grasp calibration state: causal, resettable, robust to one-sided slip, round-trips."""

import json

import numpy as np
import pytest

from aslip_ros.learn.calibration import grasp as cal
from aslip_ros.learn.checkpoint import CheckpointMismatch, load_checkpoint, save_checkpoint
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.models.svm import SvmConfig

C, M = 4, 8
MIC_ANGLE = np.array([0.25, 0.75, 1.25, 1.75]) * np.pi
NAMES = ("a", "b", "c", "d")


def grasp(rng, gains, n=3000, dirs=None, one_sided=None):
    """Synthetic log-mel frames (C, M, n) and slip labels: silence at the floor (no gain),
    common-mode background with a low spectrum, slip with a high spectrum whose level at
    each microphone follows the slip direction. ``gains``: log-power offsets per channel."""
    kind = rng.choice(3, n, p=[0.3, 0.4, 0.3])         # 0 floor, 1 background, 2 slip
    low = np.linspace(2.0, -2.0, M)
    high = -low
    x = np.empty((C, M, n))
    if one_sided is not None:
        ang = one_sided + rng.uniform(-0.3, 0.3, n)
    else:
        ang = rng.uniform(-np.pi, np.pi, n)
    pattern = 1.0 * np.cos(ang[None, :] - MIC_ANGLE[:, None])          # (C, n)
    level = rng.normal(0.0, 0.5, n)
    for t in range(n):
        if kind[t] == 0:
            x[:, :, t] = -12.0
        elif kind[t] == 1:
            x[:, :, t] = low[None, :] + level[t] + gains[:, None]
        else:
            x[:, :, t] = high[None, :] + level[t] + 1.0 + gains[:, None] + pattern[:, t, None]
    x += rng.normal(0.0, 0.05, x.shape)
    return x.astype(np.float32), kind == 2, ang


def rel(g):
    return g - g.mean()


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(0)
    frames, labels, offsets = [], [], []
    for _ in range(6):
        g = rel(rng.uniform(-0.7, 0.7, C))
        f, s, _ = grasp(rng, g, n=1500)
        frames.append(f)
        labels.append(s)
        offsets.append(g)
    return {m: cal.fit_constants(frames, labels, NAMES, 0.01, true_offsets=offsets, method=m,
                                 prior_frames=10.0, converge_frames=200)
            for m in cal.METHODS}


def test_streaming_equals_offline_and_is_causal(fitted):
    k = fitted["background"]
    rng = np.random.default_rng(1)
    f, _, _ = grasp(rng, rel(rng.uniform(-0.7, 0.7, C)), n=600)
    state = cal.CalibrationState(k)
    streamed = []
    for s in range(0, 600, 37):                 # ragged blocks, as a node receives them
        state.update(f[:, :, s:s + 37])
        streamed.append((min(s + 37, 600), state.offsets.copy()))
    ends = np.array([e for e, _ in streamed])
    offline = cal.offsets_at(f, ends, k)
    np.testing.assert_allclose(offline, np.array([o for _, o in streamed]), atol=1e-9)
    # Future audio cannot change a past estimate: scramble everything after frame 300.
    g = f.copy()
    g[:, :, 300:] = rng.normal(0.0, 3.0, g[:, :, 300:].shape)
    past = ends <= 300
    np.testing.assert_array_equal(cal.offsets_at(g, ends[past], k), offline[past])
    assert not np.allclose(cal.offsets_at(g, ends[~past], k), offline[~past])


def test_reset_forgets_the_grasp(fitted):
    k = fitted["background"]
    rng = np.random.default_rng(2)
    f, _, _ = grasp(rng, np.array([0.6, -0.6, 0.3, -0.3]), n=800)
    state = cal.CalibrationState(k)
    state.update(f)
    assert state.converged and np.abs(state.gain_db).max() > 1.0
    state.reset()
    assert not state.converged and state.weight == 0.0
    np.testing.assert_array_equal(state.offsets, np.zeros(C))
    x = np.ones((C, M, 5), dtype=np.float32)
    np.testing.assert_array_equal(state.apply(x), x)


def test_background_calibration_recovers_gains_and_converges(fitted):
    k = fitted["background"]
    rng = np.random.default_rng(3)
    g = rel(np.array([0.6, -0.5, 0.2, -0.1]))
    f, _, _ = grasp(rng, g, n=2000)
    state = cal.CalibrationState(k)
    state.update(f[:, :, :20])
    assert not state.converged
    state.update(f[:, :, 20:])
    assert state.converged
    assert np.max(np.abs(state.offsets - g)) < 0.05
    np.testing.assert_allclose(state.gain_db, state.offsets * 10.0 / np.log(10.0))
    assert k.convergence_s == pytest.approx(2.0)  # 200 frames of 10 ms (fixture)


def test_the_state_says_when_in_the_grasp_it_converged(fitted):
    """converged_after_s: the grasp's audio up to the frame whose acceptance met the
    criterion, the same however the frames arrive, and forgotten on a reset."""
    k = fitted["background"]
    rng = np.random.default_rng(5)
    f, _, _ = grasp(rng, rel(np.array([0.4, -0.4, 0.2, -0.2])), n=1500)
    dev, p, active = cal.frame_stats(f, k)
    w = cal.frame_weights(p, active, k)
    first = int(np.argmax(np.cumsum(w) >= k.converge_frames)) + 1   # frames up to it
    whole = cal.CalibrationState(k)
    assert whole.converged_after_s is None
    whole.update(f)
    ragged = cal.CalibrationState(k)
    for s in range(0, f.shape[2], 23):
        ragged.update(f[:, :, s:s + 23])
    assert whole.converged_at_frame == ragged.converged_at_frame == first
    assert whole.converged_after_s == pytest.approx(first * k.hop_s)
    whole.reset()
    assert whole.converged_after_s is None


def test_the_default_criterion_is_the_measured_one():
    """60 accepted frames with 10 pseudo-frames of prior (docs/model.md: measured)."""
    fields = {f.name: f.default for f in cal.dataclasses.fields(cal.CalibrationConstants)}
    assert fields["converge_frames"] == 60 and fields["prior_frames"] == 10.0


def _direction_of_slip(x, slip):
    """Direction read from the mean calibrated level pattern of slip frames."""
    lv = x[:, :, slip].mean(axis=1)                   # (C, n) mean over mels
    lv = lv - lv.mean(axis=0, keepdims=True)
    vec = np.array([np.cos(MIC_ANGLE) @ lv.mean(1), np.sin(MIC_ANGLE) @ lv.mean(1)])
    return np.arctan2(vec[1], vec[0]), np.hypot(*vec)


def test_one_sided_stream_does_not_bias_direction(fitted):
    rng = np.random.default_rng(4)
    g = rel(np.array([0.5, -0.4, 0.3, -0.4]))
    main = 1.0
    f, slip, _ = grasp(rng, g, n=3000, one_sided=main)
    _, clean_size = _direction_of_slip(f - g[:, None, None], slip)
    errors = {}
    for method in ("background", "slip"):
        state = cal.CalibrationState(fitted[method])
        state.update(f)
        errors[method] = np.max(np.abs(state.offsets - g))
        ang, size = _direction_of_slip(state.apply(f), slip)
        errors[method + "_dir"] = abs(np.angle(np.exp(1j * (ang - main))))
        errors[method + "_size"] = size / clean_size
    # The background estimate keeps the slip's level pattern, so its direction survives...
    assert errors["background"] < 0.05
    assert errors["background_dir"] < 0.1 and errors["background_size"] > 0.9
    # ...while averaging slip frames learns most of the one-sided direction away.
    assert errors["slip"] > 0.3 and errors["slip_size"] < 0.5


def test_constants_round_trip_and_refuse_a_mismatched_stream(fitted, tmp_path):
    k = fitted["background"]
    doc = json.loads(json.dumps(k.to_dict()))
    assert doc["convergence_s"] == pytest.approx(k.convergence_s)
    assert cal.CalibrationConstants.from_dict(doc) == k
    meta = {"model_type": "svm", "model_config": SvmConfig().to_dict(),
            "feature_config": FeatureConfig(n_mels=M).to_dict(), "channel_names": list(NAMES),
            "sample_rate": 16000.0, "window_s": 0.2, "window_samples": 3200,
            "epsilon_m_s": 0.005, "threshold": 0.5, "calibration": k.to_dict()}
    path = tmp_path / "c.pt"
    save_checkpoint(path, meta, {})
    back = cal.CalibrationConstants.from_dict(load_checkpoint(path).meta["calibration"])
    assert back == k
    back.check_stream(list(NAMES), M, 0.01)
    with pytest.raises(CheckpointMismatch, match="channels"):
        back.check_stream(["a", "b", "d", "c"], M, 0.01)
    with pytest.raises(CheckpointMismatch, match="mels"):
        back.check_stream(list(NAMES), M + 1, 0.01)
    with pytest.raises(CheckpointMismatch, match="hop"):
        back.check_stream(list(NAMES), M, 0.016)
    with pytest.raises(ValueError, match="unknown calibration keys"):
        cal.CalibrationConstants.from_dict({**doc, "extra": 1})
    # A checkpoint whose calibration does not fit its own channels or features is refused.
    for bad in ({**meta, "feature_config": FeatureConfig(n_mels=M + 2).to_dict()},
                {**meta, "channel_names": ["a", "b", "c", "e"]},
                {**meta, "calibration": {**doc, "gate_coef": [0.0]}}):
        with pytest.raises(ValueError, match="calibration"):
            save_checkpoint(tmp_path / "bad.pt", bad, {})


def test_bad_input_is_refused(fitted):
    k = fitted["background"]
    state = cal.CalibrationState(k)
    with pytest.raises(ValueError, match="frames must be"):
        state.update(np.zeros((C + 1, M, 3), dtype=np.float32))
    bad = np.zeros((C, M, 3), dtype=np.float32)
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        state.update(bad)
    assert state.n_frames == 0
    with pytest.raises(ValueError, match="method"):
        k.with_(method="median")
    with pytest.raises(ValueError, match="both slip and no-slip"):
        cal.fit_constants([np.zeros((C, M, 10))], [np.zeros(10, bool)], NAMES, 0.01)


def mixed_background_grasp(rng, gains, path_a, path_b, n=1500):
    """Like ``grasp``, but the background comes from two sources, each reaching every
    microphone through its own path (log-power ``path_a``, ``path_b`` per channel), mixed in
    a share that changes every 20 frames: the background is no longer common mode."""
    f, slip, ang = grasp(rng, gains, n=n)
    share = np.repeat(rng.uniform(0.0, 1.0, n // 20 + 1), 20)[:n]              # of source a
    mix = np.log(share[None, :] * np.exp(path_a)[:, None]
                 + (1.0 - share[None, :]) * np.exp(path_b)[:, None])         # (C, n)
    background = (f[0].mean(axis=0) > -11.0) & ~slip
    f[:, :, background] += mix[:, None, background].astype(np.float32)
    return f, slip, ang


def test_self_check_trusts_a_pure_coupling_and_not_a_background_of_mixed_paths(fitted):
    """spread_db: low when every background frame of a channel moves alike (a gain), high
    when each channel's deviation depends on the mix of background sources (a path)."""
    k = fitted["background"]
    assert k.trust_spread_db is not None and 0.0 < k.trust_spread_db < 0.5
    rng = np.random.default_rng(11)
    g = rel(np.array([0.5, -0.4, 0.3, -0.4]))
    pure, _, _ = grasp(rng, g, n=1500)
    path = rel(np.array([0.7, -0.7, 0.7, -0.7]))                  # +-3 dB, source a only
    mixed, _, _ = mixed_background_grasp(rng, g, path, np.zeros(C))
    states = {}
    for name, f in (("pure", pure), ("mixed", mixed)):
        s = cal.CalibrationState(k)
        s.update(f[:, :, :10])
        assert not s.converged and s.trusted is None           # not known before convergence
        s.update(f[:, :, 10:])
        assert s.converged
        states[name] = s
    assert states["pure"].spread_db < 0.2 < 0.6 < states["mixed"].spread_db
    assert states["pure"].trusted is True and states["mixed"].trusted is False
    # The untrusted estimate is the biased one: half the path's mean share is in it.
    err = {n: np.abs(s.offsets - g).max() for n, s in states.items()}
    assert err["pure"] < 0.05 < 0.2 < err["mixed"]
    # Constants without a threshold (fitted before the check) never judge.
    s = cal.CalibrationState(k.with_(trust_spread_db=None))
    s.update(mixed)
    assert s.trusted is None and s.spread_db == pytest.approx(states["mixed"].spread_db)
    s.reset()
    assert s.spread_db == 0.0 and s.trusted is None


def test_self_check_streams_as_offline_and_its_threshold_is_fitted(fitted):
    k = fitted["background"]
    rng = np.random.default_rng(12)
    f, _, _ = mixed_background_grasp(rng, rel(rng.uniform(-0.7, 0.7, C)),
                                     rel(rng.uniform(-0.7, 0.7, C)), np.zeros(C), n=600)
    state, ends, spreads = cal.CalibrationState(k), [], []
    for s in range(0, 600, 41):
        state.update(f[:, :, s:s + 41])
        ends.append(min(s + 41, 600))
        spreads.append(state.spread_db)
    np.testing.assert_allclose(cal.spread_at(f, np.array(ends), k), spreads, atol=1e-9)
    with pytest.raises(ValueError, match="within"):
        cal.spread_at(f, [601], k)
    # The threshold: margin x the 95th percentile of the training grasps' peaks once
    # converged; every constant but the threshold is the same for any percentile or margin.
    rng = np.random.default_rng(0)
    frames, labels, offsets = [], [], []
    for _ in range(6):                            # the fixture's training grasps, again
        g = rel(rng.uniform(-0.7, 0.7, C))
        fr, sl, _ = grasp(rng, g, n=1500)
        frames.append(fr)
        labels.append(sl)
        offsets.append(g)
    kw = dict(true_offsets=offsets, prior_frames=10.0, converge_frames=200)

    def peak(fr):                                 # the largest spread once converged
        w = cal.frame_weights(*cal.frame_stats(fr, k)[1:], k)
        return cal.spread_at(fr, np.flatnonzero(np.cumsum(w) >= k.converge_frames) + 1,
                             k).max()
    peaks = [peak(fr) for fr in frames]
    assert k.trust_spread_db == pytest.approx(
        cal.TRUST_MARGIN * np.percentile(peaks, cal.TRUST_PERCENTILE))
    wide = cal.fit_constants(frames, labels, NAMES, 0.01, trust_margin=3.0, **kw)
    assert wide.trust_spread_db == pytest.approx(k.trust_spread_db * 3.0 / cal.TRUST_MARGIN)
    assert wide.with_(trust_spread_db=None) == k.with_(trust_spread_db=None)
    with pytest.raises(ValueError, match="margin"):
        cal.trust_threshold(frames, k, margin=0.5)


def test_old_calibration_documents_without_the_self_check_still_load(fitted, tmp_path):
    k = fitted["background"]
    old = json.loads(json.dumps(k.to_dict()))
    del old["trust_spread_db"]                     # a checkpoint written before the check
    back = cal.CalibrationConstants.from_dict(old)
    assert back.trust_spread_db is None and back == k.with_(trust_spread_db=None)
    assert cal.meta_problems(old, list(NAMES), M, 0.01) == []
    meta = {"model_type": "svm", "model_config": SvmConfig().to_dict(),
            "feature_config": FeatureConfig(n_mels=M).to_dict(), "channel_names": list(NAMES),
            "sample_rate": 16000.0, "window_s": 0.2, "window_samples": 3200,
            "epsilon_m_s": 0.005, "threshold": 0.5, "calibration": old}
    save_checkpoint(tmp_path / "old.pt", meta, {})
    loaded = load_checkpoint(tmp_path / "old.pt").meta["calibration"]
    assert cal.CalibrationConstants.from_dict(loaded).trust_spread_db is None
    assert json.loads(json.dumps(k.to_dict()))["trust_spread_db"] == k.trust_spread_db
    for bad in (-1.0, 0.0, float("nan"), "1", True):
        assert "trust_spread_db" in cal.meta_problems({**old, "trust_spread_db": bad},
                                                      list(NAMES), M, 0.01)[0]
