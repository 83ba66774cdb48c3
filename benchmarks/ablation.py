"""The paper's Table I and Table II and the robot-noise evaluation on the scene.

``make ablation`` (``python -m benchmarks.ablation --out results/ablation``) trains and
evaluates every row of Table I (SVM; single microphone without and with pretraining;
pretrain-only and finetuned for the four layouts; 100, 200 and 300 ms windows), Table II
(per-object against all-object finetuning, 4 microphones) and evaluates each finetuned model
on the robot-induced validation set (Sec. "Slip with Robot Noise"). Beside the paper's SVM stand
the plain baselines of ``learn.baselines`` (a plain log-mel CNN and an RBF SVM on
time-averaged log-mel; rows without paper numbers), trained on the same training trials.

Protocol (the paper's, at the scene's scale):

- pretrain: robot-induced set of the layout (``data/datasets/<layout>/pretrain``, preset);
- finetune: encoder frozen, heads trained on the externally induced set;
- every Table I number is measured on the externally induced set's held-out *test* split
  (by trial, ``split_trials`` seed 0), the robot-noise numbers on the robot-induced set's
  *validation* split, as the paper does.

Every Table I number carries a 95 % interval from a bootstrap over the test trials
(``learn.stats``), and every row records when and on which scene version it was measured:
``--baselines-only`` measures the SVM and the plain baselines alone (minutes instead of
hours) and merges them into an existing ``table.json``, keeping the other rows as measured
before.

Outputs in ``--out``: ``table.json``/``table.md`` (ours beside the paper's),
``per_object.json``/``.md``, ``robot_noise.json``/``.md``; checkpoints and per-row metrics
under ``--out/cache`` (git-ignored). A row whose checkpoint and metrics exist is not
retrained unless ``--force``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aslip_ros.scene.layouts import PAPER_LAYOUTS
from aslip_ros.util import read_json, write_json, write_text

from .ablation_report import (CI_COLUMNS, bootstrap_intervals, majority, merge_rows, orderings,
                              pct, per_object_markdown, robot_noise_markdown, short,
                              table_markdown)
from .common import (EXTERNAL_TRIALS, DataPlan, Log, Recipe, evaluate_cached, paper_units,
                     configured, train_named)


@dataclass(frozen=True)
class Row:
    """One line of Table I: how it is trained and the paper's numbers."""

    key: str
    label: str
    kind: str            # svm | scratch | pretrain_only | finetune | plain_cnn | plain_svm
    layout: str
    window_ms: int
    paper: tuple[float, float, float, float, float] | None  # det %, dir ± std, mag ± std


