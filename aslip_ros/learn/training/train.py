"""The training stages of ``aslip train`` (the command line is learn/training/cli.py).

- ``train_cnn``: pretrain (all weights, robot-induced data), finetune (from an init: encoder
  frozen or partly trainable, heads), scratch (all weights, no initialisation);
- ``train_svm``: the handcrafted-feature SVM baseline;
- ``train_backend``: any model type whose backend defines ``fit`` (docs/design.md).

``--device`` (default cpu; auto: a CUDA GPU where torch sees one) moves the network and its
batches; checkpoints always hold CPU tensors.

Rotational slip: a dataset whose training windows carry angular labels (``wy``, dataset
version 2) gives every model a rotational output (the CNN's ``angular`` head, the SVM's
rate regressor; ``outputs`` in the checkpoint lists ``wy``); a finetune whose init has none
gets a new head. Without labels everything trains as before.

Per-grasp calibration (``--calibration``, default ``background`` on the command line): the
constants are fitted on the training trials and every window is read with its own trial's
causal calibration removed (``calibration.frames``); the constants go into the checkpoint
under ``calibration``. ``off`` trains on raw features as before.

Log-mel features of every dataset window are cached once beside the dataset
(learn/training/data.py); the CNN's epoch loop is learn/training/loop.py; every trainer writes
its checkpoint document with ``checkpoint.checkpoint_meta``.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as _dt
import os
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from aslip_ros.learn.models.registry import CNN
from aslip_ros.learn.models.svm import SvmBackend
from aslip_ros.learn.calibration.frames import remove_from_audio, training_calibration
from aslip_ros.learn.checkpoint import Checkpoint, checkpoint_meta, git_revision, load_checkpoint
from aslip_ros.learn.data_io import WindowSet
from aslip_ros.learn.metrics import compute_metrics
from aslip_ros.learn.features import FeatureConfig, normalization_stats
from aslip_ros.learn.training.losses import LossWeights
from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet
from aslip_ros.learn.calibration.output import checkpoint_fields
from aslip_ros.learn.models.svm import SvmConfig, SvmFeaturizer, fit_svm, moving
from aslip_ros.learn.training.data import Batches, feature_cache, split_windows
from aslip_ros.learn.inference.predictor import Predictor
from aslip_ros.learn.training.config import TrainConfig, TrainResult
from aslip_ros.learn.training.loop import EpochRun, evaluate_loss, resolve_device


# --- steps -------------------------------------------------------------------------------

def _seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed % (2 ** 32))


def _provenance(ds: WindowSet, cfg: TrainConfig, init: str | None) -> dict[str, Any]:
    return {"dataset": str(Path(ds.root).resolve()), "dataset_fingerprint": ds.fingerprint(),
            "git_revision": git_revision(), "seed": cfg.seed, "split_seed": cfg.split_seed,
            "stage": cfg.stage, "init": init, "torch_version": torch.__version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "filters": {"induced": cfg.induced, "objects": cfg.to_dict()["objects"],
                        "conditions": cfg.to_dict()["conditions"]}}


# --- CNN ----------------------------------------------------------------------------------

def _init_name(init: str | os.PathLike | Checkpoint | None) -> str | None:
    if isinstance(init, Checkpoint):
        return "in memory, pretrained on " + str(init.meta.get("provenance", {}).get("dataset"))
    return str(init) if init else None


def _open_init(ds: WindowSet, cfg: TrainConfig, init: str | os.PathLike | Checkpoint | None
               ) -> Checkpoint | None:
    """The checkpoint to finetune from, checked against the dataset (None without one)."""
    init_ckpt = init if isinstance(init, Checkpoint) else load_checkpoint(init) if init else None
    if cfg.stage == "finetune" and init_ckpt is None:
        raise ValueError("--stage finetune needs --init <checkpoint>")
    if init_ckpt is None:
        return None
    if init_ckpt.model_type != CNN:
        raise ValueError("--init must be a CNN checkpoint")
    init_ckpt.check_compatible(ds.sample_rate, [ds.channel_names[c] for c in
                                                ds.channel_indices(init_ckpt.channel_names)])
    if int(init_ckpt.meta["window_samples"]) != ds.window_samples:
        raise ValueError("the --init checkpoint was trained on another window length")
    return init_ckpt


def rotation_args(ds: WindowSet, idx: np.ndarray, w_pred: np.ndarray | None
                  ) -> dict[str, Any]:
    """``compute_metrics``' rotational arguments for windows ``idx`` (none when they have no
    angular label): the labels and the model's raw rates (None: no rotational output)."""
    w_true = ds.angular(idx)
    if not np.isfinite(w_true).any():
        return {}
    return {"angular": w_pred, "true_angular": w_true}


