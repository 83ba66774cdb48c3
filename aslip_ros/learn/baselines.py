"""Plain baselines that any lab would try first: a small log-mel CNN and an RBF SVM.

Both are deliberately untuned; the package's own recipe has to beat them. They read the
same window features as the package's models, computed by ``features.LogMel`` with
:func:`baseline_features` (48 mels at the stream's own rate, n_fft 1024, 10 ms hop), so
``train.feature_cache`` serves them from an exported dataset and an experiment can hand
them arrays (for example features with a per-grasp calibration removed).

- Plain CNN: per-channel standardisation (training mean and std of each channel); three
  3x3 conv blocks (32, 32, 48 channels) with batch norm, ReLU and max pooling over
  frequency only; mean over mel; one 3-wide temporal convolution with ReLU; mean over time;
  one linear layer giving the slip logit, the magnitude (in units of the median training
  slip speed) and a 2-D direction. Adam 1e-3, 25 epochs, batch 64, loss
  BCE + 2 x (1 - cosine) + 0.5 x Huber(magnitude) + 0.2 x MSE(direction, unit truth), the
  last three over slip windows only.
- Plain SVM: the time-averaged log-mel of each channel, standardised; RBF ``SVC`` for slip,
  an RBF ``SVR`` for the speed |v| over its median on the training slip windows, and two
  RBF ``SVR``s for the direction's cosine and sine (vx/|v|, vz/|v|, slip windows that
  move), scikit-learn defaults. The velocity is the speed (clamped at 0) times the unit
  vector of (cosine, sine), zero where both are 0: the speed is regressed itself, not read
  as the norm of two component estimates, which shrink towards 0 wherever the direction is
  uncertain.

Rotational slip: given angular labels ``w`` (``(n,)`` rad/s, NaN: none; training windows
with at least one label), the plain CNN gets a fifth output, the rim speed
``wy * ROTATION_RADIUS_M`` in units of the median slip speed, trained with a Huber loss over
every labelled window (weight 1), and the plain SVM an RBF ``SVR`` on the same target over
the labelled windows. ``predict_rotation`` then gives the rate (rad/s), else None.

Arrays: ``x`` is ``(n, C, M, T)`` log-mel, ``v`` ``(n, 2)`` m/s, ``slip`` ``(n,)`` bool.
``predict`` returns ``(p_slip, raw_velocity)`` as :func:`evaluate.compute_metrics` takes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.models.svm import speed_and_direction, speed_times_direction
from aslip_ros.slip import ROTATION_RADIUS_M


def baseline_features(stream_rate: float) -> FeatureConfig:
    """The plain CNN's features: 48-mel log power at the stream's rate, 1024-point FFT,
    10 ms hop."""
    return FeatureConfig(sample_rate=float(stream_rate), n_fft=1024,
                         hop=int(round(0.01 * stream_rate)), n_mels=48, fmin=30.0)


def _check(x: np.ndarray, v: np.ndarray | None = None, slip: np.ndarray | None = None):
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != 4 or x.shape[0] == 0:
        raise ValueError(f"features must be (n, C, M, T) with n > 0, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("features contain NaN or Inf")
    if v is None:
        return x
    v = np.asarray(v, dtype=np.float32).reshape(-1, 2)
    slip = np.asarray(slip, dtype=bool).reshape(-1)
    if v.shape[0] != x.shape[0] or slip.shape[0] != x.shape[0]:
        raise ValueError("features, velocities and slip labels differ in length")
    if slip.all() or not slip.any():
        raise ValueError("training needs both slip and no-slip windows")
    return x, v, slip


def _labelled(w: np.ndarray | None, n: int) -> np.ndarray | None:
    """The angular labels as float32 ``(n,)``, None when there are none at all."""
    if w is None:
        return None
    w = np.asarray(w, dtype=np.float32).reshape(-1)
    if w.shape[0] != n:
        raise ValueError("angular labels and features differ in length")
    return w if np.isfinite(w).any() else None


class PlainCNN(nn.Module):
    """The plain log-mel CNN (module docstring); ``angular``: a fifth output, the rate."""

    def __init__(self, n_channels: int, angular: bool = False) -> None:
        super().__init__()
        blocks, c_in = [], n_channels
        for c_out in (32, 32, 48):
            blocks += [nn.Conv2d(c_in, c_out, 3, padding=1), nn.BatchNorm2d(c_out), nn.ReLU(),
                       nn.MaxPool2d((2, 1))]
            c_in = c_out
        self.conv = nn.Sequential(*blocks)
        self.temporal = nn.Conv1d(48, 48, 3, padding=1)
        self.out = nn.Linear(48, 5 if angular else 4)
        self.register_buffer("mean", torch.zeros(n_channels))
        self.register_buffer("std", torch.ones(n_channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = (x - self.mean[None, :, None, None]) / self.std[None, :, None, None]
        h = self.conv(x).mean(dim=2)                       # (B, 48, T)
        h = F.relu(self.temporal(h)).mean(dim=2)           # (B, 48)
        return self.out(h)                             # logit, magnitude, dx, dz[, rim speed]


def plain_cnn_loss(out: torch.Tensor, v: torch.Tensor, slip: torch.Tensor,
                   speed_scale: float, w: torch.Tensor | None = None) -> torch.Tensor:
    """BCE + 2 x (1 - cos) + 0.5 x Huber + 0.2 x MSE on the unit direction (slip only),
    + Huber on the rim speed over the windows with an angular label ``w`` (NaN: none)."""
    loss = F.binary_cross_entropy_with_logits(out[:, 0], slip.float())
    if w is not None and out.shape[1] > 4:
        lab = torch.isfinite(w)
        if lab.any():
            loss = loss + F.huber_loss(out[lab, 4], w[lab] * ROTATION_RADIUS_M / speed_scale)
    speed = torch.linalg.norm(v, dim=1)
    m = slip & (speed > 0)
    if m.any():
        d_true = v[m] / speed[m, None]
        d = out[m, 2:4]
        cos = F.cosine_similarity(d, d_true, dim=1, eps=1e-8)
        loss = loss + 2.0 * (1.0 - cos).mean() \
            + 0.5 * F.huber_loss(out[m, 1], speed[m] / speed_scale) \
            + 0.2 * F.mse_loss(d, d_true)
    return loss


@dataclass
class PlainCnnModel:
    net: PlainCNN
    speed_scale: float

    def predict_rotation(self, x: np.ndarray, batch: int = 512) -> np.ndarray | None:
        """The rate wy [rad/s] per window, None for a model trained without angular labels."""
        if self.net.out.out_features < 5:
            return None
        x = _check(x)
        self.net.eval()
        with torch.no_grad():
            out = [self.net(torch.from_numpy(x[s:s + batch]))[:, 4].numpy()
                   for s in range(0, x.shape[0], batch)]
        return np.concatenate(out).astype(np.float64) * (self.speed_scale / ROTATION_RADIUS_M)

    def predict(self, x: np.ndarray, batch: int = 512) -> tuple[np.ndarray, np.ndarray]:
        x = _check(x)
        self.net.eval()
        probs, vels = [], []
        with torch.no_grad():
            for s in range(0, x.shape[0], batch):
                out = self.net(torch.from_numpy(x[s:s + batch]))
                d = F.normalize(out[:, 2:4], dim=1, eps=1e-8)
                mag = torch.clamp(out[:, 1], min=0.0) * self.speed_scale
                probs.append(torch.sigmoid(out[:, 0]).numpy())
                vels.append((d * mag[:, None]).numpy())
        return np.concatenate(probs).astype(np.float64), np.concatenate(vels).astype(np.float64)


def fit_plain_cnn(x: np.ndarray, v: np.ndarray, slip: np.ndarray, *, epochs: int = 25,
                  batch: int = 64, lr: float = 1e-3, seed: int = 0,
                  w: np.ndarray | None = None) -> PlainCnnModel:
    """Train the plain CNN on all given windows (no validation, no early stopping); with
    angular labels ``w`` (rad/s, NaN: none) its rotational output too."""
    x, v, slip = _check(x, v, slip)
    w = _labelled(w, x.shape[0])
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = PlainCNN(x.shape[1], angular=w is not None)
    net.mean.copy_(torch.from_numpy(x.mean(axis=(0, 2, 3))))
    net.std.copy_(torch.from_numpy(np.maximum(x.std(axis=(0, 2, 3)), 1e-3)))
    speed = np.linalg.norm(v, axis=1)
    scale = float(np.median(speed[slip])) if np.any(speed[slip] > 0) else 1.0
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    xt, vt, st = torch.from_numpy(x), torch.from_numpy(v), torch.from_numpy(slip)
    wt = None if w is None else torch.from_numpy(w)
    net.train()
    for _ in range(epochs):
        order = torch.from_numpy(rng.permutation(x.shape[0]))
        for s in range(0, x.shape[0] - 1, batch):
            b = order[s:s + batch]
            if b.numel() < 2:          # batch norm needs two samples
                continue
            opt.zero_grad()
            loss = plain_cnn_loss(net(xt[b]), vt[b], st[b], scale,
                                  None if wt is None else wt[b])
            loss.backward()
            opt.step()
    return PlainCnnModel(net.eval(), scale)


@dataclass
class PlainSvmModel:
    scaler: object
    svc: object
    svr_speed: object           # |v| / speed_scale
    svr_cos: object             # vx / |v|
    svr_sin: object             # vz / |v|
    speed_scale: float
    svr_w: object = None        # the rim speed / speed_scale; None: no angular labels

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = self.scaler.transform(svm_features(x))
        p = 1.0 / (1.0 + np.exp(-self.svc.decision_function(f)))
        direction = np.stack([self.svr_cos.predict(f), self.svr_sin.predict(f)], axis=1)
        vel = speed_times_direction(self.svr_speed.predict(f) * self.speed_scale, direction)
        return p.astype(np.float64), vel

    def predict_rotation(self, x: np.ndarray) -> np.ndarray | None:
        """The rate wy [rad/s] per window, None for a model trained without angular labels."""
        if self.svr_w is None:
            return None
        f = self.scaler.transform(svm_features(x))
        return self.svr_w.predict(f) * (self.speed_scale / ROTATION_RADIUS_M)


def svm_features(x: np.ndarray) -> np.ndarray:
    """Time-averaged log-mel of each channel, ``(n, C * M)``."""
    x = _check(x)
    return x.mean(axis=3).reshape(x.shape[0], -1).astype(np.float64)


def fit_plain_svm(x: np.ndarray, v: np.ndarray, slip: np.ndarray, *, max_train: int = 4000,
                  seed: int = 0, w: np.ndarray | None = None) -> PlainSvmModel:
    """RBF SVC (slip) and SVRs (the speed over its median on slip windows; the direction's
    cosine and sine on slip windows that move; wy on windows with an angular label ``w``,
    when given) on time-averaged log-mel.

    At most ``max_train`` windows (a random subset) keep the kernel fits to minutes.
    """
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC, SVR

    x, v, slip = _check(x, v, slip)
    w = _labelled(w, x.shape[0])
    rng = np.random.default_rng(seed)
    idx = np.arange(x.shape[0])
    if idx.size > max_train:
        idx = np.sort(rng.choice(idx, max_train, replace=False))
    f = svm_features(x[idx])
    scaler = StandardScaler().fit(f)
    f = scaler.transform(f)
    s = slip[idx]
    svc = SVC(kernel="rbf").fit(f, s)
    speed, moves, unit = speed_and_direction(v[idx][s], "the plain SVM")
    median = float(np.median(speed))
    scale = median if median > 0 else float(np.median(speed[moves]))
    svr_speed = SVR(kernel="rbf").fit(f[s], speed / scale)
    svr_cos = SVR(kernel="rbf").fit(f[s][moves], unit[:, 0])
    svr_sin = SVR(kernel="rbf").fit(f[s][moves], unit[:, 1])
    svr_w = None
    if w is not None and np.isfinite(w[idx]).sum() >= 2:
        lab = np.isfinite(w[idx])
        svr_w = SVR(kernel="rbf").fit(f[lab], w[idx][lab] * ROTATION_RADIUS_M / scale)
    return PlainSvmModel(scaler, svc, svr_speed, svr_cos, svr_sin, scale, svr_w)


def run_on_dataset(ds, kinds=("cnn", "svm"), *, split_seed: int = 0, test_split: str = "test",
                   epochs: int = 25, seed: int = 0, cache_dir=None,
                   n_boot: int = 500, train_splits: tuple[str, ...] = ("train",)
                   ) -> dict[str, dict]:
    """Train each baseline on an exported dataset's ``train_splits`` trials (``("train",
    "val")``: every trial ``aslip train``'s final model may train on; a plain baseline has
    nothing to choose on them) and report the metrics (with trial-bootstrap intervals) on
    ``test_split``; the same split and feature cache as ``aslip train``. ``ds`` is a
    ``data_io.WindowSet``."""
    from aslip_ros.learn.data_io import select_windows
    from aslip_ros.learn.stats import bootstrap_metrics
    from aslip_ros.learn.training.data import feature_cache

    feats = feature_cache(ds, baseline_features(ds.sample_rate), ds.channel_names,
                          cache_dir=cache_dir)
    tr = np.sort(np.concatenate([select_windows(ds, s, seed=split_seed)
                                 for s in train_splits]))
    te = select_windows(ds, test_split, seed=split_seed)
    if tr.size == 0 or te.size == 0:
        raise ValueError(f"{ds.root}: the split (seed {split_seed}) leaves no training or no "
                         f"{test_split} trials; use more trials")
    x_tr = np.asarray(feats[tr], dtype=np.float32)
    x_te = np.asarray(feats[te], dtype=np.float32)
    w_tr = ds.angular(tr) if ds.has_angular(tr) else None
    out = {}
    for kind in kinds:
        if kind == "cnn":
            model = fit_plain_cnn(x_tr, ds.velocity(tr), ds.slip(tr), epochs=epochs, seed=seed,
                                  w=w_tr)
        elif kind == "svm":
            model = fit_plain_svm(x_tr, ds.velocity(tr), ds.slip(tr), seed=seed, w=w_tr)
        else:
            raise ValueError(f"unknown baseline {kind!r}; choose cnn or svm")
        p, vel = model.predict(x_te)
        rot = {"angular": model.predict_rotation(x_te), "true_angular": ds.angular(te)} \
            if ds.has_angular(te) else {}
        out[f"plain_{kind}"] = bootstrap_metrics(ds.windows["trial"][te], p, vel,
                                                 ds.velocity(te), ds.slip(te), ds.window_s,
                                                 n_boot=n_boot, seed=seed, **rot)
    return out
