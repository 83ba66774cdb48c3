"""The demo's checkpoints, trained on the scene: the causal streaming model (``aslip_stream``:
one estimate per 10 ms hop, with the live per-grasp calibration), the 200 ms window CNN
with and without that calibration (``aslip_window``, ``aslip_uncalibrated``) and the SVM
baseline (calibrated); and the package's default estimator, ``aslip``: the hybrid of the
streaming model and the window CNN (learn/models/aslip_hybrid.py, ``models/aslip.pt``),
assembled from those two, not trained.

``python -m benchmarks.demo --train-models`` runs this: simulate externally induced slip on
the five objects with the scene's microphones (4mic, 200 ms windows), mostly with the arm
moving and with a share of the agent's pushes twisting the object about the pad normal
(``twist_fraction``), plus a few trials of an object held off its centre of mass that
gravity turns in the grasp (``gravity_pivot``), so every model learns the rotational output
the pivot-stop task acts on (issue #21); export it, train the four models on the same
trials, evaluate them on the held-out test trials and write ``models/aslip_stream.pt``,
``models/aslip_cnn.pt``, ``models/aslip_cnn_uncalibrated.pt``, ``models/svm.pt``, their
hybrid ``models/aslip.pt`` and ``models/manifest.json`` (scene version, recipe, commands,
metrics). A set is used only when
every model in it was trained for the current scene version with the current recipe
(manifest version 4); otherwise all are retrained, never mixed.

The scene couples every microphone differently in every grasp (since scene version 3), so the
uncalibrated CNN is the control that shows what the live calibration buys in closed loop.

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

from aslip_ros import node_table
from aslip_ros.scene.layouts import DEFAULT_LAYOUT
from aslip_ros.util import write_json

OBJECTS = ("pla_rod", "glass_cleaner", "chips_can", "mustard_container", "cracker_box")
CNN_NAME = "aslip_cnn.pt"
UNCALIBRATED_NAME = "aslip_cnn_uncalibrated.pt"
SVM_NAME = "svm.pt"
STREAM_NAME = "aslip_stream.pt"
MANIFEST = "manifest.json"
COMMAND = "python -m benchmarks.demo --train-models"
#: Trials per object and condition (externally induced; ``gravity_pivot``: held off the
#: centre of mass, arm still), the share of twisting pushes, seconds per trial, export hop
#: (the recipe).
RECIPE = {"robot_moving": 12, "robot_stationary": 6, "gravity_pivot": 2,
          "twist_fraction": 0.3, "duration_s": 10.0, "hop_s": 0.05,
          "window_s": 0.2, "seed": 0, "time_budget_s": 480.0, "epochs": 40,
          "svm_max_train": 1500, "stream_epochs": 60, "stream_time_budget_s": 600.0}
#: The manifest's format. 4: the models estimate rotation (trained on twisting pushes and
#: gravity pivots); a set of an older format is retrained, whatever its scene version.
MANIFEST_VERSION = 4
#: The condition of the gravity-pivot trials (the arm holds still).
PIVOT_CONDITION = "robot_stationary"
#: Demo method -> (checkpoint file, ``aslip train`` stage, per-grasp calibration).
MODELS = {"aslip_stream": (STREAM_NAME, "stream", "background"),
          "aslip_window": (CNN_NAME, "scratch", "background"),
          "aslip_uncalibrated": (UNCALIBRATED_NAME, "scratch", "off"),
          "svm": (SVM_NAME, "svm", "background")}


#: The package's default estimator: the hybrid of the set's streaming model and window CNN
#: (learn/models/aslip_hybrid.py, its default ``HybridConfig``), the one model both
#: closed-loop launch files run (``node_table``). No model of its own to train: it is
#: assembled from its parts (``hybrid_checkpoint``).
DEFAULT = "aslip"
DEFAULT_NAME = node_table.DEFAULT_MODEL
#: Its parts, as demo methods: the streaming part and the window part.
DEFAULT_PARTS = ("aslip_stream", "aslip_window")


def hybrid_checkpoint(stream: str | Path, window: str | Path, out: str | Path) -> Path:
    """The hybrid of two checkpoints (the default ``HybridConfig``: ``aslip hybrid``),
    written to ``out`` (atomically) unless it is there already, assembled from the same two
    files (their sha256; where they lay does not matter)."""
    from aslip_ros.learn.models.aslip_hybrid import assembled_from, parts_sha256, write_hybrid
    if assembled_from(out) == parts_sha256(stream, window):
        return Path(out)
    return write_hybrid(stream, window, out)


def default_checkpoint(models_dir: str | Path, stream: str | Path, window: str | Path,
                       scratch: str | Path) -> Path:
    """The default estimator of these two parts: the shipped ``models_dir/aslip.pt`` where
    it was assembled from them, else one assembled now into ``scratch``."""
    from aslip_ros.learn.models.aslip_hybrid import assembled_from, parts_sha256
    shipped = Path(models_dir) / DEFAULT_NAME
    if assembled_from(shipped) == parts_sha256(stream, window):
        return shipped
    return hybrid_checkpoint(stream, window, Path(scratch) / DEFAULT_NAME)


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
    """The manifest when every model of :data:`MODELS` is listed, exists and was trained for
    the current scene with the current recipe (:data:`MANIFEST_VERSION`), else None (a
    stale or partial set is retrained, never mixed)."""
    d = Path(models_dir)
    try:
        man = json.loads((d / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(man, dict) or man.get("scene_version") != scene_version() \
            or man.get("version") != MANIFEST_VERSION:
        return None
    files = man.get("files")
    if not isinstance(files, dict) or any(
            not isinstance(files.get(m), str) or not (d / files[m]).is_file() for m in MODELS):
        return None
    return man


def aslip(argv: list[str]) -> int:
    """``aslip train|evaluate ARGS`` in this process: the command's own parser, defaults and
    exit codes."""
    from aslip_ros import cli
    return cli.main(argv)


def prepare_data(data_dir: str | Path = "data/demo", progress: bool = True) -> Path:
    """Simulate and export the training set of the current scene; returns the dataset dir.

    Bags are reused when present (simulate resumes), so each scene version gets its own
    folder: audio from an older scene must never reach a model for the new one. The same
    bags come from ``aslip simulate --kind external --twist-fraction 0.3`` (each condition)
    and ``aslip simulate --kind pivot --conditions robot_stationary``."""
    from aslip_ros.data.export import ExportConfig, export
    from aslip_ros.scene.simulate import simulate

    r = RECIPE
    data = Path(data_dir) / f"scene-{scene_version()}"
    bags, ds = data / "bags", data / "dataset"
    common = dict(objects=list(OBJECTS), duration_s=r["duration_s"], seed=r["seed"],
                  layout=DEFAULT_LAYOUT, progress=progress)
    for cond in ("robot_moving", "robot_stationary"):
        _log(f"simulating {r[cond]} x {len(OBJECTS)} externally induced trials, {cond}, "
             f"{r['twist_fraction']:.0%} of the slipping pushes twisting")
        simulate(bags, "external", conditions=[cond], trials=r[cond],
                 twist_fraction=r["twist_fraction"], **common)
    _log(f"simulating {r['gravity_pivot']} x {len(OBJECTS)} gravity-pivot trials, "
         f"{PIVOT_CONDITION}")
    simulate(bags, "pivot", conditions=[PIVOT_CONDITION], trials=r["gravity_pivot"], **common)
    _log("exporting")
    export([bags], ds, ExportConfig(window_s=r["window_s"], hop_s=r["hop_s"], overwrite=True,
                                    progress=progress))
    return ds


def _log(msg: str) -> None:
    print(f"[demo models {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def train_command(method: str, dataset: str | Path, out: str | Path,
                  threads: int = 2) -> list[str]:
    """``aslip train`` arguments of one demo model (:data:`MODELS`)."""
    r = RECIPE
    _, stage, calibration = MODELS[method]
    args = ["train", "--dataset", str(dataset), "--stage", stage, "--out", str(out),
            "--seed", str(r["seed"]), "--calibration", calibration]
    if stage == "svm":
        return args + ["--svm-max-train", str(r["svm_max_train"])]
    if stage == "stream":
        return args + ["--epochs", str(r["stream_epochs"]), "--time-budget",
                       str(r["stream_time_budget_s"]), "--threads", str(threads)]
    return args + ["--epochs", str(r["epochs"]), "--time-budget", str(r["time_budget_s"]),
                   "--threads", str(threads)]


def train_models(models_dir: str | Path = "models", data_dir: str | Path = "data/demo",
                 progress: bool = True, threads: int = 2) -> dict:
    """Simulate, export, train and evaluate; returns the manifest written to models_dir."""
    t0 = time.perf_counter()
    ds = prepare_data(data_dir, progress)
    out = Path(models_dir)
    out.mkdir(parents=True, exist_ok=True)
    quiet = [] if progress else ["--no-progress"]
    metrics, train_s = {}, {}
    for method, (name, stage, calibration) in MODELS.items():
        _log(f"training {method}: {stage}, calibration {calibration}")
        t1 = time.perf_counter()
        if aslip(train_command(method, ds, out / name, threads) + quiet) != 0:
            raise RuntimeError(f"training {method} failed")
        train_s[method] = round(time.perf_counter() - t1, 1)
        js = ds.parent / f"eval_{method}.json"
        _log(f"evaluating {method} on the test trials")
        if aslip(["evaluate", "--checkpoint", str(out / name), "--dataset", str(ds),
                  "--split", "test", "--json", str(js), "--threads", str(threads)]) != 0:
            raise RuntimeError(f"evaluating {method} failed")
        overall = json.loads(js.read_text())["overall"]
        metrics[method] = {k: overall.get(k) for k in
                           ("n_windows", "detection_accuracy", "precision", "recall",
                            "direction_mae_deg", "direction_std_deg", "magnitude_rmse_mm",
                            "magnitude_std_mm")}
        # The rotational figures, under whatever names the evaluation gives them.
        metrics[method].update({k: v for k, v in overall.items()
                                if "rotation" in k and isinstance(v, (int, float))})
    files = {m: v[0] for m, v in MODELS.items()}
    hybrid_checkpoint(*(out / files[m] for m in DEFAULT_PARTS), out / DEFAULT_NAME)
    stream, window = (files[m] for m in DEFAULT_PARTS)
    man = {"format": "aslip-demo-models", "version": MANIFEST_VERSION,
           "scene_version": scene_version(),
           "command": COMMAND, "recipe": dict(RECIPE), "objects": list(OBJECTS),
           "layout": DEFAULT_LAYOUT, "files": {**files, DEFAULT: DEFAULT_NAME},
           "calibration": {m: v[2] for m, v in MODELS.items()},
           "train_commands": {**{m: "aslip " + " ".join(train_command(m, "D", f"models/{f}"))
                                 for m, f in files.items()},
                              DEFAULT: f"aslip hybrid --stream models/{stream} --window "
                                       f"models/{window} --out models/{DEFAULT_NAME}"},
           "sizes_bytes": {f: (out / f).stat().st_size
                           for f in list(files.values()) + [DEFAULT_NAME]},
           "test_metrics": metrics, "train_s_per_model": train_s,
           "train_s": round(time.perf_counter() - t0, 1),
           "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    write_json(out / MANIFEST, man)
    _log(f"wrote {', '.join(man['files'].values())} and {MANIFEST} in {out}")
    return man
