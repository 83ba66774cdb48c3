"""The recipe chosen on the user's own data: ``aslip train`` (``--stage auto``, the default).

Candidates (``RECIPES``), each trained on the dataset's training trials:

  frozen    the paper's recipe: the encoder pretrained on the robot-induced set
            (``--pretrain-dataset``), then the heads alone on this dataset
  partial   the same pretrained encoder with its temporal layers trainable at
            ``ENCODER_LR_SCALE`` times the heads' learning rate
  unfrozen  the same with every encoder weight trainable at that smaller rate
  scratch   every weight from a random start, once per seed (``--seeds``)
  svm       the handcrafted-feature SVM baseline

The three pretrained candidates share one pretraining and are skipped, with a message, when
no robot-induced set is given. The budget (``budget_s``) is the whole call's wall time. The
SVM runs first (unbudgeted; ``SvmConfig.max_train`` bounds it), then the pretraining, then
the CNN candidates in order: each CNN job gets the time left times its weight
(``JOB_WEIGHTS``) over the weights of the jobs still to run, so time one job leaves unused
goes to the later ones; a job stops at the end of the epoch that crosses its share and
keeps its best epoch.

Selection is on the validation trials (``data.dataset.split_trials`` by trial, never a
training trial; test trials are neither trained on nor looked at). The criterion
(``score``) is the sum, over direction MAE, magnitude RMSE and detection error
(1 - accuracy, floored at ``DETECTION_ERROR_FLOOR``), of the candidate's value divided by
the best candidate's value: 3.0 is best at everything, and a candidate 20 % worse on one
metric pays 0.2. Lowest wins; ties go to the candidate trained first. With
fewer than ``MIN_VAL_TRIALS`` validation trials, or none with slip, selection refuses and
says what is missing. The comparison is printed, written beside the checkpoint as
``<out>.selection.json`` and ``.md``, and stored in the chosen checkpoint's provenance
(``selection``) with the reason it won.
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

from aslip_ros.learn.data_io import WindowSet, open_dataset
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.models.aslip_cnn import ENCODER_PARTS
from aslip_ros.learn.models.svm import SvmConfig
from aslip_ros.learn.training.config import TrainConfig, TrainResult
from aslip_ros.learn.training.data import split_windows
from aslip_ros.learn.training.train import train_cnn, train_svm

RECIPES = ("frozen", "partial", "unfrozen", "scratch", "svm")
# ``partial`` by name only: at the default budget on two cores its time is better spent on
# the others (docs/model.md, "Choosing the recipe", measured).
DEFAULT_RECIPES = ("frozen", "unfrozen", "scratch", "svm")
NEEDS_PRETRAIN = ("frozen", "partial", "unfrozen")
ENCODER_LR_SCALE = 0.1
DEFAULT_SEEDS = (0,)
DEFAULT_BUDGET_S = 960.0      # with features and the SVM, inside 20 min on 2 cores
MIN_VAL_TRIALS = 2
DETECTION_ERROR_FLOOR = 0.01
JOB_WEIGHTS = {"pretrain": 4.0, "frozen": 1.0, "partial": 2.0, "unfrozen": 2.0,
               "scratch": 3.0, "svm": 0.0}
METRICS = ("detection_accuracy", "direction_mae_deg", "magnitude_rmse_mm")
CRITERION = ("sum over direction MAE, magnitude RMSE and detection error (1 - accuracy, "
             f"floored at {DETECTION_ERROR_FLOOR}) of the candidate's value over the best "
             "candidate's; lowest wins (3.0: best at all three)")
_TRAINABLE = {"frozen": (), "partial": ("conv1d", "pool"), "unfrozen": ENCODER_PARTS}

Trainer = Callable[[TrainConfig], TrainResult]


@dataclass(frozen=True)
class Candidate:
    """One recipe to train. ``trainer`` replaces the built-in one (tests, experiments)."""

    name: str
    recipe: str
    seed: int = 0
    trainer: Trainer | None = None

    @property
    def needs_pretrain(self) -> bool:
        return self.trainer is None and self.recipe in NEEDS_PRETRAIN


def plan(recipes: Iterable[str | Candidate] = DEFAULT_RECIPES,
         seeds: Sequence[int] = DEFAULT_SEEDS,
         have_pretrain: bool = False, log: Callable[[str], None] = print
         ) -> tuple[list[Candidate], list[dict[str, str]]]:
    """The candidates to run, and those skipped with the reason."""
    out: list[Candidate] = []
    skipped: list[dict[str, str]] = []
    for r in recipes:
        if isinstance(r, Candidate):
            out.append(r)
            continue
        if r not in RECIPES:
            raise ValueError(f"unknown recipe {r!r}; the recipes are {', '.join(RECIPES)}")
        if r in NEEDS_PRETRAIN and not have_pretrain:
            why = "needs a robot-induced set to pretrain on (--pretrain-dataset)"
            log(f"recipe {r}: skipped, {why}")
            skipped.append({"name": r, "reason": why})
        elif r == "scratch":
            out += [Candidate(f"scratch_s{s}", "scratch", int(s)) for s in seeds]
        else:
            out.append(Candidate(r, r))
    if not out:
        raise ValueError("no recipe left to train: " + "; ".join(
            f"{s['name']} {s['reason']}" for s in skipped))
    return out, skipped


def validation_split(ds: WindowSet, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation windows by trial; ValueError saying what is missing when the
    validation trials are too few (or have no slip) to choose on."""
    tr, va = split_windows(ds, cfg)
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
    return tr, va


