"""The paper's SVM baseline: RBF SVC for slip, an RBF SVR for the slip speed |v| and two for
its direction's unit components (vx/|v|, vz/|v|), and, trained on windows with an angular
label, one for the rotational rate ``wy``, on handcrafted features. The velocity is the
regressed speed (clamped at 0) times the unit vector of the regressed direction: the speed
is estimated itself, not as the norm of two component estimates, which shrink towards 0
wherever the direction is uncertain. Checkpoints written before that change (one regressor
per velocity component) load and predict as they did.

Features (``SvmConfig.features``), standardised:

- ``bands`` (the paper's): per channel, from the same resampled power spectrogram as the
  CNN's (``features.LogMel.power_spectrogram``), log energies in ``n_bands`` log-spaced
  bands, log RMS, spectral centroid, bandwidth, 85 % roll-off, flatness, zero-crossing rate
  and the frame-to-frame spread of log energy; the per-grasp offsets are removed from the
  audio (``calibration.frames.remove_from_audio``);
- ``logmel``: the time-averaged log-mel of each channel, the CNN's own features less the
  per-grasp offsets, as the CNN reads them. A regressor of the speed on these is what a
  careful engineer tries first, and it beat the CNN's speed on a scene nobody here tuned to
  (issue #36); reading the CNN's features, it shares the live path's sliding log-mel
  (``reads_logmel``).

scikit-learn fits the estimators; the fitted model is then reduced to arrays (support
vectors, dual coefficients, intercepts, gamma) and evaluated by ``SvmArrays`` in numpy, so
checkpoints need no pickle and inference does not depend on the sklearn version.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from aslip_ros.slip import (ANGULAR_COMPONENT, N_VELOCITY, ROTATION_EPSILON_RAD_S,
                            ROTATION_RADIUS_M, VELOCITY_COMPONENTS)
from aslip_ros.learn.calibration.frames import remove_from_audio
from aslip_ros.learn.checkpoint import Checkpoint, angular_problems
from aslip_ros.learn.features import FeatureConfig, LogMel
from aslip_ros.learn.models.registry import register_model

_FLOOR = 1e-12


@dataclass(frozen=True)
class SvmConfig:
    """SVM hyper-parameters. ``svr_epsilon`` is in the regressors' units: ``target_scale``
    (m/s) for the speed and the rate, 1 for the direction's unit components."""

    n_bands: int = 8
    C: float = 10.0
    svr_C: float = 10.0
    gamma: str | float = "scale"
    svr_epsilon: float = 0.1
    max_train: int = 4000
    features: str = "bands"          # one of FEATURES

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


#: What the SVM reads (module docstring).
FEATURES = ("bands", "logmel")


