"""The training pipeline of ``aslip train`` (the command line is learn/training/cli.py).

- ``train_backend``: any model type whose backend defines ``fit`` (docs/design.md): the
  built-in CNN's stages (pretrain, finetune, scratch: learn/models/aslip_cnn_fit.py, named
  by ``CnnBackend.fit``) as a plug-in's;
- ``train_svm``: the handcrafted-feature SVM baseline.

Rotational slip: a dataset whose training windows carry angular labels (``wy``, dataset
version 2) gives every model a rotational output (the CNN's ``angular`` head, the SVM's
rate regressor; ``outputs`` in the checkpoint lists ``wy``). Without labels everything
trains as before.

Per-grasp calibration (``--calibration``, default ``background`` on the command line): the
constants are fitted on the training trials and every window is read with its own trial's
causal calibration removed (``calibration.frames``); the constants go into the checkpoint
under ``calibration``. ``off`` trains on raw features as before.

Every trainer writes its checkpoint document with ``checkpoint.checkpoint_meta``.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np

from aslip_ros.learn.models.registry import model_fit
from aslip_ros.learn.models.svm import SvmBackend
from aslip_ros.learn.calibration.frames import training_calibration
from aslip_ros.learn.checkpoint import Checkpoint, checkpoint_meta
from aslip_ros.learn.data_io import WindowSet
from aslip_ros.learn.metrics import compute_metrics
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.calibration.output import checkpoint_fields
from aslip_ros.learn.models.svm import SvmConfig, fit_svm, moving, svm_featurizer
from aslip_ros.learn.training.data import rotation_args, split_windows
from aslip_ros.learn.inference.predictor import Predictor
from aslip_ros.learn.training.config import TrainConfig, TrainResult, provenance


# --- SVM ----------------------------------------------------------------------------------

def train_svm(ds: WindowSet, cfg: TrainConfig, *, feature_config: FeatureConfig | None = None,
              svm_config: SvmConfig = SvmConfig(), channels: Sequence[str] | None = None,
              log: Callable[[str], None] = print) -> TrainResult:
    """Fit the SVM baseline on (at most ``svm_config.max_train``) training windows, on the
    features ``svm_config.features`` names (band features or time-averaged log-mel)."""
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
    featurizer = svm_featurizer(svm_config, fcfg, ds.sample_rate)

    def feats(idx: np.ndarray) -> np.ndarray:
        chunks = (idx[s:s + 512] for s in range(0, idx.size, 512))
        return np.concatenate([featurizer(ds.window_audio(c, cols),
                                          None if offsets is None else offsets[c])
                               for c in chunks])

    t0 = time.perf_counter()
    arrays, _ = fit_svm(feats(tr), ds.slip(tr), ds.velocity(tr), svm_config,
                        angular=ds.angular(tr) if ds.has_angular(tr) else None)
    if va.size:
        prob, v, w = arrays.predict(feats(va))
        val_metrics = compute_metrics(prob, v, ds.velocity(va), ds.slip(va), ds.window_s,
                                      **rotation_args(ds, va, w))
    else:                # no validation (learn/training/folds.py fits the rest)
        val_metrics = {}
    prov = provenance(ds, cfg, None)
    prov.update(metrics={"val": val_metrics},
                training={"train_time_s": time.perf_counter() - t0,
                          "n_train_windows": int(tr.size), "n_val_windows": int(va.size)})
    meta = checkpoint_meta(
        SvmBackend.model_type, svm_config, fcfg, ds, channels, provenance=prov,
        calibration=cal, train_config=cfg.to_dict(), angular=arrays.angular is not None,
        normalization={"mean": arrays.mean.tolist(), "std": arrays.std.tolist(),
                       "scope": "per handcrafted feature over training windows"})
    if not va.size:
        return TrainResult(meta=meta, tensors=arrays.to_tensors(), history=[], model=arrays)
    meta.update(checkpoint_fields(prob, v, ds.velocity(va), ds.slip(va), w_pred=w,
                                  w_true=ds.angular(va)))
    return TrainResult(meta=meta, tensors=arrays.to_tensors(), history=[], model=arrays,
                       val_pred={"prob": prob, "v": v, "w": w})


# --- a model type's own stage --------------------------------------------------------------

def train_backend(backend: type, ds: WindowSet, cfg: TrainConfig, *,
                  feature_config: FeatureConfig | None = None,
                  channels: Sequence[str] | None = None,
                  log: Callable[[str], None] = print, **options: Any) -> TrainResult:
    """Train a model type through its backend's ``fit`` (``aslip train --stage <stage>``:
    the model type, or a stage its backend names in ``stages``).

    ``fit(ds, train_idx, channels=..., feature_config=..., config=cfg, **options)``
    (``registry.model_fit``; ``options``: that model's own, e.g. the CNN's ``init``)
    returns ``(model_config, tensors)``; the rest is the pipeline's, as for the built-in
    models: the by-trial split, the checkpoint document, the validation metrics and the
    output calibration (threshold and direction sigma), all from the model's own
    predictions on the validation trials through ``learn.inference.predictor.Predictor``.
    A fit that validates itself and writes its own document (the CNN, with early stopping
    on the validation trials) returns the whole ``TrainResult`` instead.
    """
    fit = model_fit(backend)
    if fit is None:
        raise ValueError(f"model type {backend.model_type!r} has no training stage (fit)")
    channels = list(channels or ds.channel_names)
    cols = ds.channel_indices(channels)
    fcfg = feature_config or FeatureConfig()
    tr, va = split_windows(ds, cfg)
    t0 = time.perf_counter()
    fitted = fit(ds, tr, channels=channels, feature_config=fcfg, config=cfg, **options)
    if isinstance(fitted, TrainResult):
        return fitted
    model_config, tensors = fitted
    prov = provenance(ds, cfg, None)
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