#: Table I of the paper (Det. %, Dir. MAE deg ± std, Mag. RMSE mm ± std).
TABLE1: tuple[Row, ...] = (
    Row("svm", "SVM", "svm", "4mic", 200, (73.0, 19.2, 28.6, 1.9, 2.4)),
    Row("plain_cnn", "Plain CNN (log-mel, untuned)", "plain_cnn", "4mic", 200, None),
    Row("plain_svm", "Plain SVM (time-averaged log-mel, RBF)", "plain_svm", "4mic", 200, None),
    Row("1mic_scratch", "Single mic (no pretrain)", "scratch", "1mic", 200,
        (43.3, 28.5, 26.5, 2.0, 1.0)),
    Row("1mic_finetune", "Single mic (pretrain + finetune)", "finetune", "1mic", 200,
        (70.2, 20.7, 22.4, 2.7, 0.9)),
    Row("pre_2mic_centered", "Pretrain only (2-mic, centered)", "pretrain_only",
        "2mic_centered", 200, (60.4, 29.3, 21.5, 1.5, 1.2)),
    Row("pre_2mic_corners", "Pretrain only (2-mic, corners)", "pretrain_only",
        "2mic_corners", 200, (63.1, 26.8, 21.1, 1.5, 1.2)),
    Row("pre_2mic_same_finger", "Pretrain only (2-mic, same finger)", "pretrain_only",
        "2mic_same_finger", 200, (61.2, 26.7, 21.2, 1.6, 1.2)),
    Row("pre_4mic", "Pretrain only (4-mic)", "pretrain_only", "4mic", 200,
        (72.4, 21.6, 8.0, 3.2, 1.4)),
    Row("ft_2mic_centered", "A-SLIP (2-mic, centered, finetuned)", "finetune",
        "2mic_centered", 200, (63.6, 20.4, 16.0, 1.0, 1.3)),
    Row("ft_2mic_corners", "A-SLIP (2-mic, corners, finetuned)", "finetune", "2mic_corners",
        200, (71.9, 18.1, 9.3, 0.6, 0.6)),
    Row("ft_2mic_same_finger", "A-SLIP (2-mic, same finger, finetuned)", "finetune",
        "2mic_same_finger", 200, (72.1, 19.0, 10.1, 0.7, 0.5)),
    Row("ft_4mic", "A-SLIP (4-mic, finetuned)", "finetune", "4mic", 200,
        (81.8, 14.1, 6.9, 1.0, 0.9)),
    Row("w100", "A-SLIP (100 ms window)", "finetune", "4mic", 100, (72.5, 8.2, 9.6, 0.6, 0.7)),
    Row("w200", "A-SLIP (200 ms window)", "finetune", "4mic", 200, (81.8, 14.1, 6.9, 1.0, 0.9)),
    Row("w300", "A-SLIP (300 ms window)", "finetune", "4mic", 300, (88.5, 20.9, 6.5, 1.4, 1.1)),
)
ROW_KEYS = tuple(r.key for r in TABLE1)
#: The rows ``--baselines-only`` measures: the paper's SVM and the plain baselines.
BASELINE_ROWS = ("svm", "plain_cnn", "plain_svm")

#: Table II (4 microphones): object -> {"per_object"|"all_object": (det, dir, std, mag, std)}.
TABLE2: dict[str, dict[str, tuple[float, float, float, float, float]]] = {
    "pla_rod": {"per_object": (94.5, 26.07, 9.8, 2.44, 1.20),
                "all_object": (94.7, 25.58, 9.1, 2.72, 1.30)},
    "glass_cleaner": {"per_object": (81.1, 15.17, 7.4, 0.60, 0.72),
                      "all_object": (78.7, 14.38, 6.8, 0.58, 0.68)},
    "chips_can": {"per_object": (71.8, 9.01, 6.1, 0.40, 0.63),
                  "all_object": (71.0, 8.58, 6.5, 0.41, 0.66)},
    "mustard_container": {"per_object": (84.0, 24.14, 9.6, 0.62, 0.82),
                          "all_object": (83.7, 22.20, 8.9, 0.60, 0.80)},
    "cracker_box": {"per_object": (79.4, 7.61, 5.9, 0.62, 0.74),
                    "all_object": (80.6, 6.90, 5.5, 0.55, 0.70)},
}

#: "Slip with Robot Noise": finetuned models on the robot-induced validation set
#: (dir MAE, std, mag RMSE, std; the paper gives no detection accuracy here).
ROBOT_NOISE: dict[str, tuple[float, float, float, float]] = {
    "4mic": (15.9, 16.6, 0.5, 0.2),
    "2mic_centered": (39.2, 26.0, 0.7, 0.4),
    "2mic_corners": (21.3, 20.9, 0.5, 0.4),
    "2mic_same_finger": (17.4, 18.7, 0.6, 0.3),
}


def paper_dict(p: tuple[float, ...] | None) -> dict[str, float | None]:
    keys = ("det_pct", "dir_mae_deg", "dir_std_deg", "mag_rmse_mm", "mag_std_mm")
    return dict(zip(keys, p if p is not None else (None,) * len(keys)))


@dataclass
class AblationConfig:
    """What to run; ``quick()`` is the tiny configuration the tests and ``--quick`` use."""

    out: Path = Path("results/ablation")
    data: DataPlan = field(default_factory=DataPlan)
    recipe: Recipe = field(default_factory=Recipe)
    rows: tuple[str, ...] = ROW_KEYS
    per_object: bool = True
    robot_noise: bool = True
    force: bool = False
    #: Keep the rows of an existing ``table.json`` that this run does not measure.
    merge: bool = False
    plain_epochs: int = 25      # the plain CNN's fixed recipe
    n_boot: int = 1000

    @property
    def cache(self) -> Path:
        return Path(self.out) / "cache"


