"""Rotational slip (issue #21): how well the default ``aslip train`` hears it, per layout.

The data are the scene's externally induced trials on the five objects with twisting pushes
(``--twist-fraction``: half of those pure twists about the pad normal, half twists with a
push) and gravity pivots (an object held off its centre of mass turns when the grip
relaxes), docs/scene.md "Rotational slip". Every layout is simulated from the same seeds,
so the layouts hear the same motions. For each layout the default call trains as a user
runs it, with a fixed time budget so that the layouts are compared at equal cost:

    aslip train --dataset TRAIN --out L.pt --time-budget B

and is tested on a fresh draw of the scene (other seeds: every trial a test trial). Every
figure carries a 95 % interval from a bootstrap over test trials.

- Rotational: the angular-velocity MAE over rotating windows (|w| above
  ``slip.ROTATION_EPSILON_RAD_S``) against the mean true rate there; the detection of pure
  rotation; rotation reported on pure translation; whether each slip window is told to be a
  rotation or a translation.
- Planar, on the same test trials, and (4mic) on every transfer scene (``make transfer``'s
  test sets), beside the transfer's ``aslip`` trained without rotation: adding the
  rotational output and the twisting trials must not cost planar accuracy.

    python -m benchmarks.rotation --out results/rotation          (make rotation)
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aslip_ros.util import write_json, write_text

from .common import scene_cache

#: 1, 2 and 4 microphones; the two-microphone layouts differ in where the pair sits.
LAYOUTS = ("4mic", "2mic_corners", "2mic_same_finger", "2mic_centered", "1mic")
OBJECTS = ("chips_can", "cracker_box", "glass_cleaner", "mustard_container", "pla_rod")
CONDITIONS = ("robot_stationary", "robot_off", "robot_moving")
#: Seed offsets: training trials, gravity pivots, and the fresh draw tested on.
TEST_SEED = 700_000
PIVOT_SEED = 80_000
ROT_KEYS = (("rotation_mae_deg_s", "rot. MAE deg/s", 1.0),
            ("rotation_mae_ratio", "MAE / mean rate %", 100.0),
            ("pure_rotation_detection", "pure rotation detected %", 100.0),
            ("false_rotation_on_translation", "rotation on translation %", 100.0),
            ("kind_agreement", "rotation vs translation %", 100.0))
PLANAR_KEYS = (("detection_accuracy", "detection %", 100.0),
               ("direction_mae_deg", "direction deg", 1.0),
               ("magnitude_rmse_mm", "magnitude mm", 1.0))


@dataclass
class RotationConfig:
    out: Path
    data: Path = Path("data/rotation")
    layouts: tuple[str, ...] = LAYOUTS
    trials: int = 4                  # per object and condition (60 training trials)
    test_trials: int = 1             # per object and condition in the fresh draw
    pivot_trials: int = 2            # gravity pivots per object (training; 1 in the test draw)
    duration_s: float = 10.0
    twist_fraction: float = 0.5
    time_budget_s: float = 240.0
    seed: int = 0
    threads: int = 2
    n_boot: int = 500
    planar: bool = True
    progress: bool = False


def log(msg: str) -> None:
    print(f"[rotation {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# --- data ---------------------------------------------------------------------------------

def root(cfg: RotationConfig) -> Path:
    return scene_cache(cfg.data)


def _draw(cfg: RotationConfig, test: bool) -> str:
    """The name of the training or the test draw: everything that made it."""
    n = cfg.test_trials if test else cfg.trials
    return (f"{'test' if test else 'train'}-{n}x{_pivots(cfg, test)}-{cfg.duration_s:g}s-"
            f"twist{cfg.twist_fraction:g}")


def _pivots(cfg: RotationConfig, test: bool) -> int:
    return max(1, cfg.pivot_trials // 2) if test else cfg.pivot_trials


def dataset(cfg: RotationConfig, layout: str, test: bool) -> Path:
    """The twisting-and-pivoting dataset of ``layout`` (training draw, or the test draw)."""
    from aslip_ros.data.export import export
    from aslip_ros.scene.simulate import simulate
    name = _draw(cfg, test)
    ds = root(cfg) / "datasets" / layout / name
    if (ds / "manifest.json").is_file():
        return ds
    bags = root(cfg) / "bags" / layout / name
    seed = cfg.seed + (TEST_SEED if test else 0)
    n = cfg.test_trials if test else cfg.trials
    log(f"{layout}/{name}: simulating")
    simulate(bags / "external", "external", objects=OBJECTS, conditions=CONDITIONS,
             trials=n, duration_s=cfg.duration_s, seed=seed, layout=layout,
             progress=cfg.progress, twist_fraction=cfg.twist_fraction)
    simulate(bags / "pivot", "pivot", objects=OBJECTS, conditions=("robot_stationary",),
             trials=_pivots(cfg, test), duration_s=cfg.duration_s, seed=seed + PIVOT_SEED,
             layout=layout, progress=cfg.progress)
    log(f"{layout}/{name}: exporting")
    export([bags / "external", bags / "pivot"], ds)
    return ds


# --- train, predict, score ----------------------------------------------------------------

def _transfer_config(cfg: RotationConfig):
    """``make transfer``'s configuration with this benchmark's seed, threads and budget."""
    from benchmarks import transfer as tr
    return tr.TransferConfig(out=cfg.out / "transfer", progress=cfg.progress,
                             threads=cfg.threads, seed=cfg.seed, methods=("aslip",),
                             time_budget_s=cfg.time_budget_s)


def train(cfg: RotationConfig, layout: str, train_ds: Path) -> Path:
    """The default ``aslip train`` on ``train_ds`` at the configured budget (cached), as
    ``make transfer`` trains its ``aslip``."""
    from benchmarks import transfer as tr
    return tr.train_method(_transfer_config(cfg), "aslip", train_ds,
                           root(cfg) / "models" / f"{layout}-{_draw(cfg, False)}-"
                           f"{cfg.time_budget_s:g}s", log)


def predictions(ckpt: Path, test_ds: Path) -> dict[str, Any]:
    """Every window of the test draw (all its trials are test trials)."""
    from aslip_ros.learn.evaluate import predict_split
    p = predict_split(ckpt, test_ds, "all")
    out = {k: np.asarray(p[k]) for k in ("prob", "raw_velocity", "true_velocity", "slip",
                                         "trial", "true_angular")}
    # A checkpoint without a rotational output publishes 0: scored as such.
    out["angular"] = None if p.get("angular") is None else np.asarray(p["angular"])
    return out | {"window_s": float(p["window_s"]), "threshold": float(p["threshold"])}


def score(cfg: RotationConfig, p: dict[str, Any]) -> dict[str, Any]:
    """Rotational and planar metrics with 95 % trial-bootstrap intervals."""
    from aslip_ros.learn.stats import bootstrap_metrics
    res = bootstrap_metrics(p["trial"], p["prob"], p["raw_velocity"], p["true_velocity"],
                            p["slip"], p["window_s"], n_boot=cfg.n_boot, seed=cfg.seed,
                            threshold=p["threshold"], angular=p["angular"],
                            true_angular=p["true_angular"])
    res["n_trials"] = int(np.unique(p["trial"]).size)
    return res


def planar_on_transfer(cfg: RotationConfig, ckpt: Path) -> dict[str, Any]:
    """The 4mic model on every transfer scene's test set, beside the transfer's ``aslip``."""
    from benchmarks import transfer as tr
    # The transfer's own aslip, at the transfer's own budget (aslip train's default).
    tcfg = dataclasses.replace(_transfer_config(cfg), time_budget_s=None)
    rows: dict[str, Any] = {}
    for scene, ds in tr.test_sets(tcfg, "default", log).items():
        before_path = tr._predictions_path(tcfg, "default", scene, "aslip")
        if not before_path.is_file():
            model = tr.train_method(tcfg, "aslip", tr.scene_dataset(tcfg, "default", log),
                                    tr.scene_root(tcfg) / "models" / "default", log)
            tr._save_predictions(before_path, tr.predict(tcfg, "aslip", model, ds, "all"))
        before = tr._load_predictions(before_path)
        from aslip_ros.learn.evaluate import predict_split
        after = predict_split(ckpt, ds, "all")
        rows[scene] = {"before": tr.score(tcfg, before), "after": tr.score(tcfg, after)}
        log(f"planar {scene}: before {tr.metrics_cell(rows[scene]['before'])}; "
            f"after {tr.metrics_cell(rows[scene]['after'])}")
    return rows


# --- tables -------------------------------------------------------------------------------

def cell(res: dict[str, Any], key: str, scale: float) -> str:
    v = res.get(key)
    if v is None or not np.isfinite(v):
        return "n/a"
    ci = res.get(key + "_ci")
    s = f"{v * scale:.1f}"
    return s + (f" [{ci[0] * scale:.1f}, {ci[1] * scale:.1f}]" if ci else "")


def overlaps(a: dict[str, Any], b: dict[str, Any], key: str, higher_better: bool) -> str:
    """'better', 'overlap' or 'worse' for ``a`` against ``b`` by their intervals."""
    ca, cb = a.get(key + "_ci"), b.get(key + "_ci")
    if not ca or not cb:
        return "n/a"
    if ca[0] > cb[1]:
        return "better" if higher_better else "worse"
    if ca[1] < cb[0]:
        return "worse" if higher_better else "better"
    return "overlap"


def tables(result: dict[str, Any]) -> str:
    cfg = result["config"]
    lines = ["# Rotational slip: measured (`make rotation`)\n",
             f"Training: {cfg['trials']} trials per object and condition, twist fraction "
             f"{cfg['twist_fraction']}, {cfg['pivot_trials']} gravity pivots per object, "
             f"{cfg['duration_s']:g} s each; `aslip train` at a {cfg['time_budget_s']:g} s "
             f"budget per layout. Test: a fresh draw (other seeds). 95 % intervals from a "
             f"bootstrap over test trials.\n"]
    head = ["layout", "trials"] + [name for _, name, _ in ROT_KEYS]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    for layout, res in result["layouts"].items():
        lines.append("| " + " | ".join([layout, str(res["n_trials"])] + [
            cell(res, k, s) for k, _, s in ROT_KEYS]) + " |")
    lines.append("\nPlanar, same test trials:\n")
    head = ["layout"] + [name for _, name, _ in PLANAR_KEYS]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    for layout, res in result["layouts"].items():
        lines.append("| " + " | ".join([layout] + [cell(res, k, s) for k, _, s in PLANAR_KEYS])
                     + " |")
    if result.get("planar"):
        lines.append("\nPlanar on the transfer scenes (4mic): before = `make transfer`'s "
                     "`aslip` (no rotation), after = this benchmark's 4mic model:\n")
        head = ["scene"] + [f"{name} before / after" for _, name, _ in PLANAR_KEYS]
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + "---|" * len(head))
        for scene, r in result["planar"].items():
            cells = []
            for k, _, s in PLANAR_KEYS:
                verdict = overlaps(r["after"], r["before"], k, k == "detection_accuracy")
                cells.append(f"{cell(r['before'], k, s)} / {cell(r['after'], k, s)} "
                             f"({verdict})")
            lines.append("| " + " | ".join([scene] + cells) + " |")
    return "\n".join(lines) + "\n"


# --- the protocol -------------------------------------------------------------------------

def run(cfg: RotationConfig) -> dict[str, Any]:
    result: dict[str, Any] = {"config": {k: (str(v) if isinstance(v, Path) else v)
                                         for k, v in asdict(cfg).items()},
                              "layouts": {}, "train_s": {}}
    ckpts = {}
    for layout in cfg.layouts:
        t0 = time.perf_counter()
        ckpts[layout] = train(cfg, layout, dataset(cfg, layout, test=False))
        result["train_s"][layout] = round(time.perf_counter() - t0, 1)
        res = score(cfg, predictions(ckpts[layout], dataset(cfg, layout, test=True)))
        result["layouts"][layout] = res
        log(f"{layout}: " + ", ".join(f"{name} {cell(res, k, s)}" for k, name, s in ROT_KEYS))
        _write(cfg, result)
    if cfg.planar and "4mic" in ckpts:
        result["planar"] = planar_on_transfer(cfg, ckpts["4mic"])
    _write(cfg, result)
    return result


def _write(cfg: RotationConfig, result: dict[str, Any]) -> None:
    cfg.out.mkdir(parents=True, exist_ok=True)
    write_json(cfg.out / "rotation.json", result)
    write_text(cfg.out / "rotation.md", tables(result))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.rotation", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("results/rotation"))
    p.add_argument("--data", type=Path, default=Path("data/rotation"))
    p.add_argument("--layouts", default=",".join(LAYOUTS))
    p.add_argument("--trials", type=int, default=4,
                   help="training trials per object and condition")
    p.add_argument("--duration", type=float, default=10.0, help="seconds per trial")
    p.add_argument("--time-budget", type=float, default=240.0)
    p.add_argument("--twist-fraction", type=float, default=0.5)
    p.add_argument("--no-planar", action="store_true", help="skip the transfer scenes")
    p.add_argument("--progress", action="store_true")
    a = p.parse_args(argv)
    layouts = tuple(s.strip() for s in a.layouts.split(",") if s.strip())
    from aslip_ros.scene.layouts import LAYOUTS as KNOWN
    bad = [x for x in layouts if x not in KNOWN]
    if bad or a.trials < 1 or not a.time_budget > 0 or not a.duration > 0 \
            or not 0.0 < a.twist_fraction <= 1.0:
        print(f"error: unknown layouts {bad}, or --trials < 1, --time-budget or --duration "
              f"<= 0, or --twist-fraction outside (0, 1]", file=sys.stderr)
        return 2
    cfg = RotationConfig(out=a.out, data=a.data, layouts=layouts, trials=a.trials,
                         duration_s=a.duration, time_budget_s=a.time_budget,
                         twist_fraction=a.twist_fraction,
                         planar=not a.no_planar, progress=a.progress)
    res = run(cfg)
    print(tables(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
