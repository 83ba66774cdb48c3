"""The recipe chosen on the user's own data: ``aslip train`` (``--stage auto``, the default).

Candidates (``RECIPES``), each trained on the dataset's training trials:

  frozen    the paper's recipe: the encoder pretrained on the robot-induced set
            (``--pretrain-dataset``), then the heads alone on this dataset
  partial   the same pretrained encoder with its temporal layers trainable at
            ``ENCODER_LR_SCALE`` times the heads' learning rate
  unfrozen  the same with every encoder weight trainable at that smaller rate
  scratch   every weight from a random start, once per seed (``--seeds``)
  svm       the handcrafted-feature SVM baseline
  svm_logmel  the same SVMs on the CNN's time-averaged log-mel (``SvmConfig.features``):
            the plain regressor of the speed a careful engineer tries first

and ``scratch_uncalibrated`` / ``svm_uncalibrated`` / ``svm_logmel_uncalibrated``, the
same without the per-grasp
calibration: whether the calibration helps on this recording is the data's to say (it cost
direction on a scene where most slip of a grasp goes one way), with the calibration as the
default hypothesis: an uncalibrated winner that the validation trials cannot tell from its
calibrated twin gives way to it (``prefer_calibrated``). The three pretrained
candidates share one pretraining and are skipped, with a message, when no robot-induced set
is given. ``frozen`` is not a default: it lost to every other candidate on each scene it was
measured on (docs/results.md); it stays available by name.

The budget (``budget_s``) is the whole call's wall time. The SVMs run first (unbudgeted;
``SvmConfig.max_train`` bounds them), then the pretraining (``PRETRAIN_FRACTION`` of the
time left), then the CNN candidates by successive halving (``successive_halving``): in each
of ``ceil(log2 n)`` rounds every surviving candidate trains for an equal slice, all are
scored on the validation trials with the criterion below (the SVMs' scores among them), and
the better half goes on; those rounds spend ``EARLY_FRACTION`` of the CNN time, and the last
survivor trains on with whatever is left. A stopped candidate keeps its best epoch and still
stands in the final choice. Training resumes where it paused (the CNN's job,
learn/models/aslip_cnn_fit.py), so the winner's run is one run, not a restart.

Selection is on the validation trials (``data.dataset.split_trials`` by trial, never a
training trial; test trials are neither trained on nor looked at); where the split has
fewer than ``folds.K_FOLD_BELOW`` of them, on folds by trial of the training and validation
trials, the final model then trained on all of them (``learn.training.folds``); by the
criterion of
``learn.training.selection`` (lowest wins; 3.0: best at all three metrics), which also says
what the choice is worth. With fewer than ``MIN_VAL_TRIALS`` validation trials, or none
with slip, selection refuses and says what is missing. The comparison is printed, written
beside the checkpoint as ``<out>.selection.json`` and ``.md``, and stored in the chosen
checkpoint's provenance (``selection``) with the reason it won.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from aslip_ros.util import write_json, write_text

from aslip_ros.learn.coverage import coverage_text, of_windows, warning
from aslip_ros.learn.data_io import WindowSet, open_dataset
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.models.aslip_cnn import ENCODER_PARTS
from aslip_ros.learn.models.aslip_cnn_fit import finetune, scratch, train_cnn
from aslip_ros.learn.models.svm import SvmConfig
from aslip_ros.learn.training.allocation import (EARLY_FRACTION, Job, OneShot,
                                                 successive_halving)
from aslip_ros.learn.training.config import TrainConfig, TrainResult, resolve_device
from aslip_ros.learn.training.data import split_windows
from aslip_ros.learn.training import distributed
from aslip_ros.learn.training.resume import RunStates
from aslip_ros.learn.training.folds import (K_FOLD_BELOW, REFIT_FRACTION, FoldJob,
                                            fold_trial_names, fold_windows, refit,
                                            trial_folds)
from aslip_ros.learn.models.per_output import PerOutputBackend
from aslip_ros.learn.training.selection import (CRITERION, METRICS, choose_outputs,
                                                chosen_parts, combination_cost, compose,
                                                score_difference, select, worth, worth_line)
from aslip_ros.learn.training.train import train_svm

RECIPES = ("frozen", "partial", "unfrozen", "scratch", "svm", "svm_logmel",
           "scratch_uncalibrated", "svm_uncalibrated", "svm_logmel_uncalibrated")
#: ``frozen`` and ``partial`` by name only: measured, their time is better spent on the
#: others (docs/model.md, "Choosing the recipe").
DEFAULT_RECIPES = ("unfrozen", "scratch", "scratch_uncalibrated", "svm", "svm_uncalibrated",
                   "svm_logmel", "svm_logmel_uncalibrated")
#: The SVM recipes and the features each reads (``SvmConfig.features``).
SVM_FEATURES = {"svm": "bands", "svm_logmel": "logmel"}
NEEDS_PRETRAIN = ("frozen", "partial", "unfrozen")
UNCALIBRATED = "_uncalibrated"
ENCODER_LR_SCALE = 0.1
DEFAULT_SEEDS = (0,)
DEFAULT_BUDGET_S = 960.0      # the whole call, features included (make recipe-budget)
MIN_VAL_TRIALS = 2
#: Share of the time left after the SVMs that the shared pretraining gets.
PRETRAIN_FRACTION = 0.3
_TRAINABLE = {"frozen": (), "partial": ("conv1d", "pool"), "unfrozen": ENCODER_PARTS}


@dataclass(frozen=True)
class Candidate:
    """One recipe to train. ``start`` replaces the built-in job (tests, experiments): it
    takes the candidate's TrainConfig and returns a ``Job``."""

    name: str
    recipe: str
    seed: int = 0
    start: Callable[[TrainConfig], Job] | None = None

    @property
    def base(self) -> str:
        """The recipe without its ``_uncalibrated`` suffix."""
        return self.recipe.removesuffix(UNCALIBRATED)

    @property
    def calibrated(self) -> bool:
        return not self.recipe.endswith(UNCALIBRATED)

    @property
    def needs_pretrain(self) -> bool:
        return self.start is None and self.base in NEEDS_PRETRAIN

    @property
    def is_svm(self) -> bool:
        return self.start is None and self.base in SVM_FEATURES


