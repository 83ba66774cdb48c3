"""Choosing on folds by trial where the validation split is too few trials to choose on.

One split of a lab-sized recording holds out 3 validation trials, and on 3 trials the
ranking of the candidates is chance: on a scene where each trial slips mostly one way, the
candidate that validated best on 3 trials tested 47 % worse in direction on 12 (#36).
Below ``K_FOLD_BELOW`` validation trials ``aslip train`` therefore chooses on folds:

- ``trial_folds`` shares the split's training and validation trials out into up to
  ``N_FOLDS`` folds, whole trials each, stratified by object and condition as the split
  itself (``data.dataset.split_trials``); the test trials stay out of every fold;
- every candidate trains once per fold, validating on that fold (``FoldJob``, a ``Job`` the
  budget allocator runs as it runs one), and is scored on its out-of-fold predictions,
  pooled over every trial of the folds: the recipe, calibrated or not, each output's
  candidate, the output calibration (threshold, direction sigma) and the intervals over
  trials all come from those predictions;
- the stopping epoch is the mean of the folds' best epochs (``cv_epochs``), and ``refit``
  trains each chosen candidate once more on every trial of the folds for that many epochs,
  with no validation, giving it the pooled predictions' output calibration and metrics.

So the final model is trained on every training trial, and the figures that chose it were
measured on trials its fold models never saw.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any, Callable

import numpy as np

from aslip_ros.learn.calibration.output import checkpoint_fields
from aslip_ros.learn.data_io import WindowSet
from aslip_ros.learn.metrics import compute_metrics
from aslip_ros.learn.training.allocation import Job
from aslip_ros.learn.training.config import TrainConfig, TrainResult
from aslip_ros.learn.training.data import rotation_args, split_windows

#: Fewer validation trials than this in the split: choose on folds by trial.
K_FOLD_BELOW = 5
#: Folds at most (each trains on the others): more folds, more training per candidate.
N_FOLDS = 3
#: Share of the CNN time kept for the final models (``refit``) when choosing on folds.
REFIT_FRACTION = 0.25


def trial_folds(ds: WindowSet, cfg: TrainConfig) -> list[tuple[int, ...]] | None:
    """The folds' trial indices, or None where the split's validation trials are enough
    (``K_FOLD_BELOW``) or the trials too few for two folds of two."""
    from aslip_ros.data.dataset import split_trials
    tr, va = split_windows(ds, dataclasses.replace(cfg, val_trials=None))
    trial = np.asarray(ds.windows["trial"])
    if np.unique(trial[va]).size >= K_FOLD_BELOW:
        return None
    dev = np.unique(trial[np.concatenate([tr, va])])
    k = min(N_FOLDS, dev.size // 2)
    if k < 2:
        return None
    parts = split_trials([ds.trials[int(t)] for t in dev],
                         {f"fold{i}": 1.0 for i in range(k)}, seed=cfg.split_seed)
    folds = [tuple(sorted(int(dev[p]) for p in parts[f"fold{i}"])) for i in range(k)]
    return [f for f in folds if f] if sum(bool(f) for f in folds) >= 2 else None


def fold_windows(ds: WindowSet, cfg: TrainConfig, folds: list[tuple[int, ...]]
                 ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Every fold's windows, pooled in window order, and each fold's validation windows."""
    vas = [split_windows(ds, dataclasses.replace(cfg, val_trials=f))[1] for f in folds]
    return np.sort(np.concatenate(vas)), vas


def fold_trial_names(ds: WindowSet, folds: list[tuple[int, ...]]) -> list[list[str]]:
    """Each fold's trials by their ids."""
    return [[str(ds.trials[t].get("id", t)) for t in f] for f in folds]


def _pool(preds: list[dict[str, Any]], vas: list[np.ndarray]) -> dict[str, Any]:
    """Per-fold predictions (each in its fold's window order) in pooled window order."""
    order = np.argsort(np.concatenate(vas), kind="stable")
    out: dict[str, Any] = {}
    for key in ("prob", "v", "w"):
        parts = [p.get(key) for p in preds]
        out[key] = None if any(x is None for x in parts) else \
            np.concatenate([np.asarray(x) for x in parts])[order]
    return out


def _metrics(ds: WindowSet, va: np.ndarray, pred: dict[str, Any]) -> dict[str, Any]:
    return compute_metrics(pred["prob"], pred["v"], ds.velocity(va), ds.slip(va),
                           ds.window_s, **rotation_args(ds, va, pred["w"]))


