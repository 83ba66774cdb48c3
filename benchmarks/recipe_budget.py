"""The default ``aslip train`` against its time budget, on a lab-sized recording.

The data are the scene's twin of a lab's first training set (results/recipes/README.md):
12 robot-induced trials of 60 s to pretrain on and 20 externally induced trials of 60 s (14
training, 3 validation, 3 test trials by the split). For each ``--budgets`` value the
default call runs as a user runs it, features included (the feature caches are deleted
first):

    aslip train --dataset EXT --pretrain-dataset ROBOT --out B.pt --time-budget B

and the chosen checkpoint is evaluated on the 3 test trials, which neither training nor
selection read, with 95 % intervals from a bootstrap over those trials. The budget is wall
time, so a busier machine trains fewer epochs in the same budget: run it on an idle one.

Beside it, on the same test trials (``--no-baselines``: not): the plain log-mel CNN (with
its speed head) and the plain RBF SVR that regresses the speed itself
(``learn.baselines``), each trained on the 17 training and validation trials, as many as
the default's final model trains on. Rows of budgets not run this time are kept from the
previous ``budget.json``.

    python -m benchmarks.recipe_budget --out results/recipes      (make recipe-budget)
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from aslip_ros.learn.stats import KEYS
from aslip_ros.util import read_json, write_json, write_text

from .common import scene_cache

#: Whole-call budgets [s]: 4, 8, 16 (the default) and 32 min.
BUDGETS = (240.0, 480.0, 960.0, 1920.0)
CANDIDATE_KEYS = ("name", "status", "val", "score", "train_s", "stop_reason")
#: The recording (the scene's seeds 11 and 12, as results/recipes/README.md gives it).
SIMULATE = {
    "robot": ["--kind", "robot", "--trials", "12", "--duration", "60", "--seed", "11"],
    "external": ["--kind", "external", "--objects",
                 "chips_can,cracker_box,glass_cleaner,mustard_container,pla_rod",
                 "--conditions", "robot_off,robot_moving", "--trials", "2", "--duration",
                 "60", "--seed", "12"],
}


def log(msg: str) -> None:
    print(f"[recipe-budget {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def ensure_data(root: Path) -> dict[str, Path]:
    """The two datasets under ``root`` (simulated and exported when missing)."""
    from aslip_ros.cli import main as aslip
    out = {}
    for kind, argv in SIMULATE.items():
        bags, ds = root / "bags" / kind, root / "datasets" / kind
        if not (ds / "manifest.json").is_file():
            log(f"simulating and exporting the {kind} set")
            if aslip(["simulate", *argv, "-o", str(bags)]) != 0 or aslip(
                    ["export", str(bags), "-o", str(ds)]) != 0:
                raise RuntimeError(f"could not build the {kind} dataset under {root}")
        out[kind] = ds
    return out


def run_budget(data: dict[str, Path], budget_s: float, out: Path, models: Path,
               n_boot: int) -> dict[str, Any]:
    """One default call at ``budget_s`` and its chosen model on the test trials (the
    checkpoint under ``models``, its comparison copied to ``out``)."""
    from aslip_ros.learn.evaluate import predict_split
    from aslip_ros.learn.stats import bootstrap_metrics
    from aslip_ros.learn.training import cli as train_cli
    for ds in data.values():
        shutil.rmtree(ds / ".feature_cache", ignore_errors=True)
    models.mkdir(parents=True, exist_ok=True)
    ckpt = models / f"budget_{budget_s:g}.pt"
    argv = ["--dataset", str(data["external"]), "--pretrain-dataset", str(data["robot"]),
            "--out", str(ckpt), "--time-budget", f"{budget_s:g}", "--no-progress"]
    p = argparse.ArgumentParser()
    train_cli.add_arguments(p)
    log("aslip train " + " ".join(argv))
    t0 = time.perf_counter()
    if train_cli.run(p.parse_args(argv)) != 0:
        raise RuntimeError(f"aslip train failed at budget {budget_s:g} s")
    wall = time.perf_counter() - t0
    sel = read_json(Path(f"{ckpt}.selection.json"))
    shutil.copyfile(f"{ckpt}.selection.md", out / f"budget_{budget_s:g}.selection.md")
    pr = predict_split(ckpt, data["external"], "test")
    test = bootstrap_metrics(pr["trial"], pr["prob"], pr["raw_velocity"], pr["true_velocity"],
                             pr["slip"], pr["window_s"], n_boot=n_boot)
    winner = next(r for r in sel["candidates"] if r["name"] == sel["winner"])
    return {"budget_s": budget_s, "wall_s": round(wall, 1), "winner": sel["winner"],
            "val": {k: winner["val"].get(k) for k in KEYS},
            "val_worth": sel.get("worth"),
            "test": {k: test.get(k) for k in KEYS},
            "test_ci": {k: test.get(k + "_ci") for k in KEYS},
            "n_test_trials": int(len(set(pr["trial"].tolist()))),
            "candidates": [{k: r.get(k) for k in CANDIDATE_KEYS} for r in sel["candidates"]],
            "rounds": sel["allocation"]["rounds"], "rest": sel["allocation"]["rest"]}


def run_baselines(data: dict[str, Path], n_boot: int) -> dict[str, Any]:
    """The plain CNN and the plain SVR on the test trials (module docstring)."""
    from aslip_ros.learn.baselines import run_on_dataset
    from aslip_ros.learn.data_io import open_dataset
    log("plain baselines (trained on the training and validation trials)")
    t0 = time.perf_counter()
    out = run_on_dataset(open_dataset(data["external"]), n_boot=n_boot,
                         train_splits=("train", "val"))
    return {name: {"test": {k: m.get(k) for k in KEYS},
                   "test_ci": {k: m.get(k + "_ci") for k in KEYS}}
            for name, m in out.items()} | {"wall_s": round(time.perf_counter() - t0, 1)}


def _cell(row: dict[str, Any], k: str, scale: float, nd: int) -> str:
    v, ci = row["test"].get(k), row["test_ci"].get(k)
    if v is None:
        return "-"
    interval = f" [{ci[0] * scale:.{nd}f}, {ci[1] * scale:.{nd}f}]" if ci else ""
    return f"{v * scale:.{nd}f}{interval}"


def markdown(rows: list[dict[str, Any]], command: str,
             baselines: dict[str, Any] | None = None) -> str:
    lines = ["# The default `aslip train` against its time budget", "",
             f"`{command}`. The data: results/recipes/README.md (12 robot-induced and 20 "
             "externally induced trials of 60 s). Test: the 3 test trials no training or "
             "selection read; brackets: 95 % trial-bootstrap intervals (3 trials: wide).", "",
             "| budget min | wall min | chosen | test det. % | test dir. MAE deg | test mag. "
             "RMSE mm | val det. % / dir. / mag. |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        v = r["val"]
        lines.append(
            f"| {r['budget_s'] / 60:.0f} | {r['wall_s'] / 60:.1f} | {r['winner']} | "
            f"{_cell(r, 'detection_accuracy', 100, 1)} | {_cell(r, 'direction_mae_deg', 1, 1)} "
            f"| {_cell(r, 'magnitude_rmse_mm', 1, 2)} | {100 * v['detection_accuracy']:.1f} / "
            f"{v['direction_mae_deg']:.1f} / {v['magnitude_rmse_mm']:.2f} |")
    for name, b in (baselines or {}).items():
        if name != "wall_s":
            lines.append(f"| - | - | {name} (train + val trials) | "
                         f"{_cell(b, 'detection_accuracy', 100, 1)} | "
                         f"{_cell(b, 'direction_mae_deg', 1, 1)} | "
                         f"{_cell(b, 'magnitude_rmse_mm', 1, 2)} | - |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    x = [r["budget_s"] / 60 for r in rows]
    for ax, k, label in ((axes[0], "direction_mae_deg", "direction MAE [deg]"),
                         (axes[1], "magnitude_rmse_mm", "magnitude RMSE [mm]")):
        y = [r["test"][k] for r in rows]
        lo = [r["test"][k] - r["test_ci"][k][0] for r in rows]
        hi = [r["test_ci"][k][1] - r["test"][k] for r in rows]
        ax.errorbar(x, y, yerr=[lo, hi], marker="o", capsize=3, label="test (3 trials)")
        ax.plot(x, [r["val"][k] for r in rows], marker="s", ls="--", label="validation")
        for xi, r in zip(x, rows):
            ax.annotate(r["winner"], (xi, r["test"][k]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        ax.set_xscale("log", base=2)
        ax.set_xticks(x, [f"{v:g}" for v in x])
        ax.set_xlabel("budget of the whole call [min]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("default aslip train: the chosen model against the budget", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="results/recipes", help="results (json, markdown, png)")
    p.add_argument("--data", default="data/recipes", help="bags and datasets (git-ignored)")
    p.add_argument("--budgets", default=",".join(f"{b:g}" for b in BUDGETS),
                   help="comma-separated whole-call budgets [s]")
    p.add_argument("--n-boot", type=int, default=1000)
    p.add_argument("--no-baselines", action="store_true",
                   help="leave out the plain CNN and plain SVR on the same test trials")


def run(args: argparse.Namespace) -> int:
    budgets = [float(b) for b in args.budgets.split(",") if b.strip()]
    if (not budgets and args.no_baselines) or (budgets and min(budgets) <= 0):
        raise ValueError("--budgets must be positive seconds")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    root = scene_cache(Path(args.data))
    data = ensure_data(root)
    before = read_json(out / "budget.json") if (out / "budget.json").is_file() else {}
    kept = {r["budget_s"]: r for r in before.get("rows", [])}
    baselines = before.get("baselines")
    for b in budgets:
        kept[b] = run_budget(data, b, out, root / "models", args.n_boot)
        log(f"budget {b:g} s: {kept[b]['winner']} in {kept[b]['wall_s']:.0f} s, test "
            + ", ".join(f"{k} {kept[b]['test'][k]:.3g}" for k in KEYS))
        write_json(out / "budget.json", {"rows": [kept[k] for k in sorted(kept)],
                                         "baselines": baselines})
    if not args.no_baselines:
        baselines = run_baselines(data, args.n_boot)
    rows = [kept[k] for k in sorted(kept)]
    write_json(out / "budget.json", {"rows": rows, "baselines": baselines})
    command = "python -m benchmarks.recipe_budget --budgets " + ",".join(
        f"{r['budget_s']:g}" for r in rows)
    write_text(out / "budget.md", markdown(rows, command, baselines))
    if rows:
        plot(rows, out / "budget.png")
    log(f"wrote {out / 'budget.json'}, budget.md and budget.png")
    return 0


def main(argv: list[str] | None = None) -> int:
    from benchmarks.cli import main as bench_main
    return bench_main("recipe_budget", argv)


if __name__ == "__main__":
    raise SystemExit(main())