# --- the criterion ------------------------------------------------------------------------

def _value(metrics: dict[str, Any], key: str) -> float | None:
    v = metrics.get(key)
    if v is None or not np.isfinite(v):
        return None
    return max(1.0 - v, DETECTION_ERROR_FLOOR) if key == "detection_accuracy" else float(v)


def score(val_metrics: dict[str, dict[str, Any]]) -> dict[str, float]:
    """The criterion (module docstring) per candidate name; lower is better. A metric no
    candidate has is left out; a candidate without one another has scores infinity."""
    out = {name: 0.0 for name in val_metrics}
    for key in METRICS:
        vals = {n: _value(m, key) for n, m in val_metrics.items()}
        have = [v for v in vals.values() if v is not None]
        if not have:
            continue
        best = max(min(have), 1e-9)
        for n, v in vals.items():
            out[n] += float("inf") if v is None else v / best
    return out


def select(val_metrics: dict[str, dict[str, Any]]) -> tuple[str, dict[str, float], str]:
    """The winning candidate (first of the lowest scores), all scores, and why it won."""
    if not val_metrics:
        raise ValueError("no candidate finished training; nothing to choose from")
    scores = score(val_metrics)
    winner = min(scores, key=lambda n: scores[n])   # min keeps the first of equal scores
    m = val_metrics[winner]
    others = sorted((s, n) for n, s in scores.items() if n != winner)
    runner = f"runner-up {others[0][1]} at {others[0][0]:.3f}" if others else "no rival"
    why = (f"{winner} has the lowest validation score {scores[winner]:.3f} ({runner}; "
           f"{CRITERION}) with detection "
           f"{100 * m.get('detection_accuracy', float('nan')):.1f} %, direction MAE "
           f"{m.get('direction_mae_deg', float('nan')):.1f} deg and magnitude RMSE "
           f"{m.get('magnitude_rmse_mm', float('nan')):.2f} mm on "
           f"{m.get('n_windows', 0)} validation windows")
    return winner, scores, why


# --- training the candidates --------------------------------------------------------------

def _share(left_s: float, jobs: Sequence[str | Candidate]) -> float:
    """This job's seconds: the time left times its weight over the remaining jobs'."""
    def w(j: str | Candidate) -> float:
        return JOB_WEIGHTS.get(j if isinstance(j, str) else j.recipe, 1.0)
    total = sum(w(j) for j in jobs)
    return max(1.0, left_s * w(jobs[0]) / total) if total > 0 else max(1.0, left_s)


def _job_config(cfg: TrainConfig, cand: Candidate, budget_s: float) -> TrainConfig:
    kw: dict[str, Any] = dict(seed=cand.seed, time_budget_s=budget_s)
    if cand.recipe in NEEDS_PRETRAIN:
        kw.update(stage="finetune", finetune_trainable=_TRAINABLE[cand.recipe],
                  encoder_lr_scale=1.0 if cand.recipe == "frozen" else ENCODER_LR_SCALE)
    else:
        kw["stage"] = "svm" if cand.recipe == "svm" else "scratch"
    return dataclasses.replace(cfg, **kw)