def plan(recipes: Iterable[str | Candidate] = DEFAULT_RECIPES,
         seeds: Sequence[int] = DEFAULT_SEEDS,
         have_pretrain: bool = False, log: Callable[[str], None] = print,
         calibration: str = "background"
         ) -> tuple[list[Candidate], list[dict[str, str]]]:
    """The candidates to run, and those skipped with the reason (``calibration``: the
    call's; with ``off`` the ``_uncalibrated`` variants are the plain ones)."""
    out: list[Candidate] = []
    skipped: list[dict[str, str]] = []
    for r in recipes:
        if isinstance(r, Candidate):
            out.append(r)
            continue
        if r not in RECIPES:
            raise ValueError(f"unknown recipe {r!r}; the recipes are {', '.join(RECIPES)}")
        base = r.removesuffix(UNCALIBRATED)
        if base in NEEDS_PRETRAIN and not have_pretrain:
            why = "needs a robot-induced set to pretrain on (--pretrain-dataset)"
        elif r != base and calibration == "off":
            why = f"the same as {base} with --calibration off"
        else:
            why = ""
        if why:
            log(f"recipe {r}: skipped, {why}")
            skipped.append({"name": r, "reason": why})
        elif base == "scratch":
            suffix = r[len(base):]
            out += [Candidate(f"scratch_s{s}{suffix}", r, int(s)) for s in seeds]
        else:
            out.append(Candidate(r, r))
    if not out:
        raise ValueError("no recipe left to train: " + "; ".join(
            f"{s['name']} {s['reason']}" for s in skipped))
    return out, skipped


