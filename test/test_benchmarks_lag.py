"""Lag benchmark: the delay measures on signals with known delays, and a tiny end-to-end run."""

import json

import numpy as np
import pytest

from benchmarks import lag


def test_onset_delay_finds_the_first_firing_hop_and_counts_misses():
    t = np.arange(300) * 0.01
    slip = np.zeros(300, bool)
    slip[50:100] = True          # onset at 0.5 s
    slip[200:260] = True         # onset at 2.0 s, never detected
    fired = np.zeros(300, bool)
    fired[53:110] = True
    d = lag.onset_delays(t, slip, fired)
    assert len(d) == 2 and d[0] == pytest.approx(0.03) and np.isnan(d[1])
    slip[110:120] = True         # 100 ms after a slip ended: not a clean onset
    assert len(lag.onset_delays(t, slip, fired)) == 2


@pytest.mark.parametrize("delay", [0, 40, 95, 180])
def test_tracking_delay_recovers_a_known_shift(delay):
    rng = np.random.default_rng(delay)
    n = 3000
    true = np.zeros((n, 2))
    for s in range(100, n - 200, 300):            # pushes of random direction
        true[s:s + 120] = rng.normal(0, 0.03, 2)
    k = int(round(delay / 10))
    pred = np.roll(true, k, axis=0) + rng.normal(0, 0.002, (n, 2))
    lag_s, corr = lag.tracking_delay([(pred, true)], 0.01)
    assert lag_s * 1e3 == pytest.approx(delay, abs=6) and corr > 0.9


def test_score_counts_false_alarms_only_away_from_slip():
    rate, n_hops = 48000.0, 1000
    v = np.zeros((n_hops * lag.HOP, 2))
    v[300 * lag.HOP:400 * lag.HOP] = (0.02, 0.0)
    ends = (np.arange(n_hops) + 1) * lag.HOP
    p = np.zeros(n_hops)
    p[302:405] = 0.9               # detection, trailing 50 ms: not a false alarm
    p[700:705] = 0.9               # a false alarm
    p[800:802] = 0.9               # another
    vel = np.zeros((n_hops, 2), np.float32)
    vel[302:405] = (0.02, 0.0)
    out = {"end": ends, "p": p, "v": vel, "threshold": 0.5}
    trial = {"v": v, "rate": rate}
    r = lag.score_method([out], [trial], 0.005)
    assert r["n_onsets"] == 1 and r["onset_delay_ms_median"] == pytest.approx(20.0)
    assert r["direction_mae_deg"] < 90        # zero raw velocity at 300/301 counts as 180
    assert r["tracking_delay_ms"] == pytest.approx(20.0, abs=6)
    minutes = r["no_slip_minutes"]
    assert 0.1 < minutes < 10.0 / 60 * 1.01
    assert r["false_alarms_per_min"] == pytest.approx(2 / (866 * 0.01 / 60), abs=0.01)


def test_end_to_end_on_a_short_scene_run(tmp_path):
    """A tiny streaming checkpoint (untrained) through the whole benchmark."""
    import torch

    from aslip_ros.learn.checkpoint import save_checkpoint
    from aslip_ros.learn.features import FeatureConfig
    from aslip_ros.learn.models.aslip_stream import StreamConfig, StreamNet
    from aslip_ros.scene.layouts import get_layout
    torch.manual_seed(0)
    names = list(get_layout("4mic").channel_names)
    fcfg = FeatureConfig()
    cfg = StreamConfig(n_channels=len(names), n_mels=fcfg.n_mels, embed=8, hidden=4)
    net = StreamNet(cfg)
    net.set_normalization(np.full(40, -10.0), np.full(40, 3.0))
    meta = {"model_type": "aslip_stream", "model_config": cfg.to_dict(),
            "feature_config": fcfg.to_dict(), "channel_names": names, "sample_rate": 48000.0,
            "window_s": 0.032, "window_samples": 1536, "hop_s": 0.01, "epsilon_m_s": 0.005,
            "threshold": 0.5, "label": {"kind": "slip_velocity_now"}}
    cache = tmp_path / "cache"
    cache.mkdir()
    save_checkpoint(cache / "stream.pt", meta, net.state_dict())
    out = tmp_path / "out"
    assert lag.main(["--out", str(out), "--cache", str(cache), "--models",
                     str(tmp_path / "none"), "--trials", "1", "--duration", "2",
                     "--n-iter", "20"]) == 0
    res = json.loads((out / "lag.json").read_text())
    assert [r["name"] for r in res["rows"]] == ["stream"]
    assert res["rows"][0]["hop_p99_ms"] > 0
    assert (out / "lag.png").stat().st_size > 1000 and "stream" in (out / "lag.md").read_text()
    assert lag.main(["--cache", str(tmp_path / "no"), "--models", str(tmp_path / "no")]) == 1