class Ablation:
    """Runs the rows in dependency order with cached checkpoints and metrics."""

    def __init__(self, cfg: AblationConfig, log: Log | None = None) -> None:
        self.cfg = cfg
        self.log = log or Log("ablation")
        cfg.data.log = self.log
        self._retrained: set[Path] = set()    # --force retrains each checkpoint once a run

    # --- building blocks ------------------------------------------------------------------
    def ds(self, layout: str, stage: str, window_ms: int = 200) -> Path:
        return self.cfg.data.dataset(layout, stage, window_ms)

    def _train(self, name: str, dataset: Path, stage: str, **kw: Any) -> tuple[Path, dict]:
        return train_named(self.cfg.cache, name, dataset, stage, self.cfg.recipe,
                           force=self.cfg.force, trained=self._retrained, log=self.log, **kw)

    def pretrained(self, layout: str, window_ms: int = 200) -> tuple[Path, dict]:
        return self._train(f"pre_{layout}_w{window_ms}", self.ds(layout, "pretrain", window_ms),
                           "pretrain")

    def finetuned(self, layout: str, window_ms: int = 200) -> tuple[Path, dict]:
        pre, _ = self.pretrained(layout, window_ms)
        return self._train(f"ft_{layout}_w{window_ms}", self.ds(layout, "finetune", window_ms),
                           "finetune", init=pre)

    def evaluate(self, ckpt: Path, dataset: Path, name: str = "test", split: str = "test",
                 objects: list[str] | None = None) -> dict[str, Any]:
        return evaluate_cached(ckpt, dataset, name, split=split, objects=objects,
                               split_seed=self.cfg.recipe.split_seed, force=self.cfg.force)

    def intervals(self, ckpt: Path, dataset: Path) -> dict[str, Any]:
        """Trial-bootstrap intervals of a checkpoint's test metrics (cached beside it)."""
        from aslip_ros.learn.evaluate import predict_split
        out = ckpt.with_name(f"{ckpt.stem}.boot-test.json")
        if out.is_file() and not self.cfg.force and out.stat().st_mtime >= ckpt.stat().st_mtime:
            return read_json(out)
        p = predict_split(ckpt, dataset, "test", split_seed=self.cfg.recipe.split_seed)
        res = bootstrap_intervals(p["trial"], p["prob"], p["raw_velocity"],
                                  p["true_velocity"], p["slip"], float(p["window_s"]),
                                  self.cfg.n_boot, self.cfg.recipe.seed)
        write_json(out, res)
        return res

    def plain(self, r: Row, dataset: Path) -> tuple[dict[str, Any], dict[str, Any]]:
        """A plain baseline trained on the dataset's training trials: its test metrics (with
        intervals) and a training summary, cached per dataset fingerprint."""
        import numpy as np
        from aslip_ros.learn.baselines import run_on_dataset
        from aslip_ros.learn.data_io import open_dataset, select_windows
        ds = open_dataset(dataset)
        out = self.cfg.cache / f"{r.kind}_{r.layout}_w{r.window_ms}.eval-test.json"
        key = {"dataset_fingerprint": ds.fingerprint(), "epochs": self.cfg.plain_epochs,
               "seed": self.cfg.recipe.seed, "split_seed": self.cfg.recipe.split_seed,
               "n_boot": self.cfg.n_boot}
        if out.is_file() and not self.cfg.force:
            cached = read_json(out)
            if cached.get("key") == key:
                return cached["metrics"], {**cached["training"], "cached": True}
        self.log(f"train {r.kind} on {dataset}")
        t0 = time.perf_counter()
        m = run_on_dataset(ds, kinds=(r.kind.removeprefix("plain_"),),
                           split_seed=self.cfg.recipe.split_seed,
                           epochs=self.cfg.plain_epochs, seed=self.cfg.recipe.seed,
                           n_boot=self.cfg.n_boot)[r.kind]
        te = select_windows(ds, "test", seed=self.cfg.recipe.split_seed)
        m["n_trials"] = int(np.unique(ds.windows["trial"][te]).size)
        info = {"cached": False, "stage": r.kind, "seed": self.cfg.recipe.seed,
                "epochs_run": self.cfg.plain_epochs if r.kind == "plain_cnn" else None,
                "wall_s_incl_features": round(time.perf_counter() - t0, 1)}
        write_json(out, {"key": key, "metrics": m, "training": info})
        return m, info

    # --- Table I --------------------------------------------------------------------------
    def row(self, r: Row) -> dict[str, Any]:
        ft_ds = self.ds(r.layout, "finetune", r.window_ms)
        if r.kind.startswith("plain_"):
            ov, info = self.plain(r, ft_ds)
            return _row_dict(r, None, ov, ov, {}, info)
        if r.kind == "svm":
            ckpt, info = self._train(f"svm_{r.layout}_w{r.window_ms}", ft_ds, "svm")
        elif r.kind == "scratch":
            ckpt, info = self._train(f"scratch_{r.layout}_w{r.window_ms}", ft_ds, "scratch")
        elif r.kind == "pretrain_only":
            ckpt, info = self.pretrained(r.layout, r.window_ms)
        elif r.kind == "finetune":
            ckpt, info = self.finetuned(r.layout, r.window_ms)
        else:
            raise ValueError(f"unknown row kind {r.kind!r}")
        res = self.evaluate(ckpt, ft_ds)
        return _row_dict(r, ckpt, res["overall"], self.intervals(ckpt, ft_ds),
                         res["per_object"], info)

    # --- Table II -------------------------------------------------------------------------
    def per_object(self) -> dict[str, Any]:
        all_ckpt, _ = self.finetuned("4mic")
        pre, _ = self.pretrained("4mic")
        ft_ds = self.ds("4mic", "finetune")
        all_res = self.evaluate(all_ckpt, ft_ds)
        out: dict[str, Any] = {}
        objects = sorted(set(all_res["per_object"]) | set(TABLE2))
        for obj in objects:
            entry: dict[str, Any] = {"paper": {k: paper_dict(v)
                                               for k, v in TABLE2.get(obj, {}).items()}}
            if obj in all_res["per_object"]:
                entry["all_object"] = paper_units(all_res["per_object"][obj])
                ckpt, info = self._train(f"ft_4mic_w200_only-{obj}", ft_ds, "finetune",
                                         init=pre, objects=[obj])
                try:
                    res = self.evaluate(ckpt, ft_ds, name="test", objects=[obj])
                    entry["per_object"] = paper_units(res["overall"])
                    entry["per_object_training"] = info
                except ValueError as exc:
                    entry["note"] = str(exc)
            else:
                entry["note"] = "no test trials of this object in the split"
            out[obj] = entry
        return out

    # --- robot noise ----------------------------------------------------------------------
    def robot_noise(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for layout in PAPER_LAYOUTS:
            ckpt, _ = self.finetuned(layout)
            rob = self.evaluate(ckpt, self.ds(layout, "pretrain"), name="robot-val",
                                split="val")
            ext = self.evaluate(ckpt, self.ds(layout, "finetune"))
            o, e = paper_units(rob["overall"]), paper_units(ext["overall"])
            inc = None
            if o.get("dir_mae_deg") is not None and e.get("dir_mae_deg"):
                inc = round(100.0 * (o["dir_mae_deg"] / e["dir_mae_deg"] - 1.0), 1)
            p = ROBOT_NOISE.get(layout)
            out[layout] = {"robot_val": o, "external_test": e,
                           "dir_increase_pct": inc,
                           "paper": None if p is None else {
                               "dir_mae_deg": p[0], "dir_std_deg": p[1], "mag_rmse_mm": p[2],
                               "mag_std_mm": p[3]}}
        return out

    # --- everything -----------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        t0 = time.perf_counter()
        cfg = self.cfg
        rows = [r for r in TABLE1 if r.key in cfg.rows]
        measured: dict[str, dict[str, Any]] = {}
        for i, r in enumerate(rows):
            self.log(f"[{i + 1}/{len(rows)}] {r.label}")
            measured[r.key] = {**self.row(r), "measured": self.measured()}
            self.log(f"  -> {short(measured[r.key]['ours'])}")
        table = merge_rows(ROW_KEYS, cfg.out / "table.json" if cfg.merge else None, measured)
        result = {"rows": table, "checks": orderings(table),
                  "protocol": protocol(cfg),
                  "elapsed_s": None}
        per_obj = robot = None
        if cfg.per_object:
            self.log("Table II: per-object against all-object finetuning (4 mics)")
            per_obj = self.per_object()
            write_json(cfg.out / "per_object.json", per_obj)
            write_text(cfg.out / "per_object.md", per_object_markdown(per_obj))
        if cfg.robot_noise:
            self.log("robot noise: finetuned models on the robot-induced validation set")
            robot = self.robot_noise()
            write_json(cfg.out / "robot_noise.json", robot)
            write_text(cfg.out / "robot_noise.md", robot_noise_markdown(robot))
        result["elapsed_s"] = round(time.perf_counter() - t0, 1)
        write_json(cfg.out / "table.json", result)
        write_text(cfg.out / "table.md", table_markdown(result))
        self.log(f"wrote {cfg.out}/table.md ({result['elapsed_s'] / 60:.1f} min)")
        return {"table": result, "per_object": per_obj, "robot_noise": robot}

    def measured(self) -> dict[str, Any]:
        """When, on which scene version and at which revision a row was measured."""
        from aslip_ros.learn.checkpoint import git_revision
        from aslip_ros.scene.physics import SCENE_VERSION
        return {"scene_version": "synthetic" if self.cfg.data.synthetic else SCENE_VERSION,
                "date": _dt.datetime.now(_dt.timezone.utc).date().isoformat(),
                "git_revision": git_revision()}


def _row_dict(r: Row, ckpt: Path | None, ov: dict[str, Any], boot: dict[str, Any],
              per_object: dict[str, Any], info: dict[str, Any]) -> dict[str, Any]:
    ci = {col: [round(float(x) * f, 3) for x in boot[k]] for k, (col, f) in CI_COLUMNS.items()
          if boot.get(k) is not None}
    return {"key": r.key, "label": r.label, "kind": r.kind, "layout": r.layout,
            "window_ms": r.window_ms, "checkpoint": None if ckpt is None else str(ckpt),
            "paper": paper_dict(r.paper), "ours": paper_units(ov), "ci95": ci,
            "n_test_trials": boot.get("n_trials"), "majority_det_pct": majority(ov),
            "recall_pct": pct(ov.get("recall")), "precision_pct": pct(ov.get("precision")),
            "per_object": {k: paper_units(v) for k, v in per_object.items()},
            "training": info}


def protocol(cfg: AblationConfig) -> dict[str, Any]:
    r, d = cfg.recipe, cfg.data
    return {"data_root": str(d.base), "scale": d.scale, "synthetic": d.synthetic,
            "finetune_trials_per_object": d.external, "trial_s": d.duration_s,
            "epochs": r.epochs, "patience": r.patience, "time_budget_s": r.time_budget_s,
            "finetune_time_budget_s": r.finetune_time_budget_s,
            "noslip_ratio": r.noslip_ratio,
            "threads": r.threads, "seed": r.seed, "split_seed": r.split_seed,
            "evaluation": "externally induced set, test split (by trial)",
            "robot_noise": "robot-induced set, validation split"}


# --- CLI ----------------------------------------------------------------------------------

def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("results/ablation"))
    p.add_argument("--data", type=Path, default=Path("data"),
                   help="data root (datasets are built there when missing)")
    p.add_argument("--scale", default="default", choices=["tiny", "default", "paper"],
                   help="preset scale of the pretraining sets")
    p.add_argument("--preset-finetune", action="store_true",
                   help="finetune on the preset's finetuning set instead of the larger one")
    p.add_argument("--quick", action="store_true",
                   help="tiny scale and 2 epochs: a smoke run of the whole pipeline")
    p.add_argument("--rows", default=None, help=f"comma-separated subset of {ROW_KEYS}")
    p.add_argument("--merge", action="store_true",
                   help="keep the rows of an existing table.json that this run does not "
                        "measure (each row records its scene version and date)")
    p.add_argument("--baselines-only", action="store_true",
                   help=f"measure only {BASELINE_ROWS} (minutes), skip Table II and the "
                        "robot-noise table, and merge into the existing table.json")
    p.add_argument("--plain-epochs", type=int, default=25, help="the plain CNN's epochs")
    p.add_argument("--n-boot", type=int, default=1000,
                   help="bootstrap resamples (over test trials) for the 95 %% intervals")
    p.add_argument("--no-per-object", action="store_true", help="skip Table II")
    p.add_argument("--no-robot-noise", action="store_true", help="skip the robot-noise table")
    p.add_argument("--epochs", type=int, default=300, help="max epochs per training")
    p.add_argument("--patience", type=int, default=30,
                   help="early-stopping epochs (an epoch is only a few dozen batches)")
    p.add_argument("--time-budget", type=float, default=300.0,
                   help="seconds of training per model after which the best epoch is kept")
    p.add_argument("--finetune-time-budget", type=float, default=240.0,
                   help="seconds of training per finetuning (heads only)")
    p.add_argument("--noslip-ratio", type=float, default=3.0,
                   help="no-slip windows per slip window drawn each epoch")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--force", action="store_true", help="retrain and re-evaluate every row")
    p.add_argument("--datasets-only", action="store_true",
                   help="only build the datasets the ablation needs (make datasets)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--synthetic", action="store_true", help=argparse.SUPPRESS)