def validation_split(ds: WindowSet, cfg: TrainConfig
                     ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, ...]] | None]:
    """Training and validation windows by trial, and the folds to choose on (None: the
    split's validation trials; with fewer than ``K_FOLD_BELOW`` of them, folds by trial of
    the training and validation trials, ``learn.training.folds``, whose pooled windows
    are then the validation windows and the training windows every one of them).
    ValueError saying what is missing when the validation trials are too few (or have no
    slip) to choose on."""
    tr, va = split_windows(ds, cfg)
    folds = trial_folds(ds, cfg)
    if folds is not None:
        va = fold_windows(ds, cfg, folds)[0]
        tr = va
    trials = np.asarray(ds.windows["trial"])
    n_val = np.unique(trials[va]).size
    if n_val < MIN_VAL_TRIALS or not ds.slip(va).any():
        from aslip_ros.data.dataset import split_summary
        what = (f"{n_val} validation trial(s)" if n_val < MIN_VAL_TRIALS
                else "validation trials without any slip window")
        raise ValueError(
            f"choosing a recipe needs at least {MIN_VAL_TRIALS} validation trials with slip, "
            f"held out by trial; {ds.root} has {what} ({split_summary(ds.trials, cfg.split_seed)}"
            f"): record and export more trials (about {MIN_VAL_TRIALS / 0.15:.0f} of one "
            "object and condition give that many), loosen the filters, or train one fixed "
            "recipe with --stage scratch|svm|pretrain|finetune")
    return tr, va, folds


# --- calibrated or not --------------------------------------------------------------------

def prefer_calibrated(ds: WindowSet, va: np.ndarray, results: dict[str, TrainResult],
                      winner: str) -> tuple[str, str | None]:
    """The calibrated twin of an uncalibrated winner that the validation trials cannot tell
    from it, and why; else the winner and None.

    The calibration is the default hypothesis and the data overrides it only with evidence:
    the validation grasps come from the same recording as the training grasps, so they do
    not show what the calibration is for, a grasp coupled unlike any trained on. On the
    held-out variants the calibrated model kept its direction where the coupling was wider
    (docs/results.md, "Transfer"), while the two were within noise on validation."""
    twin = winner.removesuffix(UNCALIBRATED)
    if twin == winner or twin not in results:
        return winner, None
    d = score_difference(ds, va, results, winner, twin)
    if d is None or d[2] < 0.0:
        return winner, None
    return twin, (f"{winner} scored {-d[0]:.3f} better than {twin}, but the two cannot be "
                  f"told apart on these validation trials (difference {d[0]:+.3f} "
                  f"[{d[1]:+.3f}, {d[2]:+.3f}]), so the calibrated {twin} is kept: it holds "
                  "its direction on grasps coupled unlike the trained ones")


# --- training the candidates --------------------------------------------------------------

def _job_config(cfg: TrainConfig, cand: Candidate, budget_s: float) -> TrainConfig:
    kw: dict[str, Any] = dict(seed=cand.seed, time_budget_s=budget_s)
    if not cand.calibrated:
        kw["calibration"] = "off"
    if cand.base in NEEDS_PRETRAIN:
        kw.update(stage="finetune", finetune_trainable=_TRAINABLE[cand.base],
                  encoder_lr_scale=1.0 if cand.base == "frozen" else ENCODER_LR_SCALE)
    else:
        kw["stage"] = "svm" if cand.base in SVM_FEATURES else "scratch"
    return dataclasses.replace(cfg, **kw)


def _row(cand: Candidate, status: str, res: "TrainResult | None" = None,
         **extra: Any) -> dict[str, Any]:
    row: dict[str, Any] = {"name": cand.name, "recipe": cand.recipe, "seed": cand.seed,
                           "calibrated": cand.calibrated, "status": status, **extra}
    if res is not None:
        prov = res.meta["provenance"]
        val = prov["metrics"]["val"]
        row["val"] = {k: val.get(k) for k in METRICS + ("n_windows", "n_slip")}
        row.update({k: prov.get("training", {}).get(k) for k in ("stop_reason", "best_epoch")})
    return row


def _trial_names(ds: WindowSet, idx: np.ndarray) -> list[str]:
    return [str(ds.trials[int(k)].get("id", k))
            for k in np.unique(np.asarray(ds.windows["trial"])[idx])]


