"""Causal per-grasp, per-microphone level calibration over log-mel frames.

A piezo pad couples to the object differently every time a grasp is made, so each
microphone carries an unknown gain for the length of a grasp. Within one window that gain
cannot be told from the level pattern that encodes slip direction. Across the earlier
frames of the same grasp it can: every microphone hears the same common-mode background
(the hand on the object, robot noise) through its own coupling, so the level of each
channel relative to the channel mean, averaged over background frames, is the relative gain.

The state sees only frames already received in the current grasp plus constants fitted on
training data (:class:`CalibrationConstants`, stored in a checkpoint as a JSON document):

- a slip gate: a logistic model on the channel-mean log-mel frame (gain-independent up to
  the mean gain) that keeps slip frames out of the estimate. Slip levels depend on the slip
  direction, so averaging them learns a one-sided grasp's main direction away;
- an activity floor: frames near the electronics noise floor (which the coupling does not
  scale) are ignored;
- the background's own per-channel offset in training grasps (zero for a common-mode
  background on a symmetric layout), subtracted from the estimate.

The estimate shrinks towards zero gain with ``prior_frames`` pseudo-frames, so an empty or
short history never produces a wild correction. ``converged`` turns true after
``converge_frames`` accepted frames. The defaults (10 pseudo-frames, 60 frames: 0.6 s of
background at a 10 ms hop) are measured, not guessed: on held-out scene grasps the RMS gain
error at 60 accepted frames is within 10 % of its value after 300 (``python -m
benchmarks.calibration_pipeline --frames-table``; docs/model.md, "Per-grasp calibration").
Units: offsets are natural-log power (what log-mel features add), ``gain_db`` is the same in
dB (relative to the channel mean).

Self-check: the estimate assumes the background is common mode. Where it reaches the
microphones by different paths (the hand's noise by one, the arm's by another), each channel's
deviation moves with the mix of sources in a frame, and the average mixes path and coupling.
``spread_db``, the RMS over channels of the accepted frames' weighted standard deviation
around their mean, says so: a pure coupling gain moves every background frame of a channel
alike. ``trusted`` is False once converged with ``spread_db`` above ``trust_spread_db`` (a
high percentile of the statistic on the training grasps, with a margin; ``fit_constants``),
None before convergence or for constants without a threshold (fitted before the check). A
background that reaches each microphone by a path of its own but alone (no second source to
mix with) moves every frame alike too: no level statistic can tell that path from a gain.

Methods: ``background`` (the default: no-slip frames above the floor), ``slip`` (slip frames
only; kept to measure why it fails on one-sided slip) and ``all`` (every frame above the
floor). docs/model.md, "Per-grasp calibration", has the measurements.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from aslip_ros.slip import DEFAULT_THRESHOLD

from aslip_ros.learn.compat import CheckpointMismatch

METHODS = ("background", "slip", "all")
_DB_PER_NEPER_POWER = 10.0 / np.log(10.0)
#: The self-check's threshold: this percentile over training grasps of each grasp's largest
#: ``spread_db`` once converged, times this margin (docs/model.md, "Per-grasp calibration").
TRUST_PERCENTILE = 95.0
TRUST_MARGIN = 1.5


@dataclass(frozen=True)
class CalibrationConstants:
    """Everything the state needs besides the stream; fitted by :func:`fit_constants`."""

    channel_names: tuple[str, ...]
    n_mels: int
    hop_s: float
    gate_mean: tuple[float, ...]
    gate_std: tuple[float, ...]
    gate_coef: tuple[float, ...]
    gate_bias: float
    floor_level: float
    ref_offset: tuple[float, ...]
    method: str = "background"
    gate_threshold: float = 0.2
    prior_frames: float = 10.0
    converge_frames: int = 60
    #: The self-check's threshold on ``CalibrationState.spread_db`` [dB]; None: no check
    #: (constants written before it), ``trusted`` is then None.
    trust_spread_db: float | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"calibration method must be one of {METHODS}, got {self.method!r}")
        c, m = len(self.channel_names), int(self.n_mels)
        if c < 2:
            raise ValueError("calibration needs at least two channels (gains are relative)")
        for name, n in (("gate_mean", m), ("gate_std", m), ("gate_coef", m),
                        ("ref_offset", c)):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise ValueError(f"calibration {name} must be {n} finite numbers")
        if not (self.hop_s > 0 and self.prior_frames >= 0 and self.converge_frames >= 1
                and 0.0 < self.gate_threshold < 1.0):
            raise ValueError("calibration hop_s, prior_frames, converge_frames or "
                             "gate_threshold out of range")
        t = self.trust_spread_db
        if t is not None and (isinstance(t, bool) or not isinstance(t, (int, float))
                              or not np.isfinite(t) or t <= 0):
            raise ValueError(f"calibration trust_spread_db must be a positive number or "
                             f"null, got {t!r}")

    @property
    def convergence_s(self) -> float:
        """Seconds of accepted (background) audio until ``converged``."""
        return float(self.converge_frames * self.hop_s)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["convergence_s"] = self.convergence_s
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CalibrationConstants":
        d = dict(d)
        d.pop("convergence_s", None)
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown calibration keys: {sorted(unknown)}")
        for k in ("channel_names", "gate_mean", "gate_std", "gate_coef", "ref_offset"):
            if k in d:
                d[k] = tuple(d[k])
        return cls(**d)

    def with_(self, **changes: Any) -> "CalibrationConstants":
        return dataclasses.replace(self, **changes)

    def check_stream(self, channel_names: Sequence[str], n_mels: int, hop_s: float) -> None:
        """CheckpointMismatch unless the stream's channels and features match the constants."""
        if list(channel_names) != list(self.channel_names):
            raise CheckpointMismatch(f"calibration was fitted for channels "
                                     f"{list(self.channel_names)}, the stream has "
                                     f"{list(channel_names)}")
        if int(n_mels) != self.n_mels or abs(float(hop_s) - self.hop_s) > 1e-9:
            raise CheckpointMismatch(f"calibration expects {self.n_mels} mels at a "
                                     f"{self.hop_s * 1e3:g} ms hop, the stream gives {n_mels} "
                                     f"at {hop_s * 1e3:g} ms")