def config_from_args(args: argparse.Namespace) -> AblationConfig:
    progress = not args.no_progress
    scale = "tiny" if args.quick else args.scale
    external = None if (args.preset_finetune or args.quick or args.synthetic) \
        else dict(EXTERNAL_TRIALS)
    data = DataPlan(root=args.data, scale=scale, synthetic=args.synthetic, progress=progress,
                    external=external)
    recipe = Recipe(epochs=2 if args.quick else args.epochs,
                    patience=args.patience, time_budget_s=args.time_budget,
                    finetune_time_budget_s=args.finetune_time_budget,
                    noslip_ratio=args.noslip_ratio,
                    threads=args.threads, seed=args.seed, progress=progress)
    rows = tuple(x for x in args.rows.split(",") if x) if args.rows else ROW_KEYS
    if args.baselines_only:
        if args.rows:
            raise ValueError("--baselines-only and --rows exclude each other")
        rows = BASELINE_ROWS
    bad = set(rows) - set(ROW_KEYS)
    if bad:
        raise ValueError(f"unknown rows {sorted(bad)}; choose from {ROW_KEYS}")
    return AblationConfig(out=args.out, data=data, recipe=recipe, rows=rows,
                          per_object=not (args.no_per_object or args.baselines_only),
                          robot_noise=not (args.no_robot_noise or args.baselines_only),
                          force=args.force, merge=args.merge or args.baselines_only,
                          plain_epochs=args.plain_epochs, n_boot=args.n_boot)


def run(args: argparse.Namespace) -> int:
    cfg = configured("ablation", args, config_from_args)
    if cfg is None:
        return 2
    abl = Ablation(cfg)
    if args.datasets_only:
        for r in (r for r in TABLE1 if r.key in cfg.rows):
            own = r.kind in ("svm", "scratch", "plain_cnn", "plain_svm")
            for stage in ("finetune",) if own else ("pretrain", "finetune"):
                abl.log(f"dataset {abl.ds(r.layout, stage, r.window_ms)}")
        return 0
    res = abl.run()
    print((cfg.out / "table.md").read_text())
    return 0 if res["table"]["rows"] else 1


if __name__ == "__main__":
    from benchmarks.cli import main
    sys.exit(main("ablation"))