class _Jobs:
    """The candidates' training within the whole call's budget: the SVMs, the shared
    pretraining, then successive halving over the CNN candidates."""

    def __init__(self, ds: WindowSet, cfg: TrainConfig, pretrain_ds: WindowSet | None,
                 budget_s: float, cnn_kw: dict[str, Any], svm_config: SvmConfig,
                 folds: list[tuple[int, ...]] | None = None,
                 states: RunStates | None = None) -> None:
        self.ds, self.cfg, self.pretrain_ds, self.folds = ds, cfg, pretrain_ds, folds
        self.states = states
        # The folds' windows, the same for every candidate (split once).
        self.fold_split = fold_windows(ds, cfg, folds) if folds else None
        self.budget_s, self.cnn_kw, self.svm_config = budget_s, cnn_kw, svm_config
        self.log: Callable[[str], None] = cnn_kw["log"]
        # A resumed call's budget counts the interrupted calls' time.
        self.t0 = distributed.now() - (states.spent_s() if states else 0.0)
        self.pretrained: Any = None
        self.pre_info: dict[str, Any] = {}
        self.rows: list[dict[str, Any]] = []
        self.results: dict[str, TrainResult] = {}
        self.rounds: list[dict[str, Any]] = []
        self.rest: list[dict[str, Any]] = []

    def left(self) -> float:
        return self.budget_s - (distributed.now() - self.t0)   # rank 0's, under torchrun

    def run(self, cands: list[Candidate]) -> None:
        for cand in (c for c in cands if c.is_svm):
            self.svm(cand)
        cnn = [c for c in cands if not c.is_svm]
        if any(c.needs_pretrain for c in cnn):
            self.pretrain(max(1.0, PRETRAIN_FRACTION * self.left()))
        jobs: dict[str, Job] = {}
        started: dict[str, Candidate] = {}
        for cand in cnn:
            if cand.needs_pretrain and self.pretrained is None:
                self.rows.append(_row(cand, "failed", error="pretraining failed: "
                                      + str(self.pre_info.get("error"))))
                continue
            try:
                jobs[cand.name] = self.start(cand)
            except ValueError as exc:
                self.log(f"recipe {cand.name}: failed: {exc}")
                self.rows.append(_row(cand, "failed", error=str(exc)))
                continue
            started[cand.name] = cand
        if not jobs:
            return
        others = {n: r.meta["provenance"]["metrics"]["val"] for n, r in self.results.items()}
        # On folds, the final models' training keeps its share (``refit``).
        share = self.left() * (1.0 - REFIT_FRACTION if self.folds else 1.0)
        winner, self.rounds, self.rest = successive_halving(
            jobs, max(1.0, share), others=others, log=self.log)
        resumed = {r["name"] for r in self.rest}
        stopped_in = {n: r["round"] for r in self.rounds for n in r["stopped"]
                      if n not in resumed}
        for name, job in jobs.items():
            res = job.result(f"halved in round {stopped_in[name]}" if name in stopped_in
                             else "time_budget")
            self.results[name] = res
            self.rows.append(_row(started[name], "ok", res, train_s=round(job.train_time_s, 1),
                                  survived=name == winner))

    def pretrain(self, share: float) -> None:
        """The pretraining the pretrained candidates share (on the whole robot-induced set's
        own training trials; the filters are for the user's dataset)."""
        assert self.pretrain_ds is not None
        t = time.perf_counter()
        self.log(f"pretraining on {self.pretrain_ds.root} ({share:.0f} s budget)")
        pcfg = dataclasses.replace(self.cfg, stage="pretrain", time_budget_s=share,
                                   induced=None, objects=None, conditions=None)
        self.pre_info = {"dataset": str(self.pretrain_ds.root), "budget_s": round(share, 1)}
        try:
            self.pretrained = train_cnn(self.pretrain_ds, pcfg, **self.cnn_kw,
                                        **self._state("pretrain")).checkpoint()
        except ValueError as exc:
            self.pre_info["error"] = str(exc)
            self.log(f"pretraining failed: {exc}")
            return
        self.pre_info.update(wall_s=round(time.perf_counter() - t, 1),
                             val=self.pretrained.meta["provenance"]["metrics"]["val"])

    def job(self, cand: Candidate, c: TrainConfig) -> Job:
        """The candidate's job for config ``c``, built (features, calibration, network)
        but not trained."""
        kw = self.cnn_kw
        if cand.start is not None:
            return cand.start(c)
        if cand.is_svm:
            return OneShot(lambda c: train_svm(
                self.ds, c, feature_config=kw["feature_config"],
                svm_config=dataclasses.replace(self.svm_config,
                                               features=SVM_FEATURES[cand.base]),
                channels=kw["channels"], log=self.log), c)
        state = self._state(cand.name + ("" if c.val_trials is None else "-final"
                                         if not c.val_trials else
                                         f"-fold{self.folds.index(tuple(c.val_trials))}"))
        if cand.needs_pretrain:
            return finetune(self.ds, c, init=self.pretrained, cache_dir=kw["cache_dir"],
                            log=self.log, **state)
        return scratch(self.ds, c, **kw, **state)

    def _state(self, name: str) -> dict[str, Any]:
        """The ``state`` keyword of the CNN job called ``name`` (none without states)."""
        return {} if self.states is None else {"state": self.states.job(name)}

    def start(self, cand: Candidate) -> Job:
        """The candidate's job (on the folds: one per fold, ``FoldJob``), not trained."""
        c = _job_config(self.cfg, cand, self.budget_s)
        self.log(f"recipe {cand.name}: starting"
                 + (f" ({len(self.folds)} folds by trial)" if self.folds else ""))
        if self.folds:
            return FoldJob(self.ds, c, self.folds, lambda fc: self.job(cand, fc),
                           windows=self.fold_split)
        return self.job(cand, c)

    def final(self, cands: dict[str, Candidate], names: Iterable[str], va: np.ndarray
              ) -> None:
        """On folds: ``names``' final models, each trained on every trial of the folds
        (``folds.refit``), in place of their cross-validated results; the CNNs share the
        time left."""
        if not self.folds:
            return
        names = [n for n in names if n in self.results]
        cnn = [n for n in names if not cands[n].is_svm]
        for n in names:                     # the SVMs first: their budget is a cap only
            if n not in cnn:
                self._refit(cands[n], max(1.0, self.left() / max(1, len(cnn))), va)
        for i, n in enumerate(cnn):         # the CNNs share the time left
            self._refit(cands[n], max(1.0, self.left() / (len(cnn) - i)), va)

    def _refit(self, cand: Candidate, budget_s: float, va: np.ndarray) -> None:
        c = _job_config(self.cfg, cand, budget_s)
        self.results[cand.name] = refit(self.ds, c, self.results[cand.name], va,
                                        lambda fc: self.job(cand, fc), budget_s, self.log)

    def svm(self, cand: Candidate) -> None:
        t = time.perf_counter()
        self.log(f"recipe {cand.name}: training")
        try:
            job = self.start(cand)
            job.advance(self.budget_s)
            res = job.result()
        except ValueError as exc:
            self.log(f"recipe {cand.name}: failed: {exc}")
            self.rows.append(_row(cand, "failed", error=str(exc)))
            return
        self.results[cand.name] = res
        self.rows.append(_row(cand, "ok", res, wall_s=round(time.perf_counter() - t, 1)))


