"""The transfer protocol: train on one scene, test on scenes no model was trained or tuned on.

A lab's recordings differ from the project's scene in ways nobody tuned for. The protocol
makes that measurable inside the project: every method is trained on the externally induced
trials of one scene (``--train-on``, default: the default scene) and tested on every scene in
full, as a user's recording is: all its trials are test trials. The training scene itself is
tested on a fresh draw of it (other seeds, ``HELD_OUT_SEED``), not on the few trials its
split keeps back, so every test set has as many trials as a held-out variant. A
``one_sided`` training draw gives each trial the preferred slip direction its seed draws,
which may leave a side of the circle without any (docs/results.md, "Why the folds' figure
misses the test there"); ``--headings even`` spreads its trials' directions evenly instead,
as a lab that follows the quickstart records. Test draws always keep the seeds' directions.

Scenes (``aslip simulate --variant``, ``scene/variants.py``, docs/scene.md): ``default``
(per-grasp coupling of +-3 dB); ``coupling`` (+-6 dB, hand-noise path +-2 dB); ``one_sided``
(80 % of the slip of a grasp within +-30 deg of one direction); ``contact`` (the object
seated off the pad centre, 5 mm); ``confounders`` (half the touches without slip, the hand
and the arm louder); ``mocap`` (a lab's motion capture: 100 Hz, 0.3 mm, 2 % dropped, 15 ms);
``rate`` (a 44.1 kHz sound card, resampled to the models' 48 kHz as a driver would: every
checkpoint refuses a stream at another rate); ``speed`` (the slip noise's loudness against
slip speed with another exponent per object, 0.45 to 1.05 instead of 0.75); ``path`` (the
hand's and the arm's noise reach each microphone by its own path, +-6 dB: a background that
is not common mode, where the per-grasp calibration's self-check is meant to warn).

Methods, each trained by ``aslip train`` itself (``train_arguments``): ``aslip`` (the
command's defaults: ``--stage auto`` chooses a recipe on validation trials, per-grasp
calibration ``background``) and ``paper_svm`` (``--stage svm``); with ``--methods`` also
``aslip_scratch`` (``--stage scratch``) and each without calibration (``*_uncalibrated``);
the plain baselines of ``learn.baselines`` (a plain log-mel CNN and an RBF SVM on
time-averaged log-mel).

Every metric carries a 95 % interval from a bootstrap over test trials (and the direction
error is also given by true slip direction, ``per_direction``, and for a one_sided model on
one_sided trials, whether it follows each trial's slip or the sound of its training twin,
``follows_the_trial``); the table marks the
best method of each column and every method whose interval overlaps the best one's (those
cannot be told apart on these trials). ``transfer_targets`` compares ``aslip`` with the best
baseline of each cell on the same trial resamples.

    python -m benchmarks.transfer --out results/transfer       (make transfer)
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from aslip_ros.util import atomic_path, write_json, write_text

from .common import scene_cache

SCENES = ("default", "coupling", "one_sided", "contact", "confounders", "mocap", "rate",
          "speed", "path")
METHODS = ("aslip", "aslip_uncalibrated", "aslip_scratch", "paper_svm",
           "paper_svm_uncalibrated", "plain_cnn", "plain_svm")
#: The methods of ``make transfer``: the package's default, its scratch recipe alone, the
#: paper's SVM, the plain ones.
DEFAULT_METHODS = ("aslip", "aslip_scratch", "paper_svm", "plain_cnn", "plain_svm")
#: A method's revision, in the names of its cached model and predictions: a method whose
#: estimator changed is trained and predicted again, never read from the old cache.
#: 2: the SVMs regress the speed and the direction's cosine and sine, not vx and vz;
#: ``aslip`` takes each output from the candidate that gives it best (per_output).
#: 3: ``aslip``'s per-output choice also weighs blends (the mean of two candidates).
#: 4: a final model chosen on folds averages its last half of epochs (``average_last``).
REVISION = {"plain_svm": 2, "paper_svm": 2, "paper_svm_uncalibrated": 2, "aslip": 4,
            "aslip_uncalibrated": 4}
OBJECTS = ("chips_can", "cracker_box", "glass_cleaner", "mustard_container", "pla_rod")
CONDITIONS = ("robot_stationary", "robot_moving", "robot_off")
#: Seed offset per scene, so no held-out scene replays the training scene's motions.
SCENE_SEED = {"default": 0, "coupling": 10_000, "one_sided": 20_000, "mocap": 30_000,
              "contact": 40_000, "confounders": 50_000, "rate": 60_000, "speed": 70_000,
              "path": 80_000}
#: The scene's audio rate, which every model is trained at [Hz].
TRAIN_RATE_HZ = 48000.0
#: Seed offset of the fresh draw of the training scene that it is tested on.
HELD_OUT_SEED = 500_000
KEYS = (("detection_accuracy", "detection %", 100.0), ("direction_mae_deg", "direction deg", 1.0),
        ("magnitude_rmse_mm", "magnitude mm", 1.0))


@dataclass
class TransferConfig:
    out: Path
    data: Path = Path("data/transfer")   # bags, datasets and models (git-ignored)
    train_on: tuple[str, ...] = ("default",)
    test_on: tuple[str, ...] = SCENES
    methods: tuple[str, ...] = DEFAULT_METHODS
    trials: int = 2                 # per object and condition (30 trials per scene)
    duration_s: float = 10.0
    objects: tuple[str, ...] = OBJECTS
    seed: int = 0
    time_budget_s: float | None = None   # aslip train's --time-budget (None: its default)
    epochs: int = 25                # the plain CNN's
    threads: int = 1
    n_boot: int = 500
    progress: bool = True
    merge: bool = False             # keep other methods' cached predictions in the tables
    #: The one_sided training draw's preferred slip directions: each trial's from its seed
    #: ("random"), or spread evenly round the circle over its trials ("even", as a lab that
    #: follows the quickstart records). The test draws are always "random".
    headings: str = "random"
    extra: dict[str, Any] = field(default_factory=dict)


# --- data ---------------------------------------------------------------------------------

def scene_root(cfg: TransferConfig) -> Path:
    """Where this scene version's bags, datasets, models and predictions are cached: a scene
    whose defaults changed (``SCENE_VERSION``) is simulated again, never mixed with the old."""
    return scene_cache(cfg.data)


def draw_name(cfg: TransferConfig, scene: str, held_out: bool = False) -> str:
    """The name of a draw of ``scene`` in the caches and tables: ``-held-out`` for its fresh
    draw, ``-even-headings`` for a one_sided training draw with ``headings="even"``."""
    if held_out:
        return scene + "-held-out"
    return scene + ("-even-headings" if scene == "one_sided" and cfg.headings == "even"
                    else "")


def scene_dataset(cfg: TransferConfig, scene: str, log: Callable[[str], None],
                  held_out: bool = False) -> Path:
    """The externally induced dataset of ``scene`` (with ``held_out``: its fresh draw, other
    seeds): simulated and exported once, then reused."""
    from aslip_ros.data.export import export
    from aslip_ros.scene.simulate import simulate
    name = draw_name(cfg, scene, held_out)
    headings = "even" if name.endswith("-even-headings") else "random"
    bags = scene_root(cfg) / "bags" / name
    ds = scene_root(cfg) / "datasets" / name
    if (ds / "manifest.json").is_file():
        return ds
    log(f"{name}: simulating {cfg.trials * len(cfg.objects) * len(CONDITIONS)} trials")
    simulate(bags, "external", objects=cfg.objects, conditions=CONDITIONS, trials=cfg.trials,
             duration_s=cfg.duration_s,
             seed=cfg.seed + SCENE_SEED[scene] + (HELD_OUT_SEED if held_out else 0),
             variant=None if scene == "default" else scene, progress=cfg.progress,
             headings=headings)
    log(f"{name}: exporting")
    recorded = ds.with_name(name + "-recorded")
    if not (recorded / "manifest.json").is_file():
        export([bags], recorded)
    from aslip_ros.learn.data_io import open_dataset
    if open_dataset(recorded).sample_rate == TRAIN_RATE_HZ:
        recorded.rename(ds)
    else:
        resample_dataset(recorded, ds, TRAIN_RATE_HZ)
    return ds


def resample_dataset(src: Path, dst: Path, rate: float) -> None:
    """A copy of dataset ``src`` at ``rate``: the audio resampled with a polyphase filter
    (``scipy.signal.resample_poly``), window starts and track positions in the new samples."""
    import json
    import shutil
    from fractions import Fraction

    from scipy.signal import resample_poly

    man = json.loads((src / "manifest.json").read_text())
    ratio = Fraction(rate / man["sample_rate"]).limit_denominator(10_000)
    with atomic_path(dst) as tmp:
        shutil.copytree(src, tmp)
        for t in man["trials"]:
            a = np.load(src / t["file"])
            y = resample_poly(a, ratio.numerator, ratio.denominator, axis=0)
            np.save(tmp / t["file"], y.astype(np.float32))
            t["n_samples"] = int(y.shape[0])
            if t.get("first_sample_index") is not None:
                t["first_sample_index"] = int(round(t["first_sample_index"] * ratio))
        for track in (tmp / "tracks").glob("*.npy"):
            tr = np.load(track)
            tr[:, 0] = tr[:, 0] * float(ratio)
            np.save(track, tr)
        w = np.load(src / "windows.npy")
        w["start"] = np.round(w["start"] * float(ratio)).astype(np.int64)
        np.save(tmp / "windows.npy", w)
        man.update(sample_rate=float(rate), resampled_from=man["sample_rate"],
                   n_window_samples=int(round(man["window_s"] * rate)),
                   hop_samples=int(round(man["hop_s"] * rate)))
        (tmp / "manifest.json").write_text(json.dumps(man, indent=1))


# --- methods ------------------------------------------------------------------------------

def train_arguments(method: str) -> list[str]:
    """The ``aslip train`` options of a checkpoint method on top of the command's defaults
    (``aslip``: none, what a user gets; ``--stage auto`` chooses the recipe, with the
    per-grasp calibration ``background``)."""
    stage = {"aslip": [], "aslip_scratch": ["--stage", "scratch"],
             "paper_svm": ["--stage", "svm"]}[method.removesuffix("_uncalibrated")]
    return stage + (["--calibration", "off"] if method.endswith("_uncalibrated") else [])


def aslip_recipe() -> str:
    """What the ``aslip`` method runs: ``aslip train`` with its defaults."""
    from aslip_ros.learn.training import cli as train_cli
    p = argparse.ArgumentParser()
    train_cli.add_arguments(p)
    d = p.parse_args(["--dataset", "DATASET", "--out", "X"])
    return (f"`aslip train --dataset DATASET --out X` (defaults: --stage {d.stage}, --calibration "
            f"{d.calibration}, --seeds {d.seeds}, no --pretrain-dataset)")


def cached_name(method: str) -> str:
    """``method``'s name in the cache: with its revision (``REVISION``) where it has one."""
    rev = REVISION.get(method)
    return method if rev is None else f"{method}-r{rev}"