def _apply_pooled(meta: dict[str, Any], ds: WindowSet, va: np.ndarray,
                  pred: dict[str, Any]) -> None:
    """``meta``'s output calibration and validation metrics from the pooled predictions."""
    meta.update(checkpoint_fields(pred["prob"], pred["v"], ds.velocity(va), ds.slip(va),
                                  w_pred=pred["w"], w_true=ds.angular(va)))
    meta["provenance"].setdefault("metrics", {})["val"] = _metrics(ds, va, pred)


class FoldJob:
    """One candidate trained once per fold: a ``Job`` whose slices go to the folds' jobs in
    equal shares and whose validation figures are the pooled out-of-fold ones.
    ``start(cfg)``: the candidate's job for a config (its ``val_trials``: the fold);
    ``windows``: ``fold_windows(ds, cfg, folds)`` where the caller has it already."""

    def __init__(self, ds: WindowSet, cfg: TrainConfig, folds: list[tuple[int, ...]],
                 start: Callable[[TrainConfig], Job],
                 windows: tuple[np.ndarray, list[np.ndarray]] | None = None) -> None:
        self.ds, self.folds = ds, folds
        self.va, self.vas = windows if windows is not None else fold_windows(ds, cfg, folds)
        self.jobs = [start(dataclasses.replace(cfg, val_trials=f)) for f in folds]

    @property
    def done(self) -> bool:
        return all(j.done for j in self.jobs)

    @property
    def train_time_s(self) -> float:
        return sum(j.train_time_s for j in self.jobs)

    def advance(self, seconds: float) -> None:
        active = [j for j in self.jobs if not j.done]
        for j in active:
            j.advance(seconds / len(active))

    def val_metrics(self) -> dict[str, Any]:
        return _metrics(self.ds, self.va,
                        _pool([j.val_predictions() for j in self.jobs], self.vas))

    def result(self, stop_reason: str = "time_budget") -> TrainResult:
        """The candidate's cross-validated result: fold 0's model (for its kind and cost;
        ``refit`` makes the final one), the pooled predictions, their metrics and output
        calibration, and the folds' best epochs under ``provenance["folds"]``."""
        results = [j.result(stop_reason) for j in self.jobs]
        if any(r.val_pred is None for r in results):
            raise ValueError("a fold's job gave no validation predictions")
        pred = _pool([r.val_pred for r in results], self.vas)
        meta = copy.deepcopy(results[0].meta)
        prov = meta["provenance"]
        epochs = [r.meta["provenance"].get("training", {}).get("best_epoch")
                  for r in results]
        prov["folds"] = {
            "trials": fold_trial_names(self.ds, self.folds),
            "best_epochs": epochs, "epochs": cv_epochs(epochs),
            "val": [r.meta["provenance"]["metrics"]["val"] for r in results]}
        training = prov.setdefault("training", {})
        reasons = sorted({str(r.meta["provenance"].get("training", {}).get("stop_reason"))
                          for r in results} - {"None"})
        training.update(best_epoch=prov["folds"]["epochs"],
                        stop_reason=", ".join(reasons) or None,
                        train_time_s=self.train_time_s, n_val_windows=int(self.va.size))
        _apply_pooled(meta, self.ds, self.va, pred)
        return TrainResult(meta=meta, tensors=results[0].tensors, history=results[0].history,
                           model=results[0].model, val_pred=pred)


def cv_epochs(best_epochs: list[Any]) -> int | None:
    """Epochs for the final model: the folds' mean best epoch, counted from 1 (None for a
    model without epochs, the SVM)."""
    got = [int(e) for e in best_epochs if e is not None and int(e) >= 0]
    return max(1, int(round(float(np.mean(got)))) + 1) if got else None


def refit(ds: WindowSet, cfg: TrainConfig, cv: TrainResult, va: np.ndarray,
          start: Callable[[TrainConfig], Job], budget_s: float,
          log: Callable[[str], None] = print) -> TrainResult:
    """The candidate of ``cv`` (a ``FoldJob`` result) trained on every trial of the folds,
    for the folds' epochs and within ``budget_s``; its output calibration, metrics and
    ``val_pred`` are the pooled out-of-fold ones of ``cv`` (on the windows ``va``)."""
    folds = cv.meta["provenance"]["folds"]
    c = dataclasses.replace(cfg, val_trials=())
    if folds.get("epochs"):
        c = dataclasses.replace(c, epochs=int(folds["epochs"]))
    job = start(c)
    log("final model: trained on every trial of the folds"
        + (f" for {c.epochs} epochs" if folds.get("epochs") else ""))
    job.advance(budget_s)
    res = job.result("time_budget")
    prov = res.meta["provenance"]
    prov["folds"] = folds
    prov.setdefault("training", {})["refit"] = True
    _apply_pooled(res.meta, ds, va, cv.val_pred)
    res.val_pred = cv.val_pred
    return res
