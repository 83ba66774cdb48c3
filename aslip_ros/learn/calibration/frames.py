"""Which audio feeds the per-grasp calibration state, offline and streaming (one definition).

Calibration frames are cut from the grasp's continuous audio, not from the model's windows:
frame ``j`` of a grasp is the log-mel (the checkpoint's ``features.LogMel``) of the input
samples ``[j * hop, j * hop + span)`` counted from the first sample of the grasp, featurised
on their own, where ``hop`` is the feature hop and ``span`` the fewest input samples that
give one ``n_fft`` frame at the feature rate. Frame ``j`` is complete once sample
``j * hop + span`` has arrived. A window ending at sample ``e`` (exclusive) of the grasp is
normalised with the state after the ``count(e)`` frames complete by then.

Why not the newest frames of each window: a live node runs the model only on the hops its
thread keeps up with (a late hop is superseded), and its hop is a parameter, so per-window
frames would depend on timing and configuration. Frames cut from the stream depend only on
the samples: ``StreamCalibration.push`` (the node, block by block) and
``grasp_frames`` (training and evaluation, a whole trial at once) compute the same frames,
and the same offsets for every window end (tested through the node).

The slip labels the gate is fitted on come from the dataset's windows: a frame takes the
label of the window whose centre is nearest to its centre.
"""

from __future__ import annotations

import math
import os
import tempfile
from typing import Any, Callable, Sequence

import numpy as np

from aslip_ros.learn.calibration.grasp import (CalibrationConstants, CalibrationState,
                                               fit_constants, offsets_at)
from aslip_ros.learn.compat import CheckpointMismatch
from aslip_ros.learn.features import FeatureConfig, LogMel

_CHUNK = 1024          # segments per LogMel call offline: bounds memory on long trials