def train_method(cfg: TransferConfig, method: str, train_ds: Path, cache: Path,
                 log: Callable[[str], None]):
    """A trained model of ``method`` on ``train_ds``'s training split (cached on disk)."""
    if method.startswith("plain_"):
        import pickle

        from aslip_ros.learn import baselines
        from aslip_ros.learn.data_io import open_dataset, select_windows
        from aslip_ros.learn.training.data import feature_cache
        saved = cache / f"{cached_name(method)}-{cfg.epochs}ep.pkl"
        if saved.is_file():
            # Written by this protocol only, beside the checkpoints it trains.
            return pickle.loads(saved.read_bytes())
        ds = open_dataset(train_ds)
        feats = feature_cache(ds, baselines.baseline_features(ds.sample_rate), ds.channel_names)
        tr = select_windows(ds, "train", seed=cfg.seed)
        x, v, s = np.asarray(feats[tr], dtype=np.float32), ds.velocity(tr), ds.slip(tr)
        if method == "plain_cnn":
            model = baselines.fit_plain_cnn(x, v, s, epochs=cfg.epochs, seed=cfg.seed)
        else:
            model = baselines.fit_plain_svm(x, v, s, seed=cfg.seed)
        cache.mkdir(parents=True, exist_ok=True)
        with atomic_path(saved) as tmp:
            tmp.write_bytes(pickle.dumps(model))
        return model
    ckpt = cache / f"{cached_name(method)}.pt"
    if not ckpt.is_file():
        from aslip_ros.learn.training import cli as train_cli
        cache.mkdir(parents=True, exist_ok=True)
        argv = ["--dataset", str(train_ds), "--out", str(ckpt), *train_arguments(method),
                "--threads", str(cfg.threads), "--seed", str(cfg.seed),
                "--split-seed", str(cfg.seed)]
        if cfg.time_budget_s is not None:
            argv += ["--time-budget", f"{cfg.time_budget_s:g}"]
        if not cfg.progress:
            argv.append("--no-progress")
        p = argparse.ArgumentParser()
        train_cli.add_arguments(p)
        log("aslip train " + " ".join(argv))
        if train_cli.run(p.parse_args(argv)) != 0 or not ckpt.is_file():
            raise RuntimeError(f"aslip train failed for {method} on {train_ds}")
    return ckpt