def _row(cand: Candidate, status: str, res: "TrainResult | None" = None,
         **extra: Any) -> dict[str, Any]:
    row: dict[str, Any] = {"name": cand.name, "recipe": cand.recipe, "seed": cand.seed,
                           "status": status, **extra}
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
    """The candidates' training, one job after another, within the whole call's budget."""

    def __init__(self, ds: WindowSet, cfg: TrainConfig, pretrain_ds: WindowSet | None,
                 budget_s: float, cnn_kw: dict[str, Any], svm_config: SvmConfig) -> None:
        self.ds, self.cfg, self.pretrain_ds = ds, cfg, pretrain_ds
        self.budget_s, self.cnn_kw, self.svm_config = budget_s, cnn_kw, svm_config
        self.log: Callable[[str], None] = cnn_kw["log"]
        self.t0 = time.perf_counter()
        self.pretrained: Any = None
        self.pre_info: dict[str, Any] = {}
        self.rows: list[dict[str, Any]] = []
        self.results: dict[str, TrainResult] = {}

    def run(self, jobs: list[str | Candidate]) -> None:
        for i, job in enumerate(jobs):
            share = _share(self.budget_s - (time.perf_counter() - self.t0), jobs[i:])
            if isinstance(job, str):
                self.pretrain(share)
            elif job.needs_pretrain and self.pretrained is None:
                self.rows.append(_row(job, "failed", error="pretraining failed: "
                                      + str(self.pre_info.get("error"))))
            else:
                self.candidate(job, share)

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
            self.pretrained = train_cnn(self.pretrain_ds, pcfg, **self.cnn_kw).checkpoint()
        except ValueError as exc:
            self.pre_info["error"] = str(exc)
            self.log(f"pretraining failed: {exc}")
            return
        self.pre_info.update(wall_s=round(time.perf_counter() - t, 1),
                             val=self.pretrained.meta["provenance"]["metrics"]["val"])

    def candidate(self, cand: Candidate, share: float) -> None:
        t = time.perf_counter()
        c = _job_config(self.cfg, cand, share)
        kw = self.cnn_kw
        self.log(f"recipe {cand.name}: training"
                 + (f" ({share:.0f} s budget)" if cand.recipe != "svm" else ""))
        try:
            if cand.trainer is not None:
                res = cand.trainer(c)
            elif cand.recipe == "svm":
                res = train_svm(self.ds, c, feature_config=kw["feature_config"],
                                svm_config=self.svm_config, channels=kw["channels"],
                                log=self.log)
            elif cand.recipe == "scratch":
                res = train_cnn(self.ds, c, **kw)
            else:
                res = train_cnn(self.ds, c, init=self.pretrained, cache_dir=kw["cache_dir"],
                                log=self.log)
        except ValueError as exc:
            self.log(f"recipe {cand.name}: failed: {exc}")
            self.rows.append(_row(cand, "failed", error=str(exc)))
            return
        self.results[cand.name] = res
        self.rows.append(_row(cand, "ok", res,
                              budget_s=None if cand.recipe == "svm" else round(share, 1),
                              wall_s=round(time.perf_counter() - t, 1)))


