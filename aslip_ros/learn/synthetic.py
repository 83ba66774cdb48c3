"""A tiny synthetic dataset in the documented on-disk format, for tests and smoke runs.

Slip is band-limited noise whose level grows with slip speed; each microphone sits at an
angle in the grasp plane and hears slip towards it louder (a cosine gain), so level
differences between channels encode direction and the overall level encodes speed. It is
deliberately easy: it checks that the learning code learns, not how well it would do on
the scene or on real audio.

With ``rotation_fraction`` > 0 some stretches also turn about the pad normal (``wy``, rad/s;
independent of the translation, so pure rotations, pure translations and both occur) and
the windows carry the angular label. A turn makes the microphones alternately louder and
quieter around the pad (gain ``1 + 0.7 sign(wy) cos(2 (angle - pi/4))`` on the rim speed
``|wy| ROTATION_RADIUS_M``): a pattern no translation makes, whose sign gives the sense of
the turn. Again an easy stand-in (the scene's rotation follows the local slip velocity at
each microphone), enough to check that every model learns a rotational output. Without
rotation the angular column is NaN ("no label") and the data are those of before.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy import signal as sps

from aslip_ros.data.dataset import WINDOW_DTYPE, DatasetWriter
from aslip_ros.slip import ANGULAR_COMPONENT, ROTATION_RADIUS_M, VELOCITY_COMPONENTS


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


def _rotation_track(rng: np.random.Generator, n: int, sr: float,
                    fraction: float) -> np.ndarray:
    """(n,) piecewise-constant rate [rad/s]: a ``fraction`` of the segments turn at
    1-4 rad/s either way (10-40 mm/s at the reference radius), the rest do not."""
    w = np.zeros(n, dtype=np.float32)
    t = 0
    while t < n:
        seg = int(rng.uniform(0.4, 1.2) * sr)
        if rng.random() < fraction:
            w[t:t + seg] = rng.choice([-1.0, 1.0]) * rng.uniform(1.0, 4.0)
        t += seg
    return w


def synthetic_audio(rng: np.random.Generator, v: np.ndarray, w: np.ndarray | None,
                    sample_rate: float, n_channels: int, coupling_db: float = 0.0,
                    background: float = 0.0) -> np.ndarray:
    """``(n, C)`` float32 audio of one grasp for the velocity ``v`` ``(n, 2)`` [m/s] and the
    rate ``w`` ``(n,)`` [rad/s] or None (module docstring)."""
    sr, n, n_ch = float(sample_rate), v.shape[0], n_channels
    mic_angle = 2 * np.pi * np.arange(n_ch) / n_ch + np.pi / 4
    sos = sps.butter(4, [1000.0, min(5000.0, 0.45 * sr)], btype="bandpass", fs=sr, output="sos")
    speed = np.linalg.norm(v, axis=1)
    ang = np.arctan2(v[:, 1], v[:, 0])
    level = rng.uniform(0.8, 1.25)
    gains = 3.0 * level * speed[:, None] * (1 + 0.7 * np.cos(ang[:, None] - mic_angle))
    if w is not None:
        twist = np.cos(2 * (mic_angle - np.pi / 4))
        gains = gains + 3.0 * level * (np.abs(w) * ROTATION_RADIUS_M)[:, None] * (
            1 + 0.7 * np.sign(w)[:, None] * twist)
    src = sps.sosfilt(sos, rng.standard_normal((n, n_ch)), axis=0)
    sound = gains * src
    if background > 0:        # on in about half of 0.5 s stretches
        on = np.repeat(rng.random(n // int(0.5 * sr) + 1) < 0.5, int(0.5 * sr))[:n]
        sound = sound + (background * on)[:, None] * sps.sosfilt(
            sos, rng.standard_normal((n, 1)), axis=0)
    if coupling_db > 0:
        sound = sound * 10.0 ** (rng.uniform(-coupling_db, coupling_db, n_ch) / 20.0)
    return (sound + 0.003 * rng.standard_normal((n, n_ch))).astype(np.float32)


def synthetic_trial(rng: np.random.Generator, duration_s: float, sample_rate: float,
                    n_channels: int, rotation_fraction: float = 0.0, coupling_db: float = 0.0,
                    background: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """One grasp: audio ``(n, C)``, the true velocity ``(n, 2)`` and rate ``(n,)`` per
    sample (None without rotation)."""
    n = int(round(duration_s * sample_rate))
    v = _velocity_track(rng, n, sample_rate)
    w = _rotation_track(rng, n, sample_rate, rotation_fraction) \
        if rotation_fraction > 0 else None
    return (synthetic_audio(rng, v, w, sample_rate, n_channels, coupling_db, background),
            v, w)


def _window_rows(k: int, v: np.ndarray, w: np.ndarray | None, n_win: int, n_hop: int,
                 epsilon_m_s: float) -> np.ndarray:
    """The windows of trial ``k``: mean velocity and rate (NaN without rotation)."""
    n = v.shape[0]
    starts = np.arange(0, n - n_win + 1, n_hop)
    csum = np.concatenate([np.zeros((1, 2)), np.cumsum(v, axis=0, dtype=np.float64)])
    mv = (csum[starts + n_win] - csum[starts]) / n_win
    rows = np.zeros(starts.size, dtype=WINDOW_DTYPE)
    rows["trial"], rows["start"] = k, starts
    for j, c in enumerate(VELOCITY_COMPONENTS):
        rows[c] = mv[:, j]
    speed = np.hypot(mv[:, 0], mv[:, 1])
    rows["speed"], rows["slip"] = speed, speed > epsilon_m_s
    if w is None:
        rows[ANGULAR_COMPONENT] = np.nan
    else:
        cw = np.concatenate([[0.0], np.cumsum(w, dtype=np.float64)])
        rows[ANGULAR_COMPONENT] = (cw[starts + n_win] - cw[starts]) / n_win
    return rows


def make_synthetic_dataset(path: str | os.PathLike, *, n_trials: int = 12,
                           duration_s: float = 6.0, sample_rate: float = 16000.0,
                           channel_names: Sequence[str] = ("left_front", "left_back",
                                                           "right_back", "right_front"),
                           window_s: float = 0.2, hop_s: float = 0.1,
                           epsilon_m_s: float = 0.005, objects: Sequence[str] = ("box", "can"),
                           induced: str = "external", layout: str = "4mic",
                           seed: int = 0, coupling_db: float = 0.0,
                           background: float = 0.0, rotation_fraction: float = 0.0) -> Path:
    """Write a dataset to ``path`` (atomically) and return the path.

    ``coupling_db`` > 0: each trial (grasp) scales each microphone by its own gain, uniform
    in +-coupling_db; ``background`` > 0: a common-mode noise of that amplitude (the hand on
    the object), on about half the time, reaches every microphone through that gain: what
    per-grasp calibration measures. ``rotation_fraction`` > 0: that share of stretches turn
    about the pad normal, and every window has an angular label (module docstring).
    """
    rng = np.random.default_rng(seed)
    sr = float(sample_rate)
    n_win = int(round(window_s * sr))
    n_hop = int(round(hop_s * sr))
    n_ch = len(channel_names)
    with DatasetWriter(path, overwrite=True) as writer:
        for k in range(n_trials):
            audio, v, w = synthetic_trial(rng, duration_s, sr, n_ch, rotation_fraction,
                                          coupling_db, background)
            writer.begin_trial(n_ch).append(audio)
            writer.end_trial({"id": f"synth-{k:04d}", "object": objects[k % len(objects)],
                              "pad": "textured", "layout": layout, "condition": "robot_off",
                              "induced": induced, "source_bag": "",
                              "label_source": "synthetic"},
                             _window_rows(k, v, w, n_win, n_hop, epsilon_m_s))
        writer.finish(sample_rate=sr, channel_names=list(channel_names), layout=layout,
                      window_s=window_s, hop_s=hop_s, epsilon_m_s=epsilon_m_s,
                      n_window_samples=n_win)
    return Path(path)