def predict(cfg: TransferConfig, method: str, model, test_ds: Path, split: str
            ) -> dict[str, np.ndarray]:
    """Per-window predictions and labels of ``model`` on ``split`` of ``test_ds``."""
    from aslip_ros.learn.data_io import open_dataset, select_windows
    if not method.startswith("plain_"):
        from aslip_ros.learn.evaluate import predict_split
        return predict_split(model, test_ds, split, split_seed=cfg.seed)
    from aslip_ros.learn import baselines
    from aslip_ros.learn.training.data import feature_cache
    ds = open_dataset(test_ds)
    # Every scene records at the same rate, so this is the training features' configuration.
    idx = select_windows(ds, split, seed=cfg.seed)
    feats = feature_cache(ds, baselines.baseline_features(ds.sample_rate), ds.channel_names)
    prob, vel = model.predict(np.asarray(feats[idx], dtype=np.float32))
    return {"prob": prob, "raw_velocity": vel, "true_velocity": ds.velocity(idx),
            "slip": ds.slip(idx), "trial": np.asarray(ds.windows["trial"][idx]),
            "window_s": ds.window_s}


def per_direction(p: dict[str, np.ndarray]) -> dict[str, float | None]:
    """Direction MAE [deg] of ``p``'s slip windows by their true slip direction (the sectors
    of ``learn.coverage``, grouped as ``aslip evaluate`` groups them; None where a sector
    holds no slip window): where a method fails, e.g. in directions its training trials
    hardly slipped in."""
    from aslip_ros.learn.coverage import SECTORS, direction_groups, sector_name
    from aslip_ros.learn.metrics import grouped_metrics
    by = grouped_metrics(direction_groups(p["true_velocity"], p["slip"]), p["prob"],
                         p["raw_velocity"], p["true_velocity"], p["slip"], float(p["window_s"]))
    return {name: by[name]["direction_mae_deg"] if name in by else None
            for name in map(sector_name, range(SECTORS))}


