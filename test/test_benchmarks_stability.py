"""Stability pipeline on tiny synthetic data, breakdown detection, degenerate batches."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from aslip_ros.data.dataset import WINDOW_DTYPE, DatasetWriter
from benchmarks import stability
from benchmarks.common import DataPlan, Recipe
from aslip_ros.learn.data_io import open_dataset
from aslip_ros.learn.training.config import TrainConfig
from aslip_ros.learn.models.aslip_cnn_fit import train_cnn


def test_breakdown_on_hand_made_curves():
    levels = [0, 1, 2, 4, 8]
    assert stability.breakdown(levels, [90, 85, 72, 69, 40], [10, 12, 14, 16, 40]) == {
        "level": 4, "reason": "detection 69.0 % < 70 %"}
    b = stability.breakdown(levels, [90, 90, 90, 90, 90], [10, 20, 31, 40, 50])
    assert b["level"] == 2 and "direction" in b["reason"]
    assert stability.breakdown(levels, [90] * 5, [10] * 5) is None
    # missing values (no slip windows in a bin) never count as a failure
    assert stability.breakdown(["a", "b"], [None, 80], [None, None]) is None


def test_stability_end_to_end(tmp_path):
    data = DataPlan(root=tmp_path / "data", synthetic=True, progress=False, synthetic_s=2.0)
    recipe = Recipe(epochs=1, patience=1, threads=1, progress=False, svm_max_train=300)
    cfg = stability.StabilityConfig(
        out=tmp_path / "stab", data=data, recipe=recipe, ablation_out=tmp_path / "abl",
        stressors=("dead_mic", "slip_speed", "object_out", "gain_mismatch"), seeds=(0, 1),
        gain_db=(0.0, 10.0))
    stability.Stability(cfg).run()
    out = json.loads((cfg.out / "stability.json").read_text())
    for name in cfg.stressors:
        sw = out["stressors"][name]
        assert len(sw["levels"]) == len(sw["results"]) > 0
        assert set(sw["breakdown"]) == {"cnn", "svm"}
        assert (cfg.out / f"{name}.png").stat().st_size > 1000
    assert out["stressors"]["dead_mic"]["levels"][:4] == [0, 1, 2, 3]
    seeds = out["training_seeds"]
    assert [r["seed"] for r in seeds["runs"]] == [0, 1]
    assert set(seeds["summary"]["dir_mae_deg"]) >= {"mean", "std"}


# --- degenerate batches through learn.training.train --------------------------------------

def _degenerate_dataset(path, mode: str, n_trials: int = 6, seconds: float = 1.0):
    """4-channel noise with degenerate labels: all no-slip, antipodal directions, or slip
    windows whose true velocity is exactly zero."""
    sr, n_win, hop = 16000.0, 3200, 1600
    rng = np.random.default_rng(0)
    n = int(sr * seconds)
    with DatasetWriter(path, overwrite=True) as w:
        for k in range(n_trials):
            w.begin_trial(4).append((0.01 * rng.standard_normal((n, 4))).astype(np.float32))
            rows = []
            for j, s in enumerate(range(0, n - n_win + 1, hop)):
                if mode == "noslip":
                    v, slip = (0.0, 0.0), False
                elif mode == "antipodal":
                    v, slip = ((0.02, 0.0) if j % 2 == 0 else (-0.02, 0.0)), True
                else:  # zero magnitude
                    v, slip = (0.0, 0.0), True
                rows.append((k, s, v[0], v[1], 0.0, float(np.hypot(*v)), slip))
            w.end_trial({"id": f"d-{k}", "object": "box", "pad": "textured", "layout": "4mic",
                         "condition": "robot_off", "induced": "external", "source_bag": "",
                         "label_source": "synthetic"}, np.array(rows, dtype=WINDOW_DTYPE))
        w.finish(sample_rate=sr, channel_names=["a", "b", "c", "d"], layout="4mic",
                 window_s=0.2, hop_s=0.1, epsilon_m_s=0.005, n_window_samples=n_win)
    return path


@pytest.mark.parametrize("mode", ["noslip", "antipodal", "zero_magnitude"])
def test_degenerate_batches_train_without_nan(tmp_path, mode):
    ds = open_dataset(_degenerate_dataset(tmp_path / mode, mode))
    cfg = TrainConfig(stage="scratch", epochs=4, batch_size=8, patience=10, threads=1,
                      progress=False)
    res = train_cnn(ds, cfg, log=lambda m: None)
    losses = [h["train_loss"] for h in res.history] + [h["val_loss"] for h in res.history]
    assert all(np.isfinite(losses)), losses
    # no divergence: the loss does not blow up over the epochs
    assert res.history[-1]["train_loss"] <= 3.0 * res.history[0]["train_loss"] + 1e-6
    for k, t in res.tensors.items():
        if t.is_floating_point():
            assert torch.isfinite(t).all(), k


def test_a_breakdown_line_has_its_methods_colour_and_a_legend_entry(tmp_path, monkeypatch):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgba
    kept = {}
    monkeypatch.setattr(plt, "close", lambda fig: kept.setdefault("fig", fig))
    sweep = {"x_label": "x", "levels": [0, 1, 2],
             "results": [{"cnn": {"det_pct": 95, "dir_mae_deg": 20},
                          "svm": {"det_pct": 95, "dir_mae_deg": 20},
                          "svm_seen": {"det_pct": 95, "dir_mae_deg": 20}}] * 3,
             "breakdown": {"cnn": {"level": 1}, "svm": {"level": 2}}}
    stability.plot_stressor("s", sweep, tmp_path / "s.png")
    assert (tmp_path / "s.png").is_file()
    for ax in kept["fig"].axes:
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        for m in ("cnn", "svm"):
            curve, bd = lines[m], lines[f"{m} breaks down"]
            assert to_rgba(bd.get_color()) == to_rgba(curve.get_color()), m
            assert bd.get_xdata()[0] == sweep["levels"].index(sweep["breakdown"][m]["level"])
        assert to_rgba(lines["svm_seen"].get_color()) == to_rgba(lines["svm"].get_color())
        assert to_rgba(lines["cnn"].get_color()) != to_rgba(lines["svm"].get_color())
    legend = [t.get_text() for t in kept["fig"].axes[0].get_legend().get_texts()]
    assert {"cnn breaks down", "svm breaks down"} <= set(legend)