def _init_model(init_ckpt: Checkpoint, angular: bool) -> SlipNet:
    """The init's network; with ``angular`` and an init without a rotational head, a new
    head (randomly initialised) beside its trained weights."""
    cfg = ModelConfig.from_dict(init_ckpt.meta["model_config"])
    if not angular or cfg.angular:
        model = SlipNet(cfg)
        model.load_state_dict(init_ckpt.tensors)
        return model
    model = SlipNet(dataclasses.replace(cfg, angular=True))
    missing, unexpected = model.load_state_dict(init_ckpt.tensors, strict=False)
    if unexpected or any(not k.startswith("heads.angular.") for k in missing):
        raise ValueError(f"the --init checkpoint's weights do not fit its model config "
                         f"(missing {missing}, unexpected {unexpected})")
    return model


def _build_model(ds: WindowSet, init_ckpt: Checkpoint | None, feats: np.ndarray,
                 tr: np.ndarray, channels: list[str], fcfg: FeatureConfig,
                 model_options: dict[str, Any] | None, rng: np.random.Generator) -> SlipNet:
    """The init checkpoint's network, or a new one normalised on the training windows with
    the median training slip speed as its speed scale; with a rotational head when the
    training windows carry angular labels."""
    angular = ds.has_angular(tr)
    if init_ckpt is not None:
        return _init_model(init_ckpt, angular)
    mean, std = normalization_stats(feats[np.sort(tr)] if tr.size <= 20000 else
                                    feats[np.sort(rng.choice(tr, 20000, replace=False))])
    slip_speed = ds.speed(tr)[ds.slip(tr)]
    scale = float(np.median(slip_speed)) if slip_speed.size else 0.02
    options = {"angular": angular, **dict(model_options or {})}
    mcfg = ModelConfig(n_channels=len(channels), n_mels=fcfg.n_mels,
                       speed_scale=max(scale, 1e-4), **options)
    model = SlipNet(mcfg)
    model.set_normalization(mean, std)
    return model


def _cnn_meta(ds: WindowSet, cfg: TrainConfig, model: SlipNet, fcfg: FeatureConfig,
              channels: list[str], weights: LossWeights, cal: Any, prov: dict[str, Any]
              ) -> dict[str, Any]:
    return checkpoint_meta(
        CNN, model.cfg, fcfg, ds, channels, provenance=prov, calibration=cal,
        angular=model.cfg.angular,
        normalization={"mean": model.feat_mean.tolist(), "std": model.feat_std.tolist(),
                       "scope": "per mel bin over training windows, channels and frames"},
        loss_weights=weights.to_dict(), train_config=cfg.to_dict())