def train_selected(ds: WindowSet, cfg: TrainConfig, *, pretrain_ds: WindowSet | None = None,
                   recipes: Iterable[str | Candidate] = DEFAULT_RECIPES,
                   seeds: Sequence[int] = DEFAULT_SEEDS, budget_s: float = DEFAULT_BUDGET_S,
                   feature_config: FeatureConfig | None = None,
                   model_options: dict[str, Any] | None = None,
                   channels: Sequence[str] | None = None,
                   svm_config: SvmConfig = SvmConfig(),
                   cache_dir: str | os.PathLike | None = None,
                   states: RunStates | None = None,
                   log: Callable[[str], None] = print) -> TrainResult:
    """Train the candidates within ``budget_s`` and return the one best on the validation
    trials; its ``meta["provenance"]["selection"]`` holds the comparison, the rounds of the
    allocator and the reason. ``cfg`` carries the shared settings (split seed, filters,
    calibration, device...); its stage, seed and time budget are set per candidate.
    ``states``: where the CNN jobs keep their state, to go on with an interrupted call
    (``learn.training.resume``; the budget counts the interrupted calls' time).
    ValueError when the validation trials are too few or no candidate finished."""
    tr, va, folds = validation_split(ds, cfg)
    # The slip directions the final model learns from (on folds: every trial of the folds).
    trained_on = np.union1d(tr, va) if folds else tr
    coverage = of_windows(ds, trained_on)
    if note := warning(coverage):
        log(note)
    cands, skipped = plan(recipes, seeds, pretrain_ds is not None, log, cfg.calibration)
    if folds:
        log(f"choosing on {len(folds)} folds by trial: the split has fewer than "
            f"{K_FOLD_BELOW} validation trials (learn/training/folds.py)")
    run = _Jobs(ds, cfg, pretrain_ds, budget_s,
                dict(feature_config=feature_config, model_options=model_options,
                     channels=channels, cache_dir=cache_dir, log=log), svm_config, folds,
                states)
    run.run(cands)
    winner, scores, why = select({n: r.meta["provenance"]["metrics"]["val"]
                                  for n, r in run.results.items()})
    for row in run.rows:
        sc = scores.get(row["name"])
        row["score"] = sc if sc is not None and np.isfinite(sc) else None
    winner, kept_calibrated = prefer_calibrated(ds, va, run.results, winner)
    if kept_calibrated:
        why = kept_calibrated
        log(f"choice: {kept_calibrated}")
    rivals = sorted((s, n) for n, s in scores.items() if n != winner and np.isfinite(s))
    value = worth(ds, va, run.results, winner, rivals[0][1] if rivals else None)
    selection = {
        "winner": winner, "reason": why, "criterion": CRITERION, "candidates": run.rows,
        "worth": value,
        "skipped": skipped, "pretraining": run.pre_info or None, "budget_s": budget_s,
        "allocation": {"method": "successive halving", "early_fraction": EARLY_FRACTION,
                       "pretrain_fraction": PRETRAIN_FRACTION, "rounds": run.rounds,
                       "rest": run.rest},
        "wall_s": round(time.perf_counter() - run.t0, 1), "dataset": str(ds.root),
        "split_seed": cfg.split_seed, "device": str(resolve_device(cfg.device)),
        "train_trials": _trial_names(ds, tr), "val_trials": _trial_names(ds, va),
        "direction_coverage": coverage,
        "test_trials_untouched": _trial_names(
            ds, ds.dataset.select("test", seed=cfg.split_seed))}
    # Rank 0's choice under torchrun: the latencies it weighs are measured per process.
    outputs = distributed.agree(choose_outputs(
        ds, va, run.results, winner, cost=combination_cost(ds, va, run.results, winner)))
    selection["outputs"] = outputs
    if folds:
        selection["folds"] = {"n": len(folds), "trials": fold_trial_names(ds, folds),
                              "below": K_FOLD_BELOW, "refit_fraction": REFIT_FRACTION}
        run.final({c.name: c for c in cands},
                  chosen_parts(outputs) | {winner}, va)
    best = compose(ds, va, run.results, winner, outputs) or run.results[winner]
    if best.meta["model_type"] == PerOutputBackend.model_type:
        roles = best.meta["model_config"]
        selection["latency_ms"] = best.meta["provenance"]["per_output"]["latency_ms"]
        log("choice: each output from its best candidate: " + ", ".join(
            f"{r} {n}" for r, n in roles.items() if n is not None))
    best.meta["provenance"].update(selection=selection, recipe=winner)
    best.candidates = dict(run.results)
    return best


