"""Cheap proxy read-outs that show what each mechanism of the sound model is for.

Not a model of the paper's network: windows of constant slip velocity are rendered with the
scene's own synthesizer, reduced to log band energies and inter-channel level differences,
and read out by k-nearest neighbours (detection, direction, magnitude). Switching one
mechanism off and watching a named number move is the evidence docs/scene.md records.

The default scene couples every microphone differently in every grasp (``gain_mismatch_db``).
The proxy has no calibration of its own, so by default it divides each trial's true gains
out (``ProxyConfig.oracle_gains``), as a converged per-grasp calibration would: mechanisms are
read the way a calibrated model hears them, and two rows show what the coupling costs
uncalibrated and what the scene was without it (:data:`~.physics.UNCOUPLED`).
Run ``python -m aslip_ros.scene.ablation`` for the table.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace

import numpy as np

from .layouts import DEFAULT_LAYOUT, get_layout, get_object, get_pad
from .physics import UNCOUPLED, Acoustics, Synth

#: Edges of the proxy's frequency bands [Hz]: fine below 600 Hz where ridge lines live,
#: log-spaced above.
_FINE = np.arange(0.0, 610.0, 10.0)
_COARSE = np.geomspace(620.0, 11000.0, 10)


@dataclass(frozen=True)
class ProxyConfig:
    """One proxy experiment: what to render and how much."""

    layout: str = DEFAULT_LAYOUT
    pad: str = "textured"
    object: str = "chips_can"
    condition: str = "robot_off"       # robot_moving adds arm motion during every window
    acoustics: Acoustics = Acoustics()
    n_trials: int = 8                  # trials 0..n-3 train, the last two test
    windows_per_trial: int = 48
    window_s: float = 0.2
    sample_rate: float = 24000.0       # proxy only; bands stay below 11 kHz
    slip_fraction: float = 0.5
    speed_range_m_s: tuple[float, float] = (0.002, 0.1)
    seed: int = 0
    oracle_gains: bool = True          # divide each trial's true microphone gains out


def window_features(x: np.ndarray, fs: float) -> np.ndarray:
    """Log band energies of the channel mean plus per-channel level offsets, one vector."""
    n = x.shape[0]
    spec = np.abs(np.fft.rfft(x * np.hanning(n)[:, None], axis=0)) ** 2
    freqs = np.fft.rfftfreq(n, 1.0 / fs)
    edges = np.concatenate([_FINE, _COARSE])
    idx = np.clip(np.searchsorted(edges, freqs) - 1, 0, len(edges) - 2)
    valid = (freqs >= edges[0]) & (freqs < edges[-1])
    bands = np.zeros((len(edges) - 1, x.shape[1]))
    np.add.at(bands, idx[valid], spec[valid])
    logb = np.log10(bands + 1e-18)
    common = logb.mean(axis=1)
    # Level of each channel in three broad regions, relative to the channel mean: the only
    # place the sign of the slip can show up.
    regions = [(0, len(_FINE) - 1), (len(_FINE) - 1, len(_FINE) + 4), (len(_FINE) + 4, None)]
    diffs = []
    for lo, hi in regions:
        e = np.log10(bands[lo:hi].sum(axis=0) + 1e-18)
        diffs.append(3.0 * (e - e.mean()))
    total = np.log10(spec.sum() + 1e-18)
    return np.concatenate([common] + diffs + [[total]])


def render_windows(cfg: ProxyConfig) -> dict[str, np.ndarray]:
    """Feature rows and truths for ``n_trials * windows_per_trial`` windows."""
    layout, pad, obj = get_layout(cfg.layout), get_pad(cfg.pad), get_object(cfg.object)
    fs = cfg.sample_rate
    n_win = int(round(cfg.window_s * fs))
    lead = int(round(0.05 * fs))          # discarded: lets filters settle on the new speed
    feats, vel, trial = [], [], []
    for k in range(cfg.n_trials):
        rng = np.random.default_rng([cfg.seed, k, 0xAB1])
        synth = Synth(layout, pad, obj, cfg.acoustics, fs, seed=1000 * cfg.seed + k)
        start = 0
        for _ in range(cfg.windows_per_trial):
            if rng.random() < cfg.slip_fraction:
                phi = rng.uniform(-np.pi, np.pi)
                speed = rng.uniform(*cfg.speed_range_m_s)
                v = speed * np.array([np.cos(phi), np.sin(phi)])
            else:
                v = np.zeros(2)
            touch = float(rng.random() < 0.5) * rng.uniform(0.4, 1.0)
            if cfg.condition == "robot_moving":
                d = rng.standard_normal(3)
                v_arm = rng.uniform(0.02, 0.15) * d / np.linalg.norm(d)
            else:
                v_arm = np.zeros(3)
            m = n_win + lead
            x = synth.render(start, np.tile(v, (m, 1)), np.tile(v_arm, (m, 1)),
                             np.full(m, touch))
            start += m
            x = x[lead:].astype(float)
            if cfg.oracle_gains:
                x = x / synth.gain
            feats.append(window_features(x, fs))
            vel.append(v)
            trial.append(k)
    return {"x": np.array(feats), "v": np.array(vel), "trial": np.array(trial)}


def _knn(train_x: np.ndarray, test_x: np.ndarray, k: int) -> np.ndarray:
    d = ((test_x[:, None, :] - train_x[None, :, :]) ** 2).sum(axis=2)
    return np.argsort(d, axis=1)[:, :k]


def evaluate(cfg: ProxyConfig, k: int = 7, epsilon_m_s: float = 0.001) -> dict[str, float]:
    """Detection accuracy [%], direction MAE [deg], sign flips [%], magnitude RMSE [mm]."""
    data = render_windows(cfg)
    x, v, trial = data["x"], data["v"], data["trial"]
    test = trial >= cfg.n_trials - 2
    mu, sd = x[~test].mean(axis=0), x[~test].std(axis=0) + 1e-9
    xs = (x - mu) / sd
    speed = np.hypot(v[:, 0], v[:, 1])
    slip = speed > epsilon_m_s
    nn = _knn(xs[~test], xs[test], k)
    det = np.mean((slip[~test][nn].mean(axis=1) > 0.5) == slip[test]) * 100.0
    # The simplest detector: one threshold on total energy, the best one on the train set.
    energy = x[:, -1]
    cands = np.unique(energy[~test])
    acc = [np.mean((energy[~test] > c) == slip[~test]) for c in cands]
    thr = cands[int(np.argmax(acc))]
    det_energy = np.mean((energy[test] > thr) == slip[test]) * 100.0
    # Direction and magnitude are read out among slip windows only, as in the paper, and
    # along the two routes the scene offers: the folded angle atan2(|vz|, |vx|) from the
    # common spectrum (ridge lines), the signs from all features (level offsets mostly).
    tr_s, te_s = ~test & slip, test & slip
    n_common = len(_FINE) + len(_COARSE) - 2
    unit = v[tr_s] / speed[tr_s, None]
    nn_c = _knn(xs[tr_s][:, :n_common], xs[te_s][:, :n_common], k)
    fold = np.arctan2(np.abs(unit[:, 1]), np.abs(unit[:, 0]))[nn_c].mean(axis=1)
    fold_t = np.arctan2(np.abs(v[te_s, 1]), np.abs(v[te_s, 0]))
    nn_l = _knn(xs[tr_s], xs[te_s], k)
    signs = np.sign(unit[nn_l].mean(axis=1))
    signs[signs == 0] = 1.0
    pred = signs * np.column_stack([np.cos(fold), np.sin(fold)])
    ang_p = np.arctan2(pred[:, 1], pred[:, 0])
    ang_t = np.arctan2(v[te_s, 1], v[te_s, 0])
    err = np.degrees(np.abs(np.angle(np.exp(1j * (ang_p - ang_t)))))
    mag_p = speed[tr_s][nn_c].mean(axis=1)
    mag_rmse = np.sqrt(np.mean((mag_p - speed[te_s]) ** 2)) * cfg.window_s * 1e3
    return {"det_pct": float(det), "energy_det_pct": float(det_energy),
            "dir_mae_deg": float(err.mean()),
            "flip_pct": float(np.mean(err > 90.0) * 100.0),
            "fold_mae_deg": float(np.degrees(np.abs(fold - fold_t)).mean()),
            "mag_rmse_mm": float(mag_rmse)}


def ablation_table(quick: bool = False) -> list[tuple[str, str, dict[str, float]]]:
    """Every ablation as (mechanism, setting, metrics). ``quick`` uses fewer windows."""
    base = ProxyConfig(windows_per_trial=32 if quick else 48)
    ac = base.acoustics
    dirn = replace(base, slip_fraction=1.0, speed_range_m_s=(0.01, 0.1))
    slow = replace(base, speed_range_m_s=(0.0005, 0.006))
    rows = [
        ("reference", "4mic textured", dirn),
        ("texture lines", "smooth pad", replace(dirn, pad="smooth")),
        ("smooth-pad spread", "smooth pad, source as localised as on ridges",
         replace(dirn, pad="smooth", acoustics=replace(ac, smooth_edge_fraction=1.0))),
        ("leading-edge level", "no source shift",
         replace(dirn, acoustics=replace(ac, leading_edge_shift_m=0.0))),
        ("contact wander", "no wander",
         replace(dirn, acoustics=replace(ac, contact_wander_m=0.0))),
        ("per-grasp coupling", "uncalibrated: true gains left in",
         replace(dirn, oracle_gains=False)),
        ("per-grasp coupling", "none (scene version 2)", replace(dirn, acoustics=UNCOUPLED)),
        ("mic baseline", "2mic_corners", replace(dirn, layout="2mic_corners")),
        ("mic baseline", "2mic_same_finger", replace(dirn, layout="2mic_same_finger")),
        ("mic baseline", "2mic_centered", replace(dirn, layout="2mic_centered")),
        ("tip brightness", "2mic_centered, none",
         replace(dirn, layout="2mic_centered", acoustics=replace(ac, tip_brightness=0.0))),
        ("robot noise", "4mic arm moving", replace(dirn, condition="robot_moving")),
        ("robot noise", "4mic arm moving, robot noise off",
         replace(dirn, condition="robot_moving", acoustics=replace(ac, robot_level=0.0))),
        ("robot noise", "centered arm moving",
         replace(dirn, layout="2mic_centered", condition="robot_moving")),
        ("robot noise", "centered arm moving, robot noise off",
         replace(dirn, layout="2mic_centered", condition="robot_moving",
                 acoustics=replace(ac, robot_level=0.0))),
        ("handling noise", "slow slip", slow),
        ("handling noise", "slow slip, no handling noise",
         replace(slow, acoustics=replace(ac, handling_level=0.0, click_rate_touch=0.0))),
        ("force variation", "1mic", replace(dirn, layout="1mic")),
        ("force variation", "1mic, none",
         replace(dirn, layout="1mic", acoustics=replace(ac, force_var_db=0.0))),
    ]
    return [(mech, setting, evaluate(cfg)) for mech, setting, cfg in rows]


def main(argv: list[str] | None = None) -> None:
    """Print the ablation table as Markdown."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer windows per trial")
    args = parser.parse_args(argv)
    print("| mechanism | setting | det % | energy det % | dir MAE deg | flips % "
          "| folded MAE deg | mag RMSE mm |")
    print("|---|---|---|---|---|---|---|---|")
    for mech, setting, m in ablation_table(args.quick):
        print(f"| {mech} | {setting} | {m['det_pct']:.1f} | {m['energy_det_pct']:.1f} | "
              f"{m['dir_mae_deg']:.1f} | "
              f"{m['flip_pct']:.1f} | {m['fold_mae_deg']:.1f} | {m['mag_rmse_mm']:.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