def meta_problems(doc: Any, channel_names: Sequence[str], n_mels: int | None,
                  hop_s: float | None) -> list[str]:
    """Problems of a checkpoint's ``calibration`` document against the checkpoint's own
    channels and features (an empty list when it is sound)."""
    if not isinstance(doc, dict):
        return [f"calibration must be a JSON object, got {type(doc).__name__}"]
    if not isinstance(channel_names, (list, tuple)):
        return []                       # the checkpoint's own check reports channel_names
    try:
        k = CalibrationConstants.from_dict(doc)
    except (TypeError, ValueError) as exc:
        return [f"calibration: {exc}"]
    try:
        k.check_stream(channel_names, k.n_mels if n_mels is None else n_mels,
                       k.hop_s if hop_s is None else hop_s)
    except CheckpointMismatch as exc:
        return [f"calibration does not match the checkpoint: {exc}"]
    return []


def frame_stats(frames: np.ndarray, k: CalibrationConstants
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame: level deviation ``(C, T)``, p(slip) ``(T,)`` and activity ``(T,)``.

    ``frames``: log-mel ``(C, M, T)`` (natural-log power, as ``features.LogMel`` gives).
    """
    return _frame_stats(frames, k, _GateArrays(k))


class _GateArrays:
    """The constants ``frame_stats`` reads, as arrays (built once per state, not per hop)."""

    def __init__(self, k: CalibrationConstants) -> None:
        self.mean = np.asarray(k.gate_mean, dtype=np.float64)
        self.std = np.asarray(k.gate_std, dtype=np.float64)
        self.coef = np.asarray(k.gate_coef, dtype=np.float64)


def _frame_stats(frames: np.ndarray, k: CalibrationConstants, g: _GateArrays
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``frame_stats`` with the gate's arrays already built."""
    x = np.asarray(frames, dtype=np.float64)
    if x.ndim != 3 or x.shape[0] != len(k.channel_names) or x.shape[1] != k.n_mels:
        raise ValueError(f"frames must be ({len(k.channel_names)}, {k.n_mels}, T), got "
                         f"{x.shape}")
    if not np.isfinite(x).all():
        raise ValueError("frames contain NaN or Inf")
    # Means over channels as sum / count: what ndarray.mean computes, without its per-call
    # overhead (the live node calls this for every frame).
    c = x.shape[0]
    top = x.max(axis=1, keepdims=True)
    level = (top + np.log(np.exp(x - top).sum(axis=1, keepdims=True)))[:, 0, :]   # (C, T)
    mean_level = level.sum(axis=0) / c
    dev = level - mean_level
    z = (x.sum(axis=0).T / c - g.mean) / g.std                                    # (T, M)
    logit = z @ g.coef + k.gate_bias
    p = 1.0 / (1.0 + np.exp(-np.clip(logit, -50.0, 50.0)))
    active = mean_level > k.floor_level
    return dev, p, active


def frame_weights(p: np.ndarray, active: np.ndarray, k: CalibrationConstants) -> np.ndarray:
    """Which frames the chosen method averages (0 or 1 per frame)."""
    if k.method == "background":
        keep = p < k.gate_threshold
    elif k.method == "slip":
        keep = p >= DEFAULT_THRESHOLD
    else:
        keep = np.ones_like(p, dtype=bool)
    return (keep & active).astype(np.float64)


class CalibrationState:
    """Running per-grasp gain estimate. ``update`` with new frames; ``reset`` on a new grasp."""

    def __init__(self, constants: CalibrationConstants) -> None:
        self.k = constants
        self._ref = np.asarray(constants.ref_offset, dtype=np.float64)
        self._gate = _GateArrays(constants)
        self.reset()

    def reset(self) -> None:
        """Forget the grasp: the next frames start a new estimate from zero gain."""
        self.n_frames = 0
        self.weight = 0.0
        #: frames of the grasp seen when the state first converged (None until then)
        self.converged_at_frame: int | None = None
        self._sum = np.zeros(len(self.k.channel_names))
        self._sum_sq = np.zeros(len(self.k.channel_names))     # for the self-check
        self._spread: float | None = None                       # spread_db, until an update

    def update(self, frames: np.ndarray) -> np.ndarray:
        """Consume new log-mel frames ``(C, M, T)`` (each frame once); return the offsets."""
        dev, p, active = _frame_stats(frames, self.k, self._gate)
        w = frame_weights(p, active, self.k)
        self.weight += float(w.sum())
        d = dev - self._ref[:, None]
        self._sum += d @ w
        self._sum_sq += (d * d) @ w
        self._spread = None
        if self.converged_at_frame is None and self.converged:
            # the frame of this batch at which the accepted weight reached the criterion
            need = self.k.converge_frames - (self.weight - float(w.sum()))
            at = int(np.searchsorted(np.cumsum(w), need - 1e-9)) + 1
            self.converged_at_frame = self.n_frames + min(at, int(dev.shape[1]))
        self.n_frames += int(dev.shape[1])
        return self.offsets

    @property
    def converged_after_s(self) -> float | None:
        """Seconds of the grasp's audio until the state converged (None until it has)."""
        return None if self.converged_at_frame is None \
            else float(self.converged_at_frame * self.k.hop_s)

    @property
    def offsets(self) -> np.ndarray:
        """Estimated per-channel log-power offset (subtract from log-mel features)."""
        return self._sum / (self.weight + self.k.prior_frames) if self.weight > 0 \
            else np.zeros_like(self._sum)

    @property
    def gain_db(self) -> np.ndarray:
        """Estimated per-channel gain relative to the channel mean [dB]."""
        return self.offsets * _DB_PER_NEPER_POWER

    @property
    def converged(self) -> bool:
        return self.weight >= self.k.converge_frames

    @property
    def spread_db(self) -> float:
        """The self-check's statistic [dB]: RMS over channels of the accepted frames'
        weighted standard deviation of the level deviation (0 before any frame)."""
        if self._spread is None:
            self._spread = float(_spread_db(self._sum, self._sum_sq, np.float64(self.weight)))
        return self._spread

    @property
    def trusted(self) -> bool | None:
        """False once converged with ``spread_db`` above the constants' threshold, True when
        converged within it; None before convergence or without a threshold."""
        t = self.k.trust_spread_db
        if t is None or not self.converged:
            return None
        return self.spread_db <= t

    def apply(self, features: np.ndarray) -> np.ndarray:
        """``features`` ``(..., C, M, T)`` with the current offsets removed."""
        return np.asarray(features, dtype=np.float32) \
            - self.offsets.astype(np.float32)[:, None, None]


def offsets_at(frames: np.ndarray, ends: np.ndarray, k: CalibrationConstants) -> np.ndarray:
    """Offline, for a whole grasp: the offsets after frames ``[0, end)`` for each ``end``.

    Equal to feeding the frames to a fresh :class:`CalibrationState` in order and reading
    ``offsets`` after frame ``end - 1`` (tested), computed with cumulative sums.
    """
    cw, cs, _ = _cumulative(frames, k)
    ends = _checked_ends(ends, cw.size)
    wt = cw[ends]
    out = cs[ends] / (wt + k.prior_frames)[:, None]
    out[wt <= 0] = 0.0
    return out


def _checked_ends(ends, n: int) -> np.ndarray:
    """``ends`` as indices into a cumulative sum of ``n`` entries (frames + 1)."""
    ends = np.asarray(ends, dtype=np.int64)
    if np.any(ends < 0) or np.any(ends >= n):
        raise ValueError("window ends must lie within the grasp's frames")
    return ends


def _spread_db(s1: np.ndarray, s2: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``spread_db`` from per-channel weighted sums of deviations ``s1`` and of their
    squares ``s2`` (``(..., C)``) over ``w`` (``(...)``) frames of weight."""
    w = np.asarray(w, dtype=np.float64)
    safe = np.where(w > 0, w, 1.0)[..., None]
    var = np.maximum(s2 / safe - (s1 / safe) ** 2, 0.0)
    return np.where(w > 0, np.sqrt(var.mean(axis=-1)), 0.0) * _DB_PER_NEPER_POWER


def spread_at(frames: np.ndarray, ends: np.ndarray, k: CalibrationConstants) -> np.ndarray:
    """Offline, for a whole grasp: ``spread_db`` after frames ``[0, end)`` for each ``end``
    (equal to a :class:`CalibrationState` fed the frames in order; tested)."""
    cw, cs, cs2 = _cumulative(frames, k)
    ends = _checked_ends(ends, cw.size)
    return _spread_db(cs[ends], cs2[ends], cw[ends])


def _cumulative(frames: np.ndarray, k: CalibrationConstants
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Accepted weight ``(T+1,)`` and sums of deviations and of their squares ``(T+1, C)``
    after each number of frames."""
    return _cumulative_of(frame_stats(frames, k), k)


def _cumulative_of(stats: tuple, k: CalibrationConstants
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_cumulative`` from a grasp's ``frame_stats`` (which do not depend on the
    reference offset)."""
    dev, p, active = stats
    w = frame_weights(p, active, k)
    d = dev - np.asarray(k.ref_offset, dtype=np.float64)[:, None]
    zero = np.zeros((1, d.shape[0]))
    return (np.concatenate([[0.0], np.cumsum(w)]),
            np.concatenate([zero, np.cumsum((d * w).T, axis=0)]),
            np.concatenate([zero, np.cumsum((d * d * w).T, axis=0)]))


def relative_log_gain(gain: np.ndarray) -> np.ndarray:
    """The offsets a perfect calibration would find for linear amplitude gains ``(C,)``."""
    lg = 2.0 * np.log(np.asarray(gain, dtype=np.float64))
    return lg - lg.mean()


def fit_constants(frames: Sequence[np.ndarray], frame_slip: Sequence[np.ndarray],
                  channel_names: Sequence[str], hop_s: float, *,
                  true_offsets: Sequence[np.ndarray] | None = None,
                  method: str = "background", floor_margin_db: float = 10.0,
                  max_frames: int = 60000, seed: int = 0,
                  trust_percentile: float = TRUST_PERCENTILE,
                  trust_margin: float = TRUST_MARGIN, **options: Any
                  ) -> CalibrationConstants:
    """Fit the gate, the floor and the reference offset on training grasps.

    ``frames``: one log-mel ``(C, M, T)`` per training grasp; ``frame_slip``: one boolean
    ``(T,)`` label per frame (slip at the frame's centre). ``true_offsets``: per grasp, the
    known relative log gains (a simulator's truth); without them the reference offset is the
    mean over grasps of each grasp's final estimate, which assumes that coupling averages out
    over many grasps.

    The self-check's threshold ``trust_spread_db`` is ``trust_margin`` times the
    ``trust_percentile`` percentile over training grasps of each grasp's largest
    ``spread_db`` once converged (what the node would have seen at any time of the grasp);
    None when no training grasp converges.

    The grasps are read one at a time, in four passes (the gate's standardisation and the
    floor, the gate's sample, the reference, the trust), so ``frames`` may be a sequence
    that reads each grasp from disk: the fit then holds one grasp's frames, the labels and
    the gate's sample of at most ``max_frames`` rows, whatever the hours of audio.
    """
    from sklearn.linear_model import LogisticRegression

    if len(frames) == 0 or len(frames) != len(frame_slip):
        raise ValueError("need one slip label array per grasp, and at least one grasp")
    labels = np.concatenate([np.asarray(s, dtype=bool) for s in frame_slip])
    # Pass 1: the moments of the common-mode rows (the gate's inputs), the levels.
    moments, levels, counts = _Moments(), [], []
    for i in range(len(frames)):
        common = _common_rows(frames[i])
        moments.add(common)
        counts.append(common.shape[0])
        levels.append(_mean_level(frames[i]))
    if labels.shape[0] != sum(counts):
        raise ValueError("frame_slip lengths must equal the grasps' frame counts")
    if labels.all() or not labels.any():
        raise ValueError("the gate needs both slip and no-slip frames in the training grasps")
    # Pass 2: the gate's sample, the rows in the order drawn.
    rng = np.random.default_rng(seed)
    pick = rng.choice(labels.shape[0], min(max_frames, labels.shape[0]), replace=False)
    sample = _rows_at(frames, counts, pick)
    n_mels = sample.shape[1]
    mean, std = moments.mean, np.maximum(moments.std, 1e-3)
    clf = LogisticRegression(C=1.0, max_iter=500)
    clf.fit((sample - mean) / std, labels[pick])
    floor = float(np.percentile(np.concatenate(levels), 5.0)) + \
        floor_margin_db / _DB_PER_NEPER_POWER
    k = CalibrationConstants(
        channel_names=tuple(channel_names), n_mels=n_mels, hop_s=float(hop_s),
        gate_mean=tuple(mean), gate_std=tuple(std), gate_coef=tuple(clf.coef_[0]),
        gate_bias=float(clf.intercept_[0]), floor_level=floor,
        ref_offset=(0.0,) * len(channel_names), method=method, **options)
    # Pass 3: the reference, the mean deviation of accepted frames once the coupling is
    # taken out.
    ests = []
    for i in range(len(frames)):
        dev, p, active = frame_stats(frames[i], k)
        w = frame_weights(p, active, k)
        if w.sum() == 0:
            continue
        est = dev @ w / w.sum()
        if true_offsets is not None:
            est = est - np.asarray(true_offsets[i], dtype=np.float64)
        ests.append(est)
    ref = np.mean(ests, axis=0) if ests else np.zeros(len(channel_names))
    k = k.with_(ref_offset=tuple(float(v) for v in ref))
    # Pass 4: the trust threshold under that reference.
    return k.with_(trust_spread_db=trust_threshold(frames, k, trust_percentile, trust_margin))


def trust_threshold(frames: Sequence[np.ndarray], k: CalibrationConstants,
                    percentile: float = TRUST_PERCENTILE, margin: float = TRUST_MARGIN
                    ) -> float | None:
    """``trust_spread_db`` from training grasps (log-mel ``(C, M, T)`` each) under ``k``:
    ``margin`` times the ``percentile`` over grasps of the largest ``spread_db`` each reaches
    once converged; None when none converges."""
    if not 0.0 < percentile <= 100.0 or not margin >= 1.0:
        raise ValueError("trust percentile must lie in (0, 100] and the margin be >= 1")
    peaks = []
    for i in range(len(frames)):
        cw, cs, cs2 = _cumulative_of(frame_stats(frames[i], k), k)
        on = cw >= k.converge_frames
        if np.any(on):
            peaks.append(float(np.max(_spread_db(cs[on], cs2[on], cw[on]))))
    if not peaks:
        return None
    return float(max(margin * np.percentile(peaks, percentile), 1e-3))


def _common_rows(frames: np.ndarray) -> np.ndarray:
    """The gate's inputs of one grasp: the mean over channels, ``(T, M)`` float64."""
    return np.asarray(frames, dtype=np.float64).mean(axis=0).T


class _Moments:
    """Running mean and standard deviation of rows, merged grasp by grasp (Chan et al.'s
    pairwise update: no sum of squares to lose precision in)."""

    def __init__(self) -> None:
        self.n, self.mean, self._m2 = 0, 0.0, 0.0

    def add(self, rows: np.ndarray) -> None:
        if rows.shape[0] == 0:
            return
        n, mean = rows.shape[0], rows.mean(axis=0)
        m2 = ((rows - mean) ** 2).sum(axis=0)
        total = self.n + n
        delta = mean - self.mean
        self.mean = self.mean + delta * (n / total)
        self._m2 = self._m2 + m2 + delta ** 2 * (self.n * n / total)
        self.n = total

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(self._m2 / self.n)


def _rows_at(frames: Sequence[np.ndarray], counts: Sequence[int], pick: np.ndarray
             ) -> np.ndarray:
    """The common-mode rows at the global frame indices ``pick``, in ``pick``'s order."""
    starts = np.concatenate([[0], np.cumsum(counts)])
    grasp = np.searchsorted(starts, pick, side="right") - 1
    out = None
    for i in np.unique(grasp):
        at = np.flatnonzero(grasp == i)
        rows = _common_rows(frames[int(i)])[pick[at] - starts[i]]
        if out is None:
            out = np.empty((pick.size, rows.shape[1]))
        out[at] = rows
    return out


def _mean_level(frames: np.ndarray) -> np.ndarray:
    x = np.asarray(frames, dtype=np.float64)
    top = x.max(axis=1, keepdims=True)
    return (top + np.log(np.exp(x - top).sum(axis=1, keepdims=True)))[:, 0, :].mean(axis=0)
