"""Synthetic recordings with analytically known slip, for tests and benchmarks.

The object moves at a constant velocity ``slip_velocity`` relative to the finger, expressed
in the grasp plane, so every window's true label is that velocity (y dropped). Nothing here
models acoustics: the audio is low-level noise; the scene (``aslip_ros.scene``) is the
realistic source.
"""

from __future__ import annotations

import os
from typing import Iterable, Mapping, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from aslip_ros.data.bags import DEFAULT_TOPICS, BagWriter, Topics, make_metadata
from aslip_ros.poses import IDENTITY_POSE, as_pose, compose, invert

DEFAULT_CHANNELS = ("left_front", "left_rear", "right_front", "right_rear")
#: The layout name a synthetic bag carries by default: the scene's default
#: (``scene.layouts.DEFAULT_LAYOUT``, checked equal by test/test_defaults_once.py), written
#: here because data/ does not import the scene; the channels and the noise are its own.
DEFAULT_LAYOUT = "4mic"


def _in_any(t: float, intervals: Iterable[tuple[float, float]]) -> bool:
    return any(a <= t < b for a, b in intervals)


def _metadata(metadata: Mapping | None | bool, extra: Mapping | None, *, sample_rate: float,
              channel_names: list, layout: str, induced: str, seed: int,
              calib: np.ndarray) -> dict | None:
    """The bag's scenario metadata: made up (True), as given (a mapping) or none."""
    if metadata is True:
        meta = make_metadata(sample_rate=sample_rate, channel_names=channel_names,
                             layout=layout, object="synthetic", pad="textured",
                             induced=induced,
                             condition="robot_moving" if induced == "robot" else "robot_off",
                             seed=seed, trial_id=f"synthetic-{induced}-{seed:04d}")
        meta["grasp_plane_in_" + ("tcp" if induced == "robot" else "finger")] = list(calib)
    elif metadata:
        meta = dict(metadata)
    else:
        meta = None
    if meta is not None and extra:
        meta.update(extra)
    return meta


def write_synthetic_bag(path: str | os.PathLike, *, duration_s: float = 3.0,
                        sample_rate: float = 48000.0,
                        channel_names: Sequence[str] = DEFAULT_CHANNELS,
                        block_frames: int = 480, pose_rate_hz: float = 120.0,
                        induced: str = "external",
                        slip_velocity: Sequence[float] = (0.02, 0.0, 0.0),
                        finger_pose: Sequence[float] = IDENTITY_POSE,
                        finger_velocity: Sequence[float] = (0.0, 0.0, 0.0),
                        calibration: Sequence[float] = IDENTITY_POSE,
                        metadata: Mapping | None | bool = True,
                        pose_dropouts: Sequence[tuple[float, float]] = (),
                        audio_dropouts: Sequence[tuple[float, float]] = (),
                        start_ns: int = 1_700_000_000_000_000_000, seed: int = 0,
                        topics: Topics = DEFAULT_TOPICS, layout: str = DEFAULT_LAYOUT,
                        extra_metadata: Mapping | None = None) -> None:
    """Write a bag whose slip is ``slip_velocity`` (grasp plane, m/s) throughout.

    ``induced="external"``: finger and object mocap poses (``/aslip/mocap/*``) with the
    finger at ``finger_pose`` moving at ``finger_velocity`` (world); ``calibration`` is
    ``grasp_plane_in_finger``. ``induced="robot"``: TCP poses only, the TCP sweeping past a
    fixed probe; ``calibration`` is ``grasp_plane_in_tcp``. ``metadata``: True writes the
    scenario metadata, False/None writes none, a mapping is written as given.
    ``pose_dropouts`` / ``audio_dropouts``: time intervals [a, b) with no samples.
    """
    if induced not in ("external", "robot"):
        raise ValueError(f"induced must be 'external' or 'robot', got {induced!r}")
    calib = as_pose(calibration, "calibration")
    g0 = compose(as_pose(finger_pose, "finger_pose"), calib)   # grasp plane at t = 0
    rg = Rotation.from_quat(g0[3:])
    v_rel = np.asarray(slip_velocity, dtype=np.float64)
    v_finger = np.asarray(finger_velocity, dtype=np.float64)
    inv_calib = invert(calib)
    names = list(channel_names)
    meta = _metadata(metadata, extra_metadata, sample_rate=float(sample_rate),
                     channel_names=names, layout=layout, induced=induced, seed=seed,
                     calib=calib)

    rng = np.random.default_rng(seed)
    # One second of noise reused cyclically keeps long benchmark bags cheap to make.
    noise_len = max(block_frames, int(sample_rate)) // block_frames * block_frames
    noise = (0.01 * rng.standard_normal((noise_len, len(names)))).astype(np.float32)
    n_frames = int(round(duration_s * sample_rate))
    r0 = np.array([0.0, 0.0, 0.0])
    pose_dt = 1.0 / pose_rate_hz
    n_pose = int(np.floor(duration_s * pose_rate_hz)) + 1
    pose_i = 0

    with BagWriter(path, metadata=meta, topics=topics, start_ns=start_ns) as bag:
        def poses_until(t_end: float) -> None:
            nonlocal pose_i
            # Interleaved with the audio so the bag is written in time order.
            while pose_i < n_pose and pose_i * pose_dt <= t_end + 1e-12:
                tp = pose_i * pose_dt
                pose_i += 1
                if _in_any(tp, pose_dropouts):
                    continue
                pg = g0[:3] + v_finger * tp
                if induced == "external":
                    bag.write_pose("finger", tp,
                                   compose(np.concatenate([pg, g0[3:]]), inv_calib))
                    po = pg + rg.apply(r0 + v_rel * tp)
                    bag.write_pose("object", tp, np.concatenate([po, [0.0, 0.0, 0.0, 1.0]]))
                else:
                    g = np.concatenate([g0[:3] - rg.apply(v_rel * tp), g0[3:]])
                    bag.write_pose("tcp", tp, compose(g, inv_calib))

        for first in range(0, n_frames - block_frames + 1, block_frames):
            t = first / sample_rate
            poses_until(t)
            if _in_any(t, audio_dropouts):
                continue
            off = first % noise_len
            bag.write_audio(t, first, noise[off:off + block_frames], sample_rate, names,
                            layout)
        poses_until(duration_s)
