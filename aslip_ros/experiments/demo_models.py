"""The demo's two checkpoints (A-SLIP CNN and the SVM baseline), trained on the scene.

``aslip demo --train-models`` runs this: simulate externally induced slip on the five
objects with the scene's microphones (4mic, 200 ms windows), mostly with the arm moving,
export it, train the CNN from scratch and the SVM on the same trials, evaluate both on the
held-out test trials and write ``models/aslip_cnn.pt``, ``models/svm.pt`` and
``models/manifest.json`` (scene version, command, metrics).

Why this set and not the paper's pretrain-then-finetune pair: in the closed-loop tasks the
arm moves while nothing slips (retract, approach, following), and the robot-induced
pretraining set only ever pairs robot noise with slip. A model must have heard the arm
moving without slip; the scene's ``robot_moving`` condition (the arm wanders with the
object while an agent pushes it now and then) is exactly that, so it dominates this set.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from pathlib import Path

from aslip_ros.util import write_json

OBJECTS = ("pla_rod", "glass_cleaner", "chips_can", "mustard_container", "cracker_box")
CNN_NAME = "aslip_cnn.pt"
SVM_NAME = "svm.pt"
MANIFEST = "manifest.json"
COMMAND = "aslip demo --train-models"
#: Trials per object and condition, seconds per trial, export hop (the recipe).
RECIPE = {"robot_moving": 4, "robot_stationary": 2, "duration_s": 10.0, "hop_s": 0.05,
          "window_s": 0.2, "seed": 0, "time_budget_s": 240.0, "epochs": 40,
          "svm_max_train": 1500}


def scene_version() -> str:
    """``aslip_ros.scene.SCENE_VERSION`` when the scene has one, else a hash of its code."""
    import aslip_ros.scene as scene
    v = getattr(scene, "SCENE_VERSION", None)
    if v is not None:
        return str(v)
    h = hashlib.sha256()
    for p in sorted(Path(scene.__file__).resolve().parent.glob("*.py")):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return "src-" + h.hexdigest()[:16]


def shipped_models(models_dir: str | Path) -> dict | None:
    """The manifest when both checkpoints exist and match the current scene, else None."""
    d = Path(models_dir)
    try:
        man = json.loads((d / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if man.get("scene_version") != scene_version():
        return None
    if not (d / CNN_NAME).is_file() or not (d / SVM_NAME).is_file():
        return None
    return man


def aslip(argv: list[str]) -> int:
    """``aslip train|evaluate ARGS`` through the subcommand's own parser and ``run`` (the
    same defaults as the command line, without importing the command line above this floor)."""
    import argparse

    from aslip_ros.learn import evaluate, train
    module = {"train": train, "evaluate": evaluate}[argv[0]]
    parser = argparse.ArgumentParser(prog=f"aslip {argv[0]}")
    module.add_arguments(parser)
    return int(module.run(parser.parse_args(argv[1:])) or 0)


def train_models(models_dir: str | Path = "models", data_dir: str | Path = "data/demo",
                 progress: bool = True, threads: int = 2) -> dict:
    """Simulate, export, train and evaluate; returns the manifest written to models_dir."""
    from aslip_ros.data.export import ExportConfig, export
    from aslip_ros.data.simulate import simulate

    t0 = time.perf_counter()
    r = RECIPE
    # Bags are reused when present (simulate resumes), so each scene version gets its own
    # folder: audio from an older scene must never reach a model for the new one.
    data = Path(data_dir) / f"scene-{scene_version()}"
    bags = data / "bags"
    ds = data / "dataset"
    out = Path(models_dir)
    out.mkdir(parents=True, exist_ok=True)
    log = (lambda m: print(f"[demo models {time.perf_counter() - t0:6.0f} s] {m}",
                           file=sys.stderr, flush=True))
    for cond in ("robot_moving", "robot_stationary"):
        log(f"simulating {r[cond]} x {len(OBJECTS)} externally induced trials, {cond}")
        simulate(bags, "external", objects=list(OBJECTS), conditions=[cond], trials=r[cond],
                 duration_s=r["duration_s"], seed=r["seed"], layout="4mic",
                 progress=progress)
    log("exporting")
    export([bags], ds, ExportConfig(window_s=r["window_s"], hop_s=r["hop_s"], overwrite=True,
                                    progress=progress))
    quiet = [] if progress else ["--no-progress"]
    cnn, svm = out / CNN_NAME, out / SVM_NAME
    log("training the CNN (scratch)")
    if aslip(["train", "--dataset", str(ds), "--stage", "scratch", "--out", str(cnn),
              "--seed", str(r["seed"]), "--epochs", str(r["epochs"]),
              "--time-budget", str(r["time_budget_s"]), "--threads", str(threads)]
             + quiet) != 0:
        raise RuntimeError("CNN training failed")
    log("training the SVM")
    if aslip(["train", "--dataset", str(ds), "--stage", "svm", "--out", str(svm),
              "--seed", str(r["seed"]), "--svm-max-train", str(r["svm_max_train"])]
             + quiet) != 0:
        raise RuntimeError("SVM training failed")
    metrics = {}
    for name, path in (("aslip_cnn", cnn), ("svm", svm)):
        js = data / f"eval_{name}.json"
        log(f"evaluating {name} on the test trials")
        if aslip(["evaluate", "--checkpoint", str(path), "--dataset", str(ds), "--split",
                  "test", "--json", str(js), "--threads", str(threads)]) != 0:
            raise RuntimeError(f"evaluating {name} failed")
        overall = json.loads(js.read_text())["overall"]
        metrics[name] = {k: overall.get(k) for k in
                         ("n_windows", "detection_accuracy", "precision", "recall",
                          "direction_mae_deg", "direction_std_deg", "magnitude_rmse_mm",
                          "magnitude_std_mm")}
    man = {"format": "aslip-demo-models", "version": 1, "scene_version": scene_version(),
           "command": COMMAND, "recipe": dict(r), "objects": list(OBJECTS), "layout": "4mic",
           "files": {"aslip": CNN_NAME, "svm": SVM_NAME},
           "sizes_bytes": {CNN_NAME: cnn.stat().st_size, SVM_NAME: svm.stat().st_size},
           "test_metrics": metrics, "train_s": round(time.perf_counter() - t0, 1),
           "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    write_json(out / MANIFEST, man)
    log(f"wrote {cnn}, {svm} and {out / MANIFEST}")
    return man