#: A test trial's training twin (the training trial of its object and condition) slipped
#: "elsewhere" when their preferred directions lie more than this apart [deg].
TWIN_APART_DEG = 60.0


def preferred_directions(ds) -> list[tuple[tuple[str, str], float]]:
    """Each trial of the open dataset ``ds``, in trial order: its (object, condition) and its
    preferred slip direction [rad], the direction of the sum of its slip velocities."""
    idx = np.arange(len(ds))
    v, slip, trial = ds.velocity(idx), ds.slip(idx), np.asarray(ds.windows["trial"])
    vc = v[:, 0] + 1j * v[:, 1]
    return [((str(t.get("object")), str(t.get("condition"))),
             float(np.angle(np.sum(vc[(trial == i) & slip]))))
            for i, t in enumerate(ds.trials)]


def follows_the_trial(p: dict[str, np.ndarray], test: list[tuple[tuple[str, str], float]],
                      train: list[tuple[tuple[str, str], float]]) -> dict[str, Any]:
    """Whether a method's estimates follow each test trial's slip or the sound of its training
    twins, the training trials of the same object and condition (#36: a choice must not pick
    a model that learns each trial's direction instead of the slip's). ``test`` and
    ``train`` are ``preferred_directions`` of the two datasets; ``p["trial"]`` indexes
    ``test``. Over the test trials whose every twin slipped more than ``TWIN_APART_DEG``
    away: the mean angle [deg] between the trial's mean estimated direction and its own
    preferred direction (``to_own_deg``), and its nearest twin's (``to_twin_deg``)."""
    def apart(a: float, b: float) -> float:
        return float(abs(np.degrees(np.angle(np.exp(1j * (a - b))))))
    to_own, to_twin = [], []
    for i, (key, own) in enumerate(test):
        twins = [d for k, d in train if k == key]
        if not twins or min(apart(own, d) for d in twins) <= TWIN_APART_DEG:
            continue
        m = (p["trial"] == i) & p["slip"]
        if not m.any():
            continue
        est = float(np.angle(np.sum(p["raw_velocity"][m, 0] + 1j * p["raw_velocity"][m, 1])))
        to_own.append(apart(est, own))
        to_twin.append(min(apart(est, d) for d in twins))
    return {"n_trials": len(to_own),
            "to_own_deg": float(np.mean(to_own)) if to_own else None,
            "to_twin_deg": float(np.mean(to_twin)) if to_twin else None}


