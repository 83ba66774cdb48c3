"""A tiny synthetic dataset in the documented on-disk format, for tests and smoke runs.

Slip is band-limited noise whose level grows with slip speed; each microphone sits at an
angle in the grasp plane and hears slip towards it louder (a cosine gain), so level
differences between channels encode direction and the overall level encodes speed. It is
deliberately easy: it checks that the learning code learns, not how well it would do on
the scene or on real audio.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy import signal as sps

from aslip_ros.data.dataset import WINDOW_DTYPE, DatasetWriter


def _velocity_track(rng: np.random.Generator, n: int, sr: float) -> np.ndarray:
    """(n, 2) piecewise-constant slip velocity: half the segments still, half slipping."""
    v = np.zeros((n, 2), dtype=np.float32)
    t = 0
    while t < n:
        seg = int(rng.uniform(0.4, 1.2) * sr)
        if rng.random() < 0.5:
            ang = rng.uniform(-np.pi, np.pi)
            speed = rng.uniform(0.01, 0.05)
            v[t:t + seg] = speed * np.array([np.cos(ang), np.sin(ang)], dtype=np.float32)
        t += seg
    return v


def make_synthetic_dataset(path: str | os.PathLike, *, n_trials: int = 12,
                           duration_s: float = 6.0, sample_rate: float = 16000.0,
                           channel_names: Sequence[str] = ("left_front", "left_back",
                                                           "right_back", "right_front"),
                           window_s: float = 0.2, hop_s: float = 0.1,
                           epsilon_m_s: float = 0.005, objects: Sequence[str] = ("box", "can"),
                           induced: str = "external", layout: str = "4mic",
                           seed: int = 0, coupling_db: float = 0.0,
                           background: float = 0.0) -> Path:
    """Write a dataset to ``path`` (atomically) and return the path.

    ``coupling_db`` > 0: each trial (grasp) scales each microphone by its own gain, uniform
    in +-coupling_db; ``background`` > 0: a common-mode noise of that amplitude (the hand on
    the object), on about half the time, reaches every microphone through that gain: what
    per-grasp calibration measures.
    """
    rng = np.random.default_rng(seed)
    sr = float(sample_rate)
    n = int(round(duration_s * sr))
    n_win = int(round(window_s * sr))
    n_hop = int(round(hop_s * sr))
    n_ch = len(channel_names)
    mic_angle = 2 * np.pi * np.arange(n_ch) / n_ch + np.pi / 4
    sos = sps.butter(4, [1000.0, min(5000.0, 0.45 * sr)], btype="bandpass", fs=sr, output="sos")
    with DatasetWriter(path, overwrite=True) as writer:
        for k in range(n_trials):
            v = _velocity_track(rng, n, sr)
            speed = np.linalg.norm(v, axis=1)
            ang = np.arctan2(v[:, 1], v[:, 0])
            level = rng.uniform(0.8, 1.25)
            gains = 3.0 * level * speed[:, None] * (1 + 0.7 * np.cos(ang[:, None] - mic_angle))
            src = sps.sosfilt(sos, rng.standard_normal((n, n_ch)), axis=0)
            sound = gains * src
            if background > 0:        # on in about half of 0.5 s stretches
                on = np.repeat(rng.random(n // int(0.5 * sr) + 1) < 0.5, int(0.5 * sr))[:n]
                sound = sound + (background * on)[:, None] * sps.sosfilt(
                    sos, rng.standard_normal((n, 1)), axis=0)
            if coupling_db > 0:
                sound = sound * 10.0 ** (rng.uniform(-coupling_db, coupling_db, n_ch) / 20.0)
            audio = (sound + 0.003 * rng.standard_normal((n, n_ch))).astype(np.float32)
            writer.begin_trial(n_ch).append(audio)
            csum = np.concatenate([np.zeros((1, 2)), np.cumsum(v, axis=0, dtype=np.float64)])
            rows = []
            for s in range(0, n - n_win + 1, n_hop):
                mv = (csum[s + n_win] - csum[s]) / n_win
                sp = float(np.hypot(*mv))
                rows.append((k, s, mv[0], mv[1], sp, sp > epsilon_m_s))
            writer.end_trial({"id": f"synth-{k:04d}", "object": objects[k % len(objects)],
                              "pad": "textured", "layout": layout, "condition": "robot_off",
                              "induced": induced, "source_bag": "",
                              "label_source": "synthetic"}, np.array(rows, dtype=WINDOW_DTYPE))
        writer.finish(sample_rate=sr, channel_names=list(channel_names), layout=layout,
                      window_s=window_s, hop_s=hop_s, epsilon_m_s=epsilon_m_s,
                      n_window_samples=n_win)
    return Path(path)