class SvmFeaturizer:
    """Audio windows ``(B, N, C)`` -> handcrafted features ``(B, C * (n_bands + 7))``."""

    def __init__(self, feature_cfg: FeatureConfig, input_rate: float, n_bands: int) -> None:
        if n_bands < 1:
            raise ValueError("n_bands must be >= 1")
        self.logmel = LogMel(feature_cfg, input_rate)
        cfg = feature_cfg
        self.freqs = (np.arange(cfg.n_fft // 2 + 1) * cfg.sample_rate / cfg.n_fft).astype(
            np.float32)
        edges = np.geomspace(max(cfg.fmin, 50.0), cfg.f_max, n_bands + 1)
        self.band = np.stack([(self.freqs >= lo) & (self.freqs < hi)
                              for lo, hi in zip(edges[:-1], edges[1:])], axis=1).astype(
                                  np.float32)  # (n_bins, n_bands)
        self.n_bands = n_bands

    @property
    def n_per_channel(self) -> int:
        return self.n_bands + 7

    def __call__(self, audio: np.ndarray, offsets: np.ndarray | None = None) -> np.ndarray:
        """Features of windows ``(B, N, C)``, the per-grasp ``offsets`` ``(B, C)`` (or None)
        removed from the audio first."""
        x = np.asarray(audio, dtype=np.float32)
        if x.ndim == 2:
            x = x[None]
        if offsets is not None:
            x = remove_from_audio(x, offsets)
        spec = self.logmel.power_spectrogram(x)  # (B, C, T, K)
        p = spec.mean(axis=2)                    # (B, C, K)
        total = p.sum(axis=-1) + _FLOOR
        nyq = self.freqs[-1]
        bands = np.log(p @ self.band + _FLOOR)
        centroid = (p * self.freqs).sum(-1) / total
        bandwidth = np.sqrt((p * (self.freqs - centroid[..., None]) ** 2).sum(-1) / total)
        cum = np.cumsum(p, axis=-1)
        rolloff = self.freqs[np.minimum((cum < 0.85 * total[..., None]).sum(-1),
                                        len(self.freqs) - 1)]
        flatness = np.exp(np.log(p + _FLOOR).mean(-1)) / (p.mean(-1) + _FLOOR)
        xs = self.logmel.resample(x)             # (B, N', C)
        rms = np.log(np.sqrt((xs ** 2).mean(axis=1)) + 1e-9)
        zcr = (np.diff(np.signbit(xs), axis=1) != 0).mean(axis=1)
        frame_e = np.log(spec.sum(-1) + _FLOOR)  # (B, C, T)
        spread = frame_e.std(axis=-1)
        scalars = np.stack([rms, centroid / nyq, bandwidth / nyq, rolloff / nyq, flatness,
                            zcr, spread], axis=-1)
        feats = np.concatenate([bands, scalars], axis=-1)  # (B, C, F)
        return feats.reshape(feats.shape[0], -1).astype(np.float32)


class LogMelMeans:
    """Audio windows ``(B, N, C)`` -> the time-averaged log-mel of each channel
    ``(B, C * n_mels)``, the per-grasp offsets removed from the log-mel as the CNN does."""

    def __init__(self, feature_cfg: FeatureConfig, input_rate: float) -> None:
        self.logmel = LogMel(feature_cfg, input_rate)

    def __call__(self, audio: np.ndarray, offsets: np.ndarray | None = None) -> np.ndarray:
        x = np.asarray(audio, dtype=np.float32)
        feats = self.logmel(x[None] if x.ndim == 2 else x)
        if offsets is not None:
            feats = feats - np.asarray(offsets, np.float32)[:, :, None, None]
        return self.means(feats)

    @staticmethod
    def means(feats: np.ndarray) -> np.ndarray:
        """Log-mel ``(B, C, M, T)`` -> ``(B, C * M)``."""
        f = np.asarray(feats, dtype=np.float32)
        return f.mean(axis=-1).reshape(f.shape[0], -1)


def svm_featurizer(cfg: SvmConfig, feature_cfg: FeatureConfig, input_rate: float):
    """The featurizer of ``cfg.features``: ``f(audio, offsets=None) -> (B, F)``."""
    if cfg.features == "logmel":
        return LogMelMeans(feature_cfg, input_rate)
    return SvmFeaturizer(feature_cfg, input_rate, cfg.n_bands)


@dataclass
class KernelMachine:
    """An RBF kernel expansion: f(x) = sum_i a_i exp(-gamma |x - s_i|^2) + b."""

    support: np.ndarray   # (n_sv, F)
    dual: np.ndarray      # (n_sv,)
    intercept: float
    gamma: float

    @classmethod
    def from_sklearn(cls, est) -> "KernelMachine":
        if est.kernel != "rbf":
            raise ValueError("only RBF kernels are supported")
        return cls(support=np.asarray(est.support_vectors_, dtype=np.float64),
                   dual=np.asarray(est.dual_coef_, dtype=np.float64).reshape(-1),
                   intercept=float(np.asarray(est.intercept_).reshape(-1)[0]),
                   gamma=float(est._gamma))

    def __post_init__(self) -> None:
        # |s_i|^2 once, not per call: at one window a hop it was most of the call's time.
        self._support_sq = (self.support ** 2).sum(1)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        d2 = (x ** 2).sum(1)[:, None] + self._support_sq[None, :] - 2.0 * x @ self.support.T
        return np.exp(-self.gamma * np.maximum(d2, 0.0)) @ self.dual + self.intercept

    def to_tensors(self, prefix: str) -> dict[str, torch.Tensor]:
        return {f"{prefix}.support": torch.from_numpy(self.support),
                f"{prefix}.dual": torch.from_numpy(self.dual),
                f"{prefix}.intercept": torch.tensor([self.intercept], dtype=torch.float64),
                f"{prefix}.gamma": torch.tensor([self.gamma], dtype=torch.float64)}

    @classmethod
    def from_tensors(cls, t: dict[str, torch.Tensor], prefix: str) -> "KernelMachine":
        try:
            return cls(support=t[f"{prefix}.support"].double().numpy(),
                       dual=t[f"{prefix}.dual"].double().numpy(),
                       intercept=float(t[f"{prefix}.intercept"][0]),
                       gamma=float(t[f"{prefix}.gamma"][0]))
        except KeyError as exc:
            raise ValueError(f"SVM checkpoint lacks {exc}") from exc


#: Tensor prefixes of the velocity regressors: the speed ``|v| / target_scale`` and the
#: direction's unit component along each of ``VELOCITY_COMPONENTS`` (``dir_vx``, ``dir_vz``).
SPEED_REGRESSOR = "speed"
DIRECTION_REGRESSORS = tuple(f"dir_{c}" for c in VELOCITY_COMPONENTS)
SPEED_DIRECTION = (SPEED_REGRESSOR, *DIRECTION_REGRESSORS)


def speed_and_direction(v: np.ndarray, who: str
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The regressors' targets from slip velocities ``(n, N_VELOCITY)``: the speed ``(n,)``,
    the rows that move (``|v| > 0``) and their unit directions ``(moving, N_VELOCITY)``.

    :raises ValueError: fewer than two rows move (``who`` names the model).
    """
    v = np.asarray(v, dtype=np.float64)
    speed = np.linalg.norm(v, axis=1)
    moves = speed > 0
    if moves.sum() < 2:
        raise ValueError(f"{who} needs at least two slip windows that move (|v| > 0) to "
                         "learn a direction")
    return speed, moves, v[moves] / speed[moves, None]


def speed_times_direction(speed: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Velocity ``(B, N_VELOCITY)`` from a speed ``(B,)`` (clamped at 0) and an unnormalised
    direction ``(B, N_VELOCITY)``; a zero direction gives zero velocity, never NaN."""
    speed = np.maximum(np.asarray(speed, dtype=np.float64), 0.0)
    d = np.asarray(direction, dtype=np.float64)
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    return np.divide(d, norm, out=np.zeros_like(d), where=norm > 0) * speed[:, None]


@dataclass
class SvmArrays:
    """The fitted baseline as arrays: standardisation, slip classifier, the velocity
    regressors and, optionally, one for the rotational rate (``angular``: it predicts the
    rim speed ``wy * ROTATION_RADIUS_M / target_scale``, the speed's scale).

    ``velocity`` holds either a speed and a direction regressor (keys ``SPEED_DIRECTION``:
    the speed over ``target_scale`` and the direction's unit components; velocity =
    clamped speed x unit direction) or, in checkpoints from before that, one regressor per
    slip velocity component (keys ``aslip_ros.slip.VELOCITY_COMPONENTS``, in units of
    ``target_scale``).

    ``probability`` is sigmoid(decision value): not Platt-calibrated, but p >= 0.5 exactly
    where the SVC predicts slip, which is all the threshold needs.
    """

    mean: np.ndarray
    std: np.ndarray
    slip: KernelMachine
    velocity: dict[str, KernelMachine]     # SPEED_DIRECTION or VELOCITY_COMPONENTS -> regressor
    target_scale: float   # m/s; the speed (or component) regressors predict it / target_scale
    angular: KernelMachine | None = None   # None: no rotational output

    def predict(self, feats: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(probability (B,), ungated velocity (B, 2) m/s, rate wy (B,) rad/s or None)
        from handcrafted features."""
        z = self._standardised(feats)
        prob = 1.0 / (1.0 + np.exp(-np.clip(self.slip(z), -50, 50)))
        if self.per_component:
            v = np.stack([self.velocity[c](z) for c in VELOCITY_COMPONENTS],
                         axis=1) * self.target_scale
        else:
            v = speed_times_direction(
                self.velocity[SPEED_REGRESSOR](z) * self.target_scale,
                np.stack([self.velocity[d](z) for d in DIRECTION_REGRESSORS], axis=1))
        w = None if self.angular is None else (
            self.angular(z) * (self.target_scale / ROTATION_RADIUS_M)).astype(np.float32)
        return prob.astype(np.float32), v.astype(np.float32), w

    def speed(self, feats: np.ndarray) -> np.ndarray:
        """The slip speed ``(B,)`` m/s alone: the norm of ``predict``'s velocity, from the
        speed regressor only (the classifier and the direction and rate regressors are not
        evaluated). It differs from that norm only where both direction regressors give
        exactly 0 (``predict``'s velocity is then 0). A ``per_output`` model whose speed
        comes from an SVM needs nothing else of it; beside a CNN part, evaluating the other
        regressors cost more than themselves (their 2 MB of support vectors evicted the
        CNN's weights from the cache: 0.5 ms a window against 0.15 for the speed alone)."""
        z = self._standardised(feats)
        if self.per_component:
            v = np.stack([self.velocity[c](z) for c in VELOCITY_COMPONENTS], axis=1)
            return np.linalg.norm(v * self.target_scale, axis=1)
        return np.maximum(self.velocity[SPEED_REGRESSOR](z) * self.target_scale, 0.0)

    def _standardised(self, feats: np.ndarray) -> np.ndarray:
        return (np.asarray(feats, dtype=np.float64) - self.mean) / self.std

    @property
    def per_component(self) -> bool:
        """True for the regressors of checkpoints from before the speed was regressed."""
        return tuple(self.velocity) == VELOCITY_COMPONENTS

    def to_tensors(self) -> dict[str, torch.Tensor]:
        out = {"scaler.mean": torch.from_numpy(np.asarray(self.mean, dtype=np.float64)),
               "scaler.std": torch.from_numpy(np.asarray(self.std, dtype=np.float64)),
               "target_scale": torch.tensor([self.target_scale], dtype=torch.float64)}
        out.update(self.slip.to_tensors("slip"))
        for name, regressor in self.velocity.items():
            out.update(regressor.to_tensors(name))
        if self.angular is not None:
            out.update(self.angular.to_tensors(ANGULAR_COMPONENT))
        return out

    @classmethod
    def from_tensors(cls, t: dict[str, torch.Tensor]) -> "SvmArrays":
        try:
            mean, std = t["scaler.mean"].numpy(), t["scaler.std"].numpy()
            scale = float(t["target_scale"][0])
        except KeyError as exc:
            raise ValueError(f"SVM checkpoint lacks {exc}") from exc
        angular = KernelMachine.from_tensors(t, ANGULAR_COMPONENT) \
            if f"{ANGULAR_COMPONENT}.support" in t else None
        return cls(mean=mean, std=std, slip=KernelMachine.from_tensors(t, "slip"),
                   velocity={c: KernelMachine.from_tensors(t, c)
                             for c in _velocity_regressors(t)},
                   target_scale=scale, angular=angular)

    def __post_init__(self) -> None:
        if tuple(self.velocity) not in (SPEED_DIRECTION, VELOCITY_COMPONENTS):
            raise ValueError(f"SVM velocity regressors must be {SPEED_DIRECTION} or "
                             f"{VELOCITY_COMPONENTS}, got {tuple(self.velocity)}")


def _velocity_regressors(t: dict[str, torch.Tensor]) -> tuple[str, ...]:
    """The velocity regressors a tensor set holds: speed and direction (``SPEED_DIRECTION``)
    or, written before those, one per component (``VELOCITY_COMPONENTS``)."""
    def has(names):
        return any(f"{n}.support" in t for n in names)
    new, old = has(SPEED_DIRECTION), has(VELOCITY_COMPONENTS)
    if new and old:
        raise ValueError(f"SVM checkpoint holds both speed/direction regressors "
                         f"{SPEED_DIRECTION} and per-component ones {VELOCITY_COMPONENTS}")
    if not (new or old):
        raise ValueError(f"SVM checkpoint holds no velocity regressors: neither speed and "
                         f"direction {SPEED_DIRECTION} nor per-component {VELOCITY_COMPONENTS}")
    return SPEED_DIRECTION if new else VELOCITY_COMPONENTS


def moving(slip: np.ndarray, angular: np.ndarray | None) -> np.ndarray:
    """Windows that slip in the plane or rotate (``|wy| > ROTATION_EPSILON_RAD_S``; a NaN
    label does not rotate): what a balanced subsample keeps as the positive class."""
    slip = np.asarray(slip, bool)
    if angular is None:
        return slip
    return slip | (np.abs(np.nan_to_num(np.asarray(angular, np.float64)))
                   > ROTATION_EPSILON_RAD_S)


def fit_svm(feats: np.ndarray, slip: np.ndarray, velocity: np.ndarray,
            cfg: SvmConfig = SvmConfig(), angular: np.ndarray | None = None
            ) -> tuple[SvmArrays, dict[str, Any]]:
    """Fit on handcrafted features; returns the array model and the sklearn estimators.

    The velocity regressors see slip windows only: they estimate the velocity given slip,
    and the classifier decides whether it is reported. One regresses the speed over its
    median (``target_scale``), two the direction's unit components on the slip windows that
    move; the velocity is their product (``SvmArrays.predict``). With ``angular`` (n,)
    [rad/s, NaN: no label] and at least two labelled windows, an SVR on the rate sees every
    labelled window, rotating or not (a pure rotation is planar no-slip; a translation
    teaches 0).
    """
    from sklearn.svm import SVC, SVR

    feats = np.asarray(feats, dtype=np.float64)
    slip = np.asarray(slip, dtype=bool)
    if feats.ndim != 2 or feats.shape[0] != slip.shape[0] or \
            velocity.shape != (len(slip), N_VELOCITY):
        raise ValueError(f"feats (n, F), slip (n,) and velocity (n, {N_VELOCITY}) must agree")
    if slip.all() or not slip.any():
        raise ValueError("the SVM needs both slip and no-slip training windows")
    mean = feats.mean(axis=0)
    std = np.maximum(feats.std(axis=0), 1e-6)
    z = (feats - mean) / std
    svc = SVC(kernel="rbf", C=cfg.C, gamma=cfg.gamma).fit(z, slip.astype(int))
    speed, moves, unit = speed_and_direction(np.asarray(velocity)[slip], "the SVM")
    scale = float(max(np.median(speed), 1e-4))

    def fit(rows: np.ndarray, target: np.ndarray):
        return SVR(kernel="rbf", C=cfg.svr_C, gamma=cfg.gamma,
                   epsilon=cfg.svr_epsilon).fit(rows, target)

    zs = z[slip]
    svr = {SPEED_REGRESSOR: fit(zs, speed / scale)}
    for j, name in enumerate(DIRECTION_REGRESSORS):
        svr[name] = fit(zs[moves], unit[:, j])
    rate = None
    labelled = np.zeros(len(slip), bool) if angular is None else \
        np.isfinite(np.asarray(angular, np.float64).reshape(-1))
    if labelled.sum() >= 2:
        target = np.asarray(angular, np.float64)[labelled] * (ROTATION_RADIUS_M / scale)
        svr[ANGULAR_COMPONENT] = fit(z[labelled], target)
        rate = KernelMachine.from_sklearn(svr[ANGULAR_COMPONENT])
    arrays = SvmArrays(mean=mean, std=std, slip=KernelMachine.from_sklearn(svc),
                       velocity={c: KernelMachine.from_sklearn(svr[c])
                                 for c in SPEED_DIRECTION},
                       target_scale=scale, angular=rate)
    if list(svc.classes_) != [0, 1]:
        raise ValueError(f"unexpected SVC classes {svc.classes_}")
    return arrays, {"svc": svc, **{f"svr_{c}": m for c, m in svr.items()}}


@register_model
class SvmBackend:
    """The paper's SVM baseline on handcrafted band features (learn/models/svm.py)."""

    model_type: ClassVar[str] = "svm"
    config: ClassVar[type] = SvmConfig
    streaming: ClassVar[bool] = False

    def __init__(self, arrays: SvmArrays, featurizer) -> None:
        self.arrays = arrays
        self.featurizer = featurizer
        #: On log-mel (``features: logmel``) its ``predict`` is ``infer_features`` of
        #: ``logmel`` less the offsets, as the CNN's: the live path slides those features.
        self.reads_logmel = isinstance(featurizer, LogMelMeans)
        if self.reads_logmel:
            self.logmel = featurizer.logmel

    @classmethod
    def meta_problems(cls, meta, model_config, feature_config) -> list[str]:
        problems = []
        if model_config.n_bands < 1:
            problems.append(f"model_config.n_bands must be >= 1, got {model_config.n_bands}")
        if model_config.features not in FEATURES:
            problems.append(f"model_config.features must be one of {FEATURES}, got "
                            f"{model_config.features!r}")
        return problems

    @classmethod
    def from_checkpoint(cls, ckpt: Checkpoint) -> "SvmBackend":
        fcfg = FeatureConfig.from_dict(ckpt.meta["feature_config"])
        cfg = SvmConfig(**ckpt.meta["model_config"])
        arrays = SvmArrays.from_tensors(ckpt.tensors)
        problems = angular_problems(ckpt.meta, arrays.angular is not None)
        if problems:
            raise ValueError("; ".join(problems))
        return cls(arrays, svm_featurizer(cfg, fcfg, ckpt.sample_rate))

    def predict(self, windows: np.ndarray, offsets: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        return self.arrays.predict(self.featurizer(windows, offsets))

    def infer_features(self, feats: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The model alone on log-mel ``(B, C, M, T)`` (offsets already removed); only an
        SVM on log-mel reads them."""
        return self.arrays.predict(self._logmel_means(feats))

    def predict_speed(self, windows: np.ndarray, offsets: np.ndarray | None) -> np.ndarray:
        """The speed ``(B,)`` m/s alone (``SvmArrays.speed``): a ``per_output`` speed part."""
        return self.arrays.speed(self.featurizer(windows, offsets))

    def infer_speed(self, feats: np.ndarray) -> np.ndarray:
        """``predict_speed`` on log-mel, as ``infer_features``."""
        return self.arrays.speed(self._logmel_means(feats))

    def _logmel_means(self, feats: np.ndarray) -> np.ndarray:
        if not self.reads_logmel:
            raise ValueError("this SVM reads band features, not log-mel (features: bands)")
        return LogMelMeans.means(feats)