class FrameCutter:
    """Calibration frames of a stream at ``input_rate`` for a feature config."""

    def __init__(self, feature_config: FeatureConfig, input_rate: float) -> None:
        self.logmel = LogMel(feature_config, input_rate)
        up, down = self.logmel.up, self.logmel.down
        hop = feature_config.hop * down / up
        if abs(hop - round(hop)) > 1e-9:
            raise CheckpointMismatch(
                f"the calibration needs the feature hop ({feature_config.hop} samples at "
                f"{feature_config.sample_rate:g} Hz) to be a whole number of samples at the "
                f"stream's {input_rate:g} Hz")
        self.hop = int(round(hop))
        span = max(1, math.ceil(feature_config.n_fft * down / up))
        while self.logmel.resampled_length(span) < feature_config.n_fft:
            span += 1
        self.span = span
        self.input_rate = float(input_rate)
        #: The newest ``live_frames`` call: (its audio, its frames), for a second stream
        #: calibration that cuts the same frames (``StreamCalibration.share_frames``).
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self.shared = False                 # set by ``share_frames``: only then remembered
        self.reused = 0                     # live_frames calls answered from ``_last``

    def cuts_like(self, other: "FrameCutter") -> bool:
        """Whether ``other`` cuts the same frames from the same audio."""
        return (self.logmel.cfg == other.logmel.cfg and self.input_rate == other.input_rate
                and (self.hop, self.span) == (other.hop, other.span))

    @property
    def hop_s(self) -> float:
        return self.hop / self.input_rate

    def count(self, n_samples: Any) -> Any:
        """Frames complete after ``n_samples`` samples of the grasp (scalar or array)."""
        if isinstance(n_samples, (int, np.integer)):     # the live case, once a block
            return max(0, (int(n_samples) - self.span) // self.hop + 1)
        n = np.asarray(n_samples, dtype=np.int64)
        out = np.maximum(0, (n - self.span) // self.hop + 1)
        return int(out) if out.ndim == 0 else out

    def frames(self, audio: np.ndarray) -> np.ndarray:
        """Every complete frame of ``audio`` ``(n_samples, C)``: log-mel ``(C, M, T)``."""
        a = np.ascontiguousarray(audio, dtype=np.float32)
        t = self.count(a.shape[0])
        m = self.logmel.cfg.n_mels
        if t == 0:
            return np.zeros((a.shape[1], m, 0), np.float32)
        # Frame j's samples as a strided view (n, span, C) of the audio: sliding_window_view
        # costs more than the frame's log-mel when a block completes one frame (the node).
        segs = np.ndarray((t, self.span, a.shape[1]), np.float32, a, 0,
                          (self.hop * a.strides[0],) + a.strides)
        out = np.empty((t, a.shape[1], m), np.float32)
        for s in range(0, t, _CHUNK):
            out[s:s + _CHUNK] = self.logmel(np.ascontiguousarray(segs[s:s + _CHUNK]))[..., 0]
        return np.ascontiguousarray(np.transpose(out, (1, 2, 0)))

    def live_frames(self, audio: np.ndarray) -> np.ndarray:
        """``frames`` of a block's few new frames; for a shared cutter (read-only) the same
        audio as the call before gives that call's frames without computing them again."""
        if not self.shared:                 # one calibration: nothing to remember
            return self.frames(audio)
        a = np.ascontiguousarray(audio, dtype=np.float32)
        last = self._last
        if last is not None and last[0].shape == a.shape and np.array_equal(last[0], a):
            self.reused += 1
            return last[1]
        out = self.frames(a)
        out.flags.writeable = False
        self._last = (a.copy(), out)
        return out


class StreamCalibration:
    """The live form: ``push`` each accepted block; ``reset`` when a new grasp starts."""

    def __init__(self, constants: CalibrationConstants, feature_config: FeatureConfig,
                 input_rate: float) -> None:
        self.cutter = FrameCutter(feature_config, input_rate)
        self.state = CalibrationState(constants)
        self.resets = 0
        self._tail = np.zeros((0, len(constants.channel_names)), np.float32)

    def share_frames(self, other: "StreamCalibration") -> bool:
        """Cut frames with ``other``'s cutter where it cuts the same ones (a hybrid's two
        parts push the same audio: the second one's frames then cost a comparison). Each
        keeps its own state and constants; a part whose audio differs (its own restart)
        computes its own. Whether it is shared."""
        if not self.cutter.cuts_like(other.cutter):
            return False
        self.cutter = other.cutter
        self.cutter.shared = True
        return True

    def reset(self) -> None:
        self.state.reset()
        self._tail = self._tail[:0]
        self.resets += 1

    def push(self, block: np.ndarray) -> None:
        """Append ``(n, C)`` samples; every frame they complete updates the state."""
        tail = np.concatenate([self._tail, np.asarray(block, dtype=np.float32)])
        n = self.cutter.count(tail.shape[0])
        if n:
            self.state.update(self.cutter.live_frames(tail[:(n - 1) * self.cutter.hop
                                                           + self.cutter.span]))
            tail = tail[n * self.cutter.hop:]
        self._tail = tail

    @property
    def offsets(self) -> np.ndarray:
        return self.state.offsets

    def summary(self) -> dict[str, Any]:
        """What the diagnostics show: convergence, per-channel gain, frame counts, the
        self-check's statistic and, once known, its verdict (``calibration_trusted``)."""
        s = self.state
        out = {"calibration_converged": bool(s.converged),
               "calibration_accepted_frames": int(round(s.weight)),
               "calibration_frames": int(s.n_frames), "calibration_resets": self.resets,
               "calibration_spread_db": round(s.spread_db, 3),
               "gain_db": {n: round(float(g), 3)
                           for n, g in zip(s.k.channel_names, s.gain_db)}}
        if s.converged_after_s is not None:     # seconds of the grasp's audio, once converged
            out["calibration_converged_after_s"] = round(s.converged_after_s, 3)
        trusted = s.trusted
        if trusted is not None:                 # converged, with a threshold in the constants
            out["calibration_trusted"] = trusted
            out["calibration_trust_spread_db"] = s.k.trust_spread_db
        return out


def remove_from_audio(windows: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Windows ``(B, N, C)`` scaled so their log power drops by ``offsets`` ``(B, C)``: the
    same removal for models that read audio rather than log-mel features (the SVM)."""
    scale = np.exp(-0.5 * np.asarray(offsets, dtype=np.float64)).astype(np.float32)
    return np.asarray(windows, dtype=np.float32) * scale[:, None, :]


def grasp_frames(audio: np.ndarray, feature_config: FeatureConfig, input_rate: float
                 ) -> np.ndarray:
    """All calibration frames of one recorded grasp (``(n_samples, C)`` from its start)."""
    return FrameCutter(feature_config, input_rate).frames(audio)


def window_offsets(frames: np.ndarray, window_ends: np.ndarray, cutter: FrameCutter,
                   k: CalibrationConstants) -> np.ndarray:
    """Offsets ``(n, C)`` for windows ending at these samples of the grasp (exclusive)."""
    return offsets_at(frames, cutter.count(np.asarray(window_ends)), k)


def frame_slip_from_windows(n_frames: int, cutter: FrameCutter, starts: np.ndarray,
                            window_samples: int, slip: np.ndarray) -> np.ndarray:
    """Per calibration frame, the slip label of the window whose centre is nearest."""
    centres = np.arange(n_frames) * cutter.hop + cutter.span / 2.0
    wc = np.asarray(starts, dtype=np.float64) + window_samples / 2.0
    order = np.argsort(wc)
    wc, lab = wc[order], np.asarray(slip, dtype=bool)[order]
    j = np.clip(np.searchsorted(wc, centres), 1, max(wc.size - 1, 1))
    left = np.clip(j - 1, 0, wc.size - 1)
    j = np.clip(j, 0, wc.size - 1)
    pick = np.where(np.abs(centres - wc[left]) <= np.abs(centres - wc[j]), left, j)
    return lab[pick]


def _trial_rows(ds, trial: int) -> np.ndarray:
    return np.flatnonzero(ds.windows["trial"] == trial)


def fit_on_dataset(ds, train_idx: np.ndarray, channels: Sequence[str],
                   feature_config: FeatureConfig, **options: Any) -> CalibrationConstants:
    """Constants from the trials (grasps) of the training windows ``train_idx``. Each
    grasp's frames are cut once and spilled to a temporary file (``SpilledFrames``, in the
    system's temporary directory: ``TMPDIR``), which the fit reads grasp by grasp."""
    cutter = FrameCutter(feature_config, ds.sample_rate)
    cols = ds.channel_indices(channels)
    labels = []
    with SpilledFrames() as frames:
        for trial in np.unique(ds.windows["trial"][train_idx]):
            rows = _trial_rows(ds, int(trial))
            f = cutter.frames(np.asarray(ds.audio(int(trial)))[:, cols])
            ds.release_audio()          # the trial's pages leave resident memory
            if f.shape[2] == 0:
                continue
            frames.append(f)
            labels.append(frame_slip_from_windows(f.shape[2], cutter,
                                                  ds.windows["start"][rows],
                                                  ds.window_samples, ds.slip(rows)))
            del f
        if not labels:
            raise ValueError("no training trial is long enough for a calibration frame")
        return fit_constants(frames, labels, list(channels), cutter.hop_s, **options)


class SpilledFrames:
    """Grasps' calibration frames written once to an unnamed temporary file in
    ``directory`` and read back as maps, one grasp at a time: a fit that reads them several
    times holds none of them in its own memory (hours of audio are gigabytes of frames)."""

    def __init__(self, directory: str | os.PathLike | None = None) -> None:
        self._file = tempfile.TemporaryFile(dir=directory)
        self._parts: list[tuple[int, tuple[int, ...]]] = []

    def append(self, frames: np.ndarray) -> None:
        a = np.ascontiguousarray(frames, dtype=np.float32)
        offset = self._file.seek(0, os.SEEK_END)
        self._file.write(a.tobytes())
        self._parts.append((offset, a.shape))

    def __len__(self) -> int:
        return len(self._parts)

    def __getitem__(self, i: int) -> np.ndarray:
        offset, shape = self._parts[i]
        self._file.flush()
        if 0 in shape:
            return np.zeros(shape, np.float32)
        return np.memmap(self._file, dtype=np.float32, mode="r", offset=offset, shape=shape)

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "SpilledFrames":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def dataset_offsets(ds, channels: Sequence[str], feature_config: FeatureConfig,
                    k: CalibrationConstants, idx: np.ndarray | None = None) -> np.ndarray:
    """Per window, the causal offsets ``(len(ds), C)`` float32 (zero outside ``idx``'s
    trials): the state of its own trial after the frames complete at the window's end."""
    cutter = FrameCutter(feature_config, ds.sample_rate)
    cols = ds.channel_indices(channels)
    k.check_stream([ds.channel_names[c] for c in cols], feature_config.n_mels, cutter.hop_s)
    out = np.zeros((len(ds), len(cols)), np.float32)
    trials = np.unique(ds.windows["trial"] if idx is None else ds.windows["trial"][idx])
    for trial in trials:
        rows = _trial_rows(ds, int(trial))
        f = cutter.frames(np.asarray(ds.audio(int(trial)))[:, cols])
        ds.release_audio()
        ends = ds.windows["start"][rows].astype(np.int64) + ds.window_samples
        out[rows] = window_offsets(f, ends, cutter, k)
    return out


def training_calibration(ds, method: str, channels: Sequence[str],
                         feature_config: FeatureConfig, tr: np.ndarray, va: np.ndarray,
                         reuse: dict[str, Any] | None = None,
                         log: Callable[[str], None] = print
                         ) -> tuple[CalibrationConstants | None, np.ndarray | None]:
    """For ``aslip train``: constants (fitted on the training windows' trials, or ``reuse``d
    from the init checkpoint of a finetune: its encoder learned on those features) and the
    causal offsets of every training and validation window; (None, None) when off."""
    if reuse is not None:
        if method == "off":
            raise ValueError("the --init checkpoint was trained with per-grasp calibration; "
                             "its encoder expects calibrated features (drop "
                             "--calibration off)")
        k = CalibrationConstants.from_dict(reuse)
    elif method == "off":
        return None, None
    elif len(channels) < 2:
        log("calibration: off (one channel: gains are relative between microphones)")
        return None, None
    else:
        k = fit_on_dataset(ds, tr, channels, feature_config, method=method)
        log(f"calibration: {k.method} constants fitted on the training trials (converged "
            f"after {k.convergence_s:g} s of accepted audio)")
    try:
        offsets = dataset_offsets(ds, channels, feature_config, k, np.concatenate([tr, va]))
    except CheckpointMismatch as exc:
        raise ValueError(f"calibration does not fit this dataset: {exc}") from exc
    return k, offsets