def _trial_identity(cfg: TransferConfig, train: str, test: str,
                    preds: dict[str, dict[str, np.ndarray]]) -> dict[str, Any] | None:
    """``follows_the_trial`` of every method for a one_sided model tested on the one_sided
    fresh draw (the only cell whose trials have a preferred direction); None elsewhere or
    where the datasets are not in the cache."""
    if not (train == test == "one_sided"):
        return None
    root = scene_root(cfg) / "datasets"
    train_ds, test_ds = root / draw_name(cfg, train), root / draw_name(cfg, test, True)
    if not ((train_ds / "manifest.json").is_file() and (test_ds / "manifest.json").is_file()):
        return None
    from aslip_ros.learn.data_io import open_dataset
    own, twins = (preferred_directions(open_dataset(d)) for d in (test_ds, train_ds))
    return {m: follows_the_trial(p, own, twins) for m, p in preds.items()}


def score(cfg: TransferConfig, p: dict[str, np.ndarray]) -> dict[str, Any]:
    from aslip_ros.learn.stats import bootstrap_metrics
    res = bootstrap_metrics(p["trial"], p["prob"], p["raw_velocity"], p["true_velocity"],
                            p["slip"], float(p["window_s"]), n_boot=cfg.n_boot, seed=cfg.seed)
    res["n_trials"] = int(np.unique(p["trial"]).size)
    return res


# --- the protocol -------------------------------------------------------------------------

def _predictions_path(cfg: TransferConfig, train: str, test: str, method: str) -> Path:
    return (scene_root(cfg) / "predictions" / f"{draw_name(cfg, train)}--{test}"
            / f"{cached_name(method)}.npz")


def _save_predictions(path: Path, p: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **{k: np.asarray(p[k]) for k in PRED_KEYS})
    tmp.replace(path)


def _load_predictions(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: z[k] for k in PRED_KEYS}


PRED_KEYS = ("prob", "raw_velocity", "true_velocity", "slip", "trial", "window_s")


def test_sets(cfg: TransferConfig, train: str, log: Callable[[str], None]
              ) -> dict[str, Path]:
    """Each test scene's dataset for a model trained on ``train``: every trial of a held-out
    scene, or the fresh draw of the training scene itself."""
    return {test: scene_dataset(cfg, test, log, held_out=test == train)
            for test in cfg.test_on}


