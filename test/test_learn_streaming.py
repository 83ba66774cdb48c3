"""Incremental log-mel features: block-size invariance, reference decimation, refusals."""

import numpy as np
import pytest
from scipy import signal as sps

from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.incremental_features import (StreamingLogMel, decimation_factor,
                                                  decimation_filter, stream_logmel)


def noisy_trial(n=24000, c=3, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None] / 48000.0
    tone = np.sin(2 * np.pi * np.array([300.0, 2500.0, 7000.0][:c]) * t)
    return (0.05 * rng.standard_normal((n, c)) + 0.1 * tone).astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_blocks_give_the_offline_frames(seed):
    cfg = FeatureConfig()
    audio = noisy_trial(seed=seed)
    offline = stream_logmel(audio, cfg, 48000.0)
    assert offline.shape == (1 + (audio.shape[0] // 3 - cfg.n_fft) // cfg.hop, 3, cfg.n_mels)
    live = StreamingLogMel(cfg, 48000.0, 3)
    rng = np.random.default_rng(seed + 10)
    out, i = [], 0
    while i < audio.shape[0]:
        n = int(rng.choice([1, 2, 7, 160, 479, 480, 481, 3000]))
        out.append(live.push(audio[i:i + n]))
        i += n
    got = np.concatenate(out)
    assert got.shape == offline.shape
    np.testing.assert_allclose(got, offline, atol=1e-4, rtol=0)
    assert live.n_frames == offline.shape[0]


def test_frames_match_an_independent_causal_filter_and_stft():
    cfg = FeatureConfig(n_mels=20)
    audio = noisy_trial(n=9600, c=2)
    got = stream_logmel(audio, cfg, 48000.0)
    h = decimation_filter(3)
    pcm = sps.lfilter(h.astype(np.float64), [1.0], audio.astype(np.float64), axis=0)[2::3]
    k = np.arange(got.shape[0])
    win = sps.get_window("hann", cfg.n_fft, fftbins=True)
    frames = np.stack([pcm[j * cfg.hop:j * cfg.hop + cfg.n_fft] for j in k])   # (K, N, C)
    power = np.abs(np.fft.rfft(frames * win[None, :, None], axis=1)) ** 2     # (K, F, C)
    from aslip_ros.learn.features import mel_filterbank
    ref = np.log(np.maximum(np.einsum("mf,kfc->kcm", mel_filterbank(cfg), power),
                            cfg.log_floor))
    np.testing.assert_allclose(got, ref, atol=2e-3, rtol=0)


def test_frame_ends_and_reset():
    cfg = FeatureConfig()
    f = StreamingLogMel(cfg, 48000.0, 1)
    assert f.frame_samples == 1536 and f.frame_step_samples == 480
    assert f.push(np.zeros((1535, 1), np.float32)).shape[0] == 0
    assert f.push(np.zeros((1, 1), np.float32)).shape[0] == 1
    assert list(f.frame_end_samples([0, 1])) == [1536, 2016]
    f.push(np.zeros((479, 1), np.float32))
    f.reset()
    assert f.n_frames == 0 and f.push(np.zeros((1535, 1), np.float32)).shape[0] == 0
    x = noisy_trial(n=4800, c=1)
    f.reset()
    np.testing.assert_allclose(f.push(x), stream_logmel(x, cfg, 48000.0), atol=1e-5)


def test_unsupported_rate_ratios_are_refused_with_a_clear_error():
    assert decimation_factor(48000.0, 16000.0) == 3
    assert decimation_factor(16000.0, 16000.0) == 1
    for rate in (44100.0, 8000.0, 40000.0):
        with pytest.raises(ValueError, match="integer multiple"):
            StreamingLogMel(FeatureConfig(), rate, 2)
    with pytest.raises(ValueError, match="positive"):
        decimation_factor(float("nan"), 16000.0)
    f = StreamingLogMel(FeatureConfig(), 48000.0, 2)
    with pytest.raises(ValueError, match=r"\(n, 2\)"):
        f.push(np.zeros((10, 3), np.float32))


# ------------------------------------------------------------------ aslip evaluate (stream)

@pytest.fixture(scope="module")
def stream_dataset(tmp_path_factory):
    from aslip_ros.data.export import export
    from aslip_ros.data.synthetic import write_synthetic_bag
    from test_learn_streaming_model import NAMES
    root = tmp_path_factory.mktemp("stream_eval")
    for i, v in enumerate([(0.02, 0.0, 0.0), (0.0, 0.0, -0.03), (0.0, 0.0, 0.0)]):
        write_synthetic_bag(root / "bags" / f"t{i}", duration_s=1.2, slip_velocity=v,
                            seed=i, channel_names=NAMES)
    export([root / "bags"], root / "ds", window_s=0.2, hop_s=0.1, progress=False)
    return root / "ds"


def test_evaluate_scores_a_streaming_checkpoint_at_each_window_end(stream_dataset, tmp_path):
    """Each window gets the estimate a live StreamingPredictor fed the trial block by block
    had produced last when the window ended; the window's own label scores it."""
    from aslip_ros.learn.data_io import open_dataset
    from aslip_ros.learn.evaluate import evaluate_checkpoint, predict_split
    from aslip_ros.learn.inference.stream_predictor import StreamingPredictor
    from test_learn_streaming_model import blocks, make_checkpoint
    ckpt = make_checkpoint(tmp_path / "s.pt", threshold=0.5)
    p = predict_split(ckpt, stream_dataset, "all")
    ds = open_dataset(stream_dataset)
    assert p["index"].size == len(ds.windows) > 20 and p["window_s"] == ds.window_s
    assert len(set(p["prob"].round(5))) > 5
    for k in range(len(ds.trials)):
        live = StreamingPredictor.from_checkpoint(ckpt)
        ests = [e for b in blocks(np.asarray(ds.audio(k)), 480, start_index=0)
                for e in live.push(b)]
        at = np.array([e.sample_index for e in ests])
        rows = np.flatnonzero(p["trial"] == k)
        for r in rows:
            end = int(ds.windows["start"][p["index"][r]]) + ds.window_samples
            e = ests[np.flatnonzero(at <= end)[-1]]
            assert end - e.sample_index < 480                 # at most one hop old
            assert p["prob"][r] == pytest.approx(e.prediction.probability, abs=1e-5)
            np.testing.assert_allclose(p["raw_velocity"][r], e.raw_velocity, atol=1e-6)
        np.testing.assert_allclose(p["true_velocity"][rows],
                                   ds.velocity(p["index"][rows]), atol=0)
    res = evaluate_checkpoint(ckpt, stream_dataset, "all")
    assert res["model_type"] == "aslip_stream" and res["calibration"] is None
    assert res["overall"]["n_windows"] == p["index"].size
    assert 0.0 <= res["overall"]["detection_accuracy"] <= 1.0
    assert res["overall"]["window_s"] == ds.window_s and res["overall"]["threshold"] == 0.5


def test_aslip_evaluate_cli_on_a_streaming_checkpoint(stream_dataset, tmp_path, capsys):
    import json

    from aslip_ros import cli
    from test_learn_streaming_model import make_checkpoint
    ckpt = make_checkpoint(tmp_path / "s.pt")
    out = tmp_path / "m.json"
    assert cli.main(["evaluate", "--checkpoint", str(ckpt), "--dataset", str(stream_dataset),
                     "--split", "all", "--threads", "1", "--json", str(out)]) == 0
    assert "aslip_stream" in capsys.readouterr().out
    assert json.loads(out.read_text())["overall"]["n_windows"] > 20
    other = make_checkpoint(tmp_path / "o.pt", channel_names=["x0", "x1"])
    assert cli.main(["evaluate", "--checkpoint", str(other), "--dataset", str(stream_dataset),
                     "--split", "all", "--threads", "1"]) == 1
    assert "x0" in capsys.readouterr().err


def test_warm_up_and_feed_leave_a_predictor_as_fresh_as_a_new_one(tmp_path):
    """The node's path: warm_up, then feed (no gate) with reset where the node restarts."""
    from aslip_ros.learn.inference.stream_predictor import StreamingPredictor
    from test_learn_streaming_model import audio, blocks, make_checkpoint, outputs
    ckpt = make_checkpoint(tmp_path / "s.pt")
    bl = blocks(audio(n=14400, seed=2), 480)
    ref = StreamingPredictor.from_checkpoint(ckpt)
    want = outputs([e for b in bl for e in ref.push(b)])
    p = StreamingPredictor.from_checkpoint(ckpt)
    p.warm_up()
    assert p.fresh and p.resets == 0
    got = outputs([e for b in bl for e in p.feed(b)])
    assert got[0].size == want[0].size == 27
    np.testing.assert_allclose(got[0], want[0], atol=1e-6)
    assert not p.fresh
    p.reset("gap")
    assert p.fresh and p.resets == 1 and p.last_reset_reason == "gap"
    again = [e for b in bl[5:] for e in p.feed(b)]
    assert again[0].sample_index == bl[5].first_sample_index + 1536     # a new history


# ------------------------------------------------------------------ training device

@pytest.fixture(scope="module")
def stream_train_dataset(tmp_path_factory):
    from aslip_ros.data.export import export
    from aslip_ros.data.synthetic import write_synthetic_bag
    from test_learn_streaming_model import NAMES
    root = tmp_path_factory.mktemp("stream_train")
    for i in range(6):
        v = [(0.02, 0.0, 0.0), (0.0, 0.0, -0.03), (0.0, 0.0, 0.0)][i % 3]
        write_synthetic_bag(root / "bags" / f"t{i}", duration_s=1.2, slip_velocity=v,
                            seed=10 + i, channel_names=NAMES)
    export([root / "bags"], root / "ds", window_s=0.2, hop_s=0.1, progress=False)
    return root / "ds"


def test_stream_training_device(stream_train_dataset, monkeypatch):
    """auto trains on the CPU where torch sees no GPU; cuda there is a clear error; the
    checkpoint's tensors are CPU tensors and its provenance names the device."""
    import torch

    from aslip_ros.learn.data_io import open_dataset
    from aslip_ros.learn.training.stream import StreamTrainConfig, train_stream
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    ds = open_dataset(stream_train_dataset)
    cfg = dict(epochs=1, steps_per_epoch=2, batch_size=4, seq_frames=40, progress=False)
    meta, tensors, _ = train_stream(ds, StreamTrainConfig(device="auto", **cfg),
                                    log=lambda m: None)
    assert meta["provenance"]["training"]["device"] == "cpu"
    assert meta["train_config"]["device"] == "auto"
    assert all(t.device.type == "cpu" for t in tensors.values())
    with pytest.raises(ValueError, match="no CUDA GPU"):
        train_stream(ds, StreamTrainConfig(device="cuda", **cfg), log=lambda m: None)