class CnnJob:
    """One CNN training run that can be paused: ``advance(seconds)`` trains whole epochs
    for about that long, ``val_metrics()`` scores the best epoch so far on the validation
    trials, ``result()`` ends the run with the best epoch's weights. ``train_cnn`` is one
    uninterrupted job; ``aslip train --stage auto`` resumes the candidates that survive
    each round of its budget allocator (learn/training/recipes.py)."""

    def __init__(self, ds: WindowSet, cfg: TrainConfig, *,
                 feature_config: FeatureConfig | None = None,
                 model_options: dict[str, Any] | None = None,
                 channels: Sequence[str] | None = None,
                 init: str | os.PathLike | Checkpoint | None = None,
                 weights: LossWeights = LossWeights(),
                 cache_dir: str | os.PathLike | None = None,
                 log: Callable[[str], None] = print) -> None:
        torch.set_num_threads(max(1, cfg.threads))
        self.device = resolve_device(cfg.device)
        _seed_everything(cfg.seed)
        rng = np.random.default_rng(cfg.seed)
        init_ckpt = _open_init(ds, cfg, init)
        if init_ckpt is not None:   # the init's channels and features: its weights read those
            channels = init_ckpt.channel_names
            feature_config = FeatureConfig.from_dict(init_ckpt.meta["feature_config"])
        self.channels = list(channels or ds.channel_names)
        self.fcfg = feature_config or FeatureConfig()
        self.ds, self.cfg, self.weights, self.init = ds, cfg, weights, init
        self.init_ckpt = init_ckpt

        t0 = time.perf_counter()
        feats = feature_cache(ds, self.fcfg, self.channels, cache_dir, progress=cfg.progress)
        self.tr, self.va = split_windows(ds, cfg)
        reuse = None if init_ckpt is None else init_ckpt.meta.get("calibration")
        self.cal, offsets = training_calibration(ds, cfg.calibration, self.channels, self.fcfg,
                                                 self.tr, self.va, reuse, log)
        self.feature_time_s = time.perf_counter() - t0
        self.data = Batches(feats, ds, offsets)
        self.model = _build_model(ds, init_ckpt, feats, self.tr, self.channels, self.fcfg,
                                  model_options, rng)
        if cfg.stage == "finetune":
            self.model.freeze_encoder(cfg.finetune_trainable)
        self.model.to(self.device)
        self.run = EpochRun(self.model, self.data, self.tr, self.va, cfg, weights, rng, log)

    @property
    def done(self) -> bool:
        return self.run.done

    @property
    def train_time_s(self) -> float:
        return self.run.train_time_s

    def advance(self, seconds: float) -> None:
        self.run.advance(seconds)

    def _predict_val(self) -> dict[str, np.ndarray]:
        _, pred = evaluate_loss(self.model, self.data, self.va, self.weights)
        return pred

    def val_metrics(self) -> dict[str, Any]:
        """The best epoch's validation metrics; training resumes from the current weights."""
        current = copy.deepcopy(self.model.state_dict())
        self.model.load_state_dict(self.run.best_state())
        pred = self._predict_val()
        self.model.load_state_dict(current)
        return compute_metrics(pred["prob"], pred["v"], self.data.v[self.va],
                               self.data.slip[self.va], self.ds.window_s,
                               **rotation_args(self.ds, self.va, pred["w"]))

    def result(self, stop_reason: str = "time_budget") -> TrainResult:
        """End the run: the best epoch's weights, its metrics and the checkpoint document."""
        fit = self.run.finish(stop_reason)
        ds, cfg, data, va = self.ds, self.cfg, self.data, self.va
        pred = self._predict_val()
        model = self.model.to("cpu")
        val_metrics = compute_metrics(pred["prob"], pred["v"], data.v[va], data.slip[va],
                                      ds.window_s, **rotation_args(ds, va, pred["w"]))
        prov = _provenance(ds, cfg, _init_name(self.init))
        prov["device"] = str(self.device)
        if self.init_ckpt is not None:
            prov["init_provenance"] = {k: self.init_ckpt.meta.get("provenance", {}).get(k)
                                       for k in ("dataset", "stage", "seed", "git_revision")}
        prov.update(metrics={"val": val_metrics, "best_val_loss": fit.best_loss},
                    training={"best_epoch": fit.best_epoch, "epochs_run": len(fit.history),
                              "stop_reason": fit.stop_reason,
                              "train_time_s": fit.train_time_s,
                              "feature_time_s": self.feature_time_s,
                              "n_train_windows": int(self.tr.size),
                              "n_val_windows": int(va.size)})
        meta = _cnn_meta(ds, cfg, model, self.fcfg, self.channels, self.weights, self.cal,
                         prov)
        meta.update(checkpoint_fields(pred["prob"], pred["v"], data.v[va], data.slip[va],
                                      w_pred=pred["w"], w_true=data.w[va]))
        model.eval()
        tensors = {k: v.detach().clone() for k, v in model.state_dict().items()}
        return TrainResult(meta=meta, tensors=tensors, history=fit.history, model=model,
                           val_pred=pred)


def train_cnn(ds: WindowSet, cfg: TrainConfig, *, feature_config: FeatureConfig | None = None,
              model_options: dict[str, Any] | None = None,
              channels: Sequence[str] | None = None,
              init: str | os.PathLike | Checkpoint | None = None,
              weights: LossWeights = LossWeights(), cache_dir: str | os.PathLike | None = None,
              log: Callable[[str], None] = print) -> TrainResult:
    """Train (pretrain / scratch) or finetune (``init`` given, a path or a loaded checkpoint;
    encoder frozen but for ``cfg.finetune_trainable``) the CNN on ``cfg.device``, within
    ``cfg.time_budget_s``."""
    job = CnnJob(ds, cfg, feature_config=feature_config, model_options=model_options,
                 channels=channels, init=init, weights=weights, cache_dir=cache_dir, log=log)
    job.advance(cfg.time_budget_s)
    return job.result()


# --- SVM ----------------------------------------------------------------------------------