def run_protocol(cfg: TransferConfig, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Train on each ``train_on`` scene, test on every ``test_on`` scene; the result table."""
    for train in cfg.train_on:
        train_ds = scene_dataset(cfg, train, log)
        tests = test_sets(cfg, train, log)
        for method in cfg.methods:
            t0 = time.perf_counter()
            model = train_method(cfg, method, train_ds,
                                 scene_root(cfg) / "models" / draw_name(cfg, train), log)
            log(f"trained {method} on {train} ({time.perf_counter() - t0:.0f} s)")
            for test, ds in tests.items():
                p = predict(cfg, method, model, ds, "all")
                _save_predictions(_predictions_path(cfg, train, test, method), p)
                log(f"  {method}: {train} -> {test}: {metrics_cell(score(cfg, p))}")
    return write_tables(cfg)


def write_tables(cfg: TransferConfig) -> dict[str, Any]:
    """The tables from the cached predictions of ``cfg.methods`` (with ``merge``: of every
    method that has them), written to ``cfg.out``."""
    from benchmarks.transfer_targets import PLAIN, targets
    cells: dict[str, dict[str, dict[str, Any]]] = {}
    preds: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    fresh: list[str] = []
    pairs: dict[str, tuple[str, str]] = {}
    for train in cfg.train_on:
        for test in cfg.test_on:
            cell = f"{draw_name(cfg, train)} -> {test}"
            pairs[cell] = (train, test)
            if train == test:
                fresh.append(cell)
            for method in (m for m in METHODS if cfg.merge or m in cfg.methods):
                path = _predictions_path(cfg, train, test, method)
                if path.is_file():
                    preds.setdefault(cell, {})[method] = p = _load_predictions(path)
                    cells.setdefault(cell, {})[method] = score(cfg, p)
    result = {"format": "aslip-transfer", "version": 2,
              "config": {k: (str(v) if isinstance(v, Path) else v)
                         for k, v in asdict(cfg).items()},
              "aslip_method": aslip_recipe(), "cells": cells, "fresh_draw_cells": fresh,
              "per_direction": {c: {m: per_direction(p) for m, p in ps.items()}
                                for c, ps in preds.items()},
              "trial_identity": {c: t for c, ps in preds.items()
                                 if (t := _trial_identity(cfg, *pairs[c], ps)) is not None},
              "targets": {c: targets(p, cfg.n_boot, cfg.seed) for c, p in preds.items()},
              "targets_plain": {c: targets(p, cfg.n_boot, cfg.seed, PLAIN)
                                for c, p in preds.items()}}
    write_json(cfg.out / "transfer.json", result)
    write_text(cfg.out / "transfer.md", table_markdown(result))
    return result


def metrics_cell(res: dict[str, Any]) -> str:
    """Detection / direction / magnitude with their intervals, in the tables' units."""
    return " / ".join(format_ci(res, key, scale) for key, _, scale in KEYS)


def format_ci(res: dict[str, Any], key: str, scale: float) -> str:
    """``value [low, high]`` of ``key`` (and its ``_ci``) times ``scale``; n/a if absent."""
    v = res.get(key)
    if v is None:
        return "n/a"
    lo, hi = res.get(key + "_ci", (np.nan, np.nan))
    return f"{v * scale:.1f} [{lo * scale:.1f}, {hi * scale:.1f}]"


def best_and_ties(rows: dict[str, dict[str, Any]], key: str) -> tuple[str | None, set[str]]:
    """The best method for ``key`` (highest detection, lowest errors) and every method whose
    interval overlaps the best one's interval (cannot be told apart on these trials)."""
    have = {m: r for m, r in rows.items() if r.get(key) is not None}
    if not have:
        return None, set()
    higher = key == "detection_accuracy"
    best = (max if higher else min)(have, key=lambda m: have[m][key])
    blo, bhi = have[best].get(key + "_ci", (have[best][key],) * 2)
    ties = {m for m, r in have.items() if m != best and
            r.get(key + "_ci", (r[key],) * 2)[0] <= bhi and
            r.get(key + "_ci", (r[key],) * 2)[1] >= blo}
    return best, ties


def table_markdown(result: dict[str, Any]) -> str:
    lines = ["# Transfer: trained on one scene, tested on scenes no model saw", "",
             "Cells: value [95 % trial-bootstrap interval]. **Bold**: the best method of the "
             "column; *italic*: cannot be told apart from it (overlapping intervals).", ""]
    from benchmarks.transfer_targets import targets_markdown
    lines += [f"`aslip`: {result.get('aslip_method', '')}. The training scene is tested on a "
              "fresh draw of it (other seeds), every held-out scene on all its trials.", ""]
    for cell, rows in result["cells"].items():
        n = max((r.get("n_trials", 0) for r in rows.values()), default=0)
        train, test = cell.split(" -> ")
        fresh = cell in result["fresh_draw_cells"] if "fresh_draw_cells" in result \
            else train == test
        what = "fresh draw of the training scene, " if fresh else ""
        lines += [f"## {cell} ({what}{n} test trials)", "",
                  "| method | " + " | ".join(h for _, h, _ in KEYS) + " |",
                  "|---|" + "---|" * len(KEYS)]
        marks = {key: best_and_ties(rows, key) for key, _, _ in KEYS}
        for m, r in rows.items():
            out = []
            for key, _, scale in KEYS:
                s = format_ci(r, key, scale)
                best, ties = marks[key]
                out.append(f"**{s}**" if m == best else f"*{s}*" if m in ties else s)
            lines.append(f"| {m} | " + " | ".join(out) + " |")
        lines.append("")
        by_dir = result.get("per_direction", {}).get(cell)
        if by_dir:
            sectors = list(next(iter(by_dir.values())))
            lines += ["Direction MAE (deg) by true slip direction:", "",
                      "| method | " + " | ".join(sectors) + " |",
                      "|---|" + "---|" * len(sectors)]
            for m, d in by_dir.items():
                row = ("-" if v is None else f"{v:.0f}" for v in d.values())
                lines.append(f"| {m} | " + " | ".join(row) + " |")
            lines.append("")
        ident = result.get("trial_identity", {}).get(cell)
        if ident:
            n = max(r["n_trials"] for r in ident.values())
            lines += [f"Does the estimate follow the slip or the trial's sound? On the {n} test "
                      "trials whose training twin (the training trial of the same object and "
                      f"condition) slipped over {TWIN_APART_DEG:.0f} deg away, the angle from "
                      "each trial's mean estimate to its own preferred direction / to its "
                      "twin's: " + "; ".join(
                          f"{m} {r['to_own_deg']:.0f} / {r['to_twin_deg']:.0f} deg"
                          for m, r in ident.items() if r["to_own_deg"] is not None) + ".", ""]
    lines += targets_markdown(result.get("targets", {}))
    lines += targets_markdown(result.get("targets_plain", {}),
                              "the better plain baseline (plain CNN, plain SVM)")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="results/transfer", help="results (json, markdown)")
    p.add_argument("--data", default="data/transfer", help="bags, datasets and models")
    p.add_argument("--train-on", default="default", help="comma-separated scenes to train on")
    p.add_argument("--test-on", default=",".join(SCENES), help="comma-separated scenes")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help=f"comma-separated methods out of {','.join(METHODS)}")
    p.add_argument("--merge", action="store_true",
                   help="tables also show the cached predictions of the methods not run")
    p.add_argument("--tables-only", action="store_true",
                   help="train and predict nothing: the tables from cached predictions")
    p.add_argument("--trials", type=int, default=2, help="trials per object and condition")
    p.add_argument("--duration", type=float, default=10.0, help="seconds per trial")
    p.add_argument("--time-budget", type=float, default=None,
                   help="aslip train's --time-budget [s] (default: aslip train's own)")
    p.add_argument("--epochs", type=int, default=25, help="plain CNN epochs")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--headings", choices=("random", "even"), default="random",
                   help="one_sided training draw: each trial's preferred slip direction from "
                        "its seed, or the trials' spread evenly round the circle (the test "
                        "draws: always from the seeds)")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: 2 objects, 4 s trials, 1 trial each, short training")
    p.add_argument("--no-progress", action="store_true")