def train_selected(ds: WindowSet, cfg: TrainConfig, *, pretrain_ds: WindowSet | None = None,
                   recipes: Iterable[str | Candidate] = DEFAULT_RECIPES,
                   seeds: Sequence[int] = DEFAULT_SEEDS, budget_s: float = DEFAULT_BUDGET_S,
                   feature_config: FeatureConfig | None = None,
                   model_options: dict[str, Any] | None = None,
                   channels: Sequence[str] | None = None,
                   svm_config: SvmConfig = SvmConfig(),
                   cache_dir: str | os.PathLike | None = None,
                   log: Callable[[str], None] = print) -> TrainResult:
    """Train the candidates within ``budget_s`` and return the one best on the validation
    trials; its ``meta["provenance"]["selection"]`` holds the comparison and the reason.
    ``cfg`` carries the shared settings (split seed, filters, calibration, device...); its
    stage, seed and time budget are set per candidate. ValueError when the validation trials
    are too few or no candidate finished."""
    tr, va = validation_split(ds, cfg)
    cands, skipped = plan(recipes, seeds, pretrain_ds is not None, log)
    run = _Jobs(ds, cfg, pretrain_ds, budget_s,
                dict(feature_config=feature_config, model_options=model_options,
                     channels=channels, cache_dir=cache_dir, log=log), svm_config)
    # The SVM first: its fit is not budgeted, so the CNN shares are cut from what it leaves.
    svm = [c for c in cands if c.recipe == "svm" and c.trainer is None]
    rest = [c for c in cands if c not in svm]
    run.run(svm + (["pretrain"] if any(c.needs_pretrain for c in cands) else []) + rest)
    winner, scores, why = select({n: r.meta["provenance"]["metrics"]["val"]
                                  for n, r in run.results.items()})
    for row in run.rows:
        sc = scores.get(row["name"])
        row["score"] = sc if sc is not None and np.isfinite(sc) else None
    selection = {
        "winner": winner, "reason": why, "criterion": CRITERION, "candidates": run.rows,
        "skipped": skipped, "pretraining": run.pre_info or None, "budget_s": budget_s,
        "wall_s": round(time.perf_counter() - run.t0, 1), "dataset": str(ds.root),
        "split_seed": cfg.split_seed, "device": cfg.device,
        "train_trials": _trial_names(ds, tr), "val_trials": _trial_names(ds, va),
        "test_trials_untouched": _trial_names(
            ds, ds.dataset.select("test", seed=cfg.split_seed))}
    best = run.results[winner]
    best.meta["provenance"].update(selection=selection, recipe=winner)
    best.candidates = dict(run.results)
    return best


# --- the comparison and the command line ---------------------------------------------------

def _fmt(v: Any, scale: float = 1.0, nd: int = 1) -> str:
    return "-" if v is None else f"{v * scale:.{nd}f}"


def comparison_markdown(sel: dict[str, Any]) -> str:
    """The comparison as a markdown table with the winner and the reason."""
    lines = ["| candidate | status | det. % | dir. MAE deg | mag. RMSE mm | score | budget s "
             "| wall s | stop |", "|---|---|---|---|---|---|---|---|---|"]
    for r in sel["candidates"]:
        v = r.get("val", {})
        mark = "**" if r["name"] == sel["winner"] else ""
        lines.append(
            f"| {mark}{r['name']}{mark} | {r['status']} | "
            f"{_fmt(v.get('detection_accuracy'), 100)} | {_fmt(v.get('direction_mae_deg'))} | "
            f"{_fmt(v.get('magnitude_rmse_mm'), nd=2)} | {_fmt(r.get('score'), nd=3)} | "
            f"{_fmt(r.get('budget_s'), nd=0)} | {_fmt(r.get('wall_s'), nd=0)} | "
            f"{r.get('stop_reason') or r.get('error', '-')} |")
    for s in sel["skipped"]:
        lines.append(f"| {s['name']} | skipped | | | | | | | {s['reason']} |")
    return ("\n".join(lines) + f"\n\nChosen: **{sel['winner']}**. {sel['reason']}.\n\n"
            f"Validation trials ({len(sel['val_trials'])}): {', '.join(sel['val_trials'])}; "
            f"training trials: {len(sel['train_trials'])}; test trials, not looked at: "
            f"{len(sel['test_trials_untouched'])}. Whole call: {sel['wall_s']:.0f} s "
            f"(budget {sel['budget_s']:.0f} s).\n")


def write_comparison(out: str | os.PathLike, sel: dict[str, Any]) -> tuple[Path, Path]:
    """``<out>.selection.json`` and ``<out>.selection.md``, each written atomically."""
    js, md = Path(f"{out}.selection.json"), Path(f"{out}.selection.md")
    write_json(js, sel)
    write_text(md, comparison_markdown(sel))
    return js, md


def run_selected(args: argparse.Namespace, ds: WindowSet, cfg: TrainConfig,
                 fcfg: FeatureConfig, model_options: dict[str, Any],
                 svm_config: SvmConfig) -> int:
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
                         cache_dir=args.cache_dir)
    sel = res.meta["provenance"]["selection"]
    res.save(args.out)
    js, md = write_comparison(args.out, sel)
    if getattr(args, "keep_candidates", False):
        for name, r in (res.candidates or {}).items():
            r.save(Path(f"{args.out}.candidates") / f"{name}.pt")
    print(comparison_markdown(sel))
    print(f"wrote {args.out} ({sel['winner']}), {js} and {md}")
    return 0