# --- the comparison and the command line ---------------------------------------------------

def _fmt(v: Any, scale: float = 1.0, nd: int = 1) -> str:
    return "-" if v is None else f"{v * scale:.{nd}f}"


def _latency_text(ms: dict[str, float]) -> str:
    if not ms:
        return ""
    return (" One window's estimate, median on this machine: " + ", ".join(
        f"{name} {v:.2f} ms" for name, v in ms.items()) + ".")


def comparison_markdown(sel: dict[str, Any]) -> str:
    """The comparison as a markdown table with the allocator's rounds, the winner and the
    reason."""
    lines = ["| candidate | status | det. % | dir. MAE deg | mag. RMSE mm | score | trained s "
             "| wall s | stop |", "|---|---|---|---|---|---|---|---|---|"]
    for r in sel["candidates"]:
        v = r.get("val", {})
        mark = "**" if r["name"] == sel["winner"] else ""
        lines.append(
            f"| {mark}{r['name']}{mark} | {r['status']} | "
            f"{_fmt(v.get('detection_accuracy'), 100)} | {_fmt(v.get('direction_mae_deg'))} | "
            f"{_fmt(v.get('magnitude_rmse_mm'), nd=2)} | {_fmt(r.get('score'), nd=3)} | "
            f"{_fmt(r.get('train_s'), nd=0)} | {_fmt(r.get('wall_s'), nd=0)} | "
            f"{r.get('stop_reason') or r.get('error', '-')} |")
    for s in sel["skipped"]:
        lines.append(f"| {s['name']} | skipped | | | | | | | {s['reason']} |")
    rounds = (sel.get("allocation") or {}).get("rounds") or []
    if rounds:
        lines += ["", "Successive halving (validation score after each round, lower is "
                  "better):", ""]
        for r in rounds:
            lines.append(f"- round {r['round']} ({r['slice_s']:.0f} s each): "
                         + ", ".join(f"{n} {v:.3f}" for n, v in r["scores"].items())
                         + f"; went on: {', '.join(r['kept'])}")
        for r in (sel.get("allocation") or {}).get("rest") or []:
            lines.append(f"- then {r['name']} trained on for {r['seconds']:.0f} s")
    worth_text = worth_line(sel.get("worth") or {})
    outputs = sel.get("outputs") or {}
    if not outputs:
        per_output = ""
    elif all(row["from"] == sel["winner"] for row in outputs.values()):
        per_output = "Each output stays the winner's: " + "; ".join(
            f"{role}: {row['why']}" for role, row in outputs.items()) + "."
    else:
        per_output = "Each output from the candidate that gives it best: " + "; ".join(
            f"{role} from **{row['from']}** ({row['why']})" for role, row in outputs.items()
        ) + "." + _latency_text(sel.get("latency_ms") or {})
    folds = sel.get("folds")
    trials_text = (
        f"Chosen on {folds['n']} folds by trial (the split has fewer than {folds['below']} "
        "validation trials): every candidate trained once per fold and was scored on the "
        "pooled out-of-fold predictions of every fold's trials ("
        + "; ".join(", ".join(f) for f in folds["trials"]) + "); the final model trained "
        "on all of them for the folds' mean best epoch. " if folds else
        f"Validation trials ({len(sel['val_trials'])}): {', '.join(sel['val_trials'])}; ")
    return ("\n".join(lines) + f"\n\nChosen: **{sel['winner']}**. {sel['reason']}.\n\n"
            + "".join(t + "\n\n" for t in (worth_text, per_output) if t) + trials_text +
            f"training trials: {len(sel['train_trials'])}; test trials, not looked at: "
            f"{len(sel['test_trials_untouched'])}. Whole call: {sel['wall_s']:.0f} s "
            f"(budget {sel['budget_s']:.0f} s).\n"
            + (f"\n{coverage_text(sel['direction_coverage'])}\n"
               if sel.get("direction_coverage") else ""))