def config_from_args(args: argparse.Namespace) -> TransferConfig:
    def names(s: str, allowed: tuple[str, ...], what: str) -> tuple[str, ...]:
        out = tuple(x for x in s.split(",") if x)
        bad = [x for x in out if x not in allowed]
        if bad or not out:
            raise SystemExit(f"transfer: unknown {what} {bad or s!r}; choose from {allowed}")
        return out
    cfg = TransferConfig(out=Path(args.out), data=Path(args.data),
                         train_on=names(args.train_on, SCENES, "scene"),
                         test_on=names(args.test_on, SCENES, "scene"),
                         methods=names(args.methods, METHODS, "method"), trials=args.trials,
                         duration_s=args.duration, time_budget_s=args.time_budget,
                         epochs=args.epochs, threads=args.threads,
                         progress=not args.no_progress, merge=args.merge,
                         headings=args.headings)
    if cfg.headings != "random" and "one_sided" not in cfg.train_on:
        raise SystemExit("transfer: --headings applies to a one_sided training draw: "
                         "add one_sided to --train-on")
    if args.quick:
        cfg.objects, cfg.trials, cfg.duration_s = OBJECTS[:2], 1, 4.0
        cfg.time_budget_s, cfg.epochs, cfg.n_boot = 20.0, 2, 50
    return cfg


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.transfer",
                                description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_arguments(p)
    args = p.parse_args(argv)
    cfg = config_from_args(args)
    from benchmarks.common import Log, set_threads
    set_threads(cfg.threads)
    if args.tables_only:
        write_tables(cfg)
    else:
        run_protocol(cfg, Log("transfer"))
    print(cfg.out / "transfer.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