def train_svm(ds: WindowSet, cfg: TrainConfig, *, feature_config: FeatureConfig | None = None,
              svm_config: SvmConfig = SvmConfig(), channels: Sequence[str] | None = None,
              log: Callable[[str], None] = print) -> TrainResult:
    """Fit the SVM baseline on (at most ``svm_config.max_train``) training windows."""
    rng = np.random.default_rng(cfg.seed)
    channels = list(channels or ds.channel_names)
    cols = ds.channel_indices(channels)
    fcfg = feature_config or FeatureConfig()
    tr, va = split_windows(ds, cfg)
    cal, offsets = training_calibration(ds, cfg.calibration, channels, fcfg, tr, va, None,
                                        log)
    # Slip or rotating windows are the positives of the balanced subsample.
    slip_all = moving(ds.slip(np.arange(len(ds))), ds.angular(np.arange(len(ds))))
    if tr.size > svm_config.max_train:
        # Balanced subsample: SVC cost grows quadratically with the training set.
        pos, neg = tr[slip_all[tr]], tr[~slip_all[tr]]
        n_pos = min(pos.size, svm_config.max_train // 2)
        n_neg = min(neg.size, svm_config.max_train - n_pos)
        tr = np.sort(np.concatenate([rng.choice(pos, n_pos, replace=False),
                                     rng.choice(neg, n_neg, replace=False)]))
    featurizer = SvmFeaturizer(fcfg, ds.sample_rate, svm_config.n_bands)

    def audio(idx: np.ndarray) -> np.ndarray:
        a = ds.window_audio(idx, cols)
        return a if offsets is None else remove_from_audio(a, offsets[idx])

    def feats(idx: np.ndarray) -> np.ndarray:
        return np.concatenate([featurizer(audio(idx[s:s + 512]))
                               for s in range(0, idx.size, 512)])

    t0 = time.perf_counter()
    arrays, _ = fit_svm(feats(tr), ds.slip(tr), ds.velocity(tr), svm_config,
                        angular=ds.angular(tr) if ds.has_angular(tr) else None)
    prob, v, w = arrays.predict(feats(va))
    val_metrics = compute_metrics(prob, v, ds.velocity(va), ds.slip(va), ds.window_s,
                                  **rotation_args(ds, va, w))
    prov = _provenance(ds, cfg, None)
    prov.update(metrics={"val": val_metrics},
                training={"train_time_s": time.perf_counter() - t0,
                          "n_train_windows": int(tr.size), "n_val_windows": int(va.size)})
    meta = checkpoint_meta(
        SvmBackend.model_type, svm_config, fcfg, ds, channels, provenance=prov,
        calibration=cal, train_config=cfg.to_dict(), angular=w is not None,
        normalization={"mean": arrays.mean.tolist(), "std": arrays.std.tolist(),
                       "scope": "per handcrafted feature over training windows"})
    meta.update(checkpoint_fields(prob, v, ds.velocity(va), ds.slip(va), w_pred=w,
                                  w_true=ds.angular(va)))
    return TrainResult(meta=meta, tensors=arrays.to_tensors(), history=[], model=arrays,
                       val_pred={"prob": prob, "v": v, "w": w})


# --- a model type's own stage --------------------------------------------------------------

def train_backend(backend: type, ds: WindowSet, cfg: TrainConfig, *,
                  feature_config: FeatureConfig | None = None,
                  channels: Sequence[str] | None = None,
                  log: Callable[[str], None] = print) -> TrainResult:
    """Train a model type through its backend's ``fit`` (``aslip train --stage <type>``).

    ``backend.fit(ds, train_idx, channels=..., feature_config=..., config=cfg)`` returns
    ``(model_config, tensors)``; the rest is the pipeline's, as for the built-in models:
    the by-trial split, the checkpoint document, the validation metrics and the output
    calibration (threshold and direction sigma), all from the model's own predictions on the
    validation trials through ``learn.inference.predictor.Predictor``.
    """
    channels = list(channels or ds.channel_names)
    cols = ds.channel_indices(channels)
    fcfg = feature_config or FeatureConfig()
    tr, va = split_windows(ds, cfg)
    t0 = time.perf_counter()
    model_config, tensors = backend.fit(ds, tr, channels=channels, feature_config=fcfg,
                                        config=cfg)
    prov = _provenance(ds, cfg, None)
    meta = checkpoint_meta(backend.model_type, model_config, fcfg, ds, channels,
                           normalization=None, provenance=prov, train_config=cfg.to_dict())
    pred = Predictor(Checkpoint(meta=meta, tensors=dict(tensors)))
    parts = [pred.predict_batch(ds.window_audio(va[s:s + 512], cols))
             for s in range(0, va.size, 512)]
    prob = np.concatenate([b.probability for b in parts])
    raw = np.concatenate([b.raw_velocity for b in parts])
    prov.update(metrics={"val": compute_metrics(prob, raw, ds.velocity(va), ds.slip(va),
                                                ds.window_s)},
                training={"train_time_s": time.perf_counter() - t0,
                          "n_train_windows": int(tr.size), "n_val_windows": int(va.size)})
    meta.update(checkpoint_fields(prob, raw, ds.velocity(va), ds.slip(va)))
    log(f"{backend.model_type}: trained on {tr.size} windows")
    return TrainResult(meta=meta, tensors=dict(tensors), history=[])