def write_comparison(out: str | os.PathLike, sel: dict[str, Any]) -> tuple[Path, Path]:
    """``<out>.selection.json`` and ``<out>.selection.md``, each written atomically."""
    js, md = Path(f"{out}.selection.json"), Path(f"{out}.selection.md")
    write_json(js, sel)
    write_text(md, comparison_markdown(sel))
    return js, md


def run_selected(args: argparse.Namespace, ds: WindowSet, cfg: TrainConfig,
                 fcfg: FeatureConfig, model_options: dict[str, Any],
                 svm_config: SvmConfig, states: RunStates | None = None) -> int:
    """``aslip train --stage auto``: train, choose, write the checkpoint and comparison."""
    try:
        seeds = [int(s) for s in (args.seeds or "").split(",") if s.strip()] or [0]
    except ValueError:
        raise ValueError(f"--seeds must be comma-separated integers, got {args.seeds!r}")
    recipes = [r for r in (args.recipes or "").split(",") if r] or list(DEFAULT_RECIPES)
    pre = open_dataset(args.pretrain_dataset) if args.pretrain_dataset else None
    chans = [c for c in (args.channels or "").split(",") if c] or None
    res = train_selected(ds, cfg, pretrain_ds=pre, recipes=recipes, seeds=seeds,
                         budget_s=args.time_budget or DEFAULT_BUDGET_S, feature_config=fcfg,
                         model_options=model_options, channels=chans, svm_config=svm_config,
                         cache_dir=args.cache_dir, states=states)
    sel = res.meta["provenance"]["selection"]
    if not distributed.is_main():
        return 0
    res.save(args.out)
    js, md = write_comparison(args.out, sel)
    if getattr(args, "keep_candidates", False):
        for name, r in (res.candidates or {}).items():
            r.save(Path(f"{args.out}.candidates") / f"{name}.pt")
    print(comparison_markdown(sel))
    print(f"wrote {args.out} ({sel['winner']}), {js} and {md}")
    return 0
