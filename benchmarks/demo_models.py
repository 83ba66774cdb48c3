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
the pivot-stop task acts on (issue #21); export it, train the models, evaluate each on the
held-out test trials of its set and write ``models/aslip_stream.pt``, ``models/aslip_cnn.pt``,
``models/aslip_cnn_uncalibrated.pt``, ``models/svm.pt``, their hybrid ``models/aslip.pt``
and ``models/manifest.json`` (scene version, each model's recipe and command, metrics).

Two training sets (:data:`DATASETS`): the window models and the SVM learn on ``demo``; the
streaming part, which decides when a slip starts, on ``arm_drawn``: the same trials, but each
trial with the arm moving has its own arm loudness, drawn log-uniform in 0.5-4 times the
scene's (``aslip simulate --robot-noise-range``), and the gravity pivots are made with the
arm moving too. A streaming part that has heard a loud arm without slip stops as early and
hears more of the quiet turns (docs/results.md, "The arm drawn up to 4x").

A set is used only when every model in it was trained for the current scene version with its
current recipe (manifest version 5, ``model_recipes``); a model whose recipe changed is
retrained, and a model whose recipe did not is kept.

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
from aslip_ros.data.labels import DEFAULT_LABEL_SMOOTHING_S
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
#: centre of mass), the share of twisting pushes, seconds per trial, export hop, the export's
#: label smoothing (``aslip export --label-smoothing``: its default), the arm's loudness
#: range of the ``arm_drawn`` set, the training budgets and how many frames the streaming
#: part reads at once (``aslip train --stream-context``; docs/results.md) (the recipe).
RECIPE = {"robot_moving": 12, "robot_stationary": 6, "gravity_pivot": 2,
          "twist_fraction": 0.3, "duration_s": 10.0, "hop_s": 0.05,
          "window_s": 0.2, "label_smoothing_s": DEFAULT_LABEL_SMOOTHING_S, "seed": 0,
          "time_budget_s": 480.0, "epochs": 40,
          "svm_max_train": 1500, "stream_epochs": 60, "stream_time_budget_s": 1500.0,
          "stream_threads": 1, "stream_context": 5, "arm_noise_range": [0.5, 4.0]}
#: The manifest's format. 5: a training set and a recipe per model (``model_recipes``); a
#: set of an older format is retrained, whatever its scene version.
MANIFEST_VERSION = 5
#: The condition of the demo set's gravity-pivot trials (the arm holds still).
PIVOT_CONDITION = "robot_stationary"
#: The training sets: ``demo`` (the arm as loud as the scene's, pivots with the arm still)
#: and ``arm_drawn`` (each arm-moving trial's arm drawn in ``arm_noise_range``, pivots with
#: the arm moving and still).
DATASETS = ("demo", "arm_drawn")
#: The recipe items each set is made from.
DATA_KEYS = ("robot_moving", "robot_stationary", "gravity_pivot", "twist_fraction",
             "duration_s", "hop_s", "window_s", "label_smoothing_s", "seed")
#: Demo method -> (checkpoint file, ``aslip train`` stage, per-grasp calibration).
MODELS = {"aslip_stream": (STREAM_NAME, "stream", "background"),
          "aslip_window": (CNN_NAME, "scratch", "background"),
          "aslip_uncalibrated": (UNCALIBRATED_NAME, "scratch", "off"),
          "svm": (SVM_NAME, "svm", "background")}
#: Demo method -> the training set it learns on.
MODEL_DATA = {"aslip_stream": "arm_drawn", "aslip_window": "demo",
              "aslip_uncalibrated": "demo", "svm": "demo"}


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


def data_recipe(name: str) -> dict:
    """What the training set ``name`` (:data:`DATASETS`) is made from, as the manifest keeps
    it."""
    if name not in DATASETS:
        raise ValueError(f"unknown training set {name!r}: one of {', '.join(DATASETS)}")
    got = {k: RECIPE[k] for k in DATA_KEYS}
    if name == "arm_drawn":
        got["arm_noise_range"] = list(RECIPE["arm_noise_range"])
    return got


def model_recipe(method: str) -> dict:
    """One model's recipe: its training set, what that is made from, and its ``aslip train``
    command (the manifest's ``model_recipes``; a model is kept while it is unchanged)."""
    name = MODEL_DATA[method]
    return {"data": name, "data_recipe": data_recipe(name),
            "command": train_command(method, name, f"models/{MODELS[method][0]}")}


def _read_manifest(models_dir: Path) -> dict | None:
    try:
        man = json.loads((models_dir / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return man if isinstance(man, dict) else None


def _current(man: dict | None, models_dir: Path) -> list[str]:
    """The models of :data:`MODELS` that this manifest lists, that are there and that were
    trained for the current scene with their current recipe."""
    if man is None or man.get("scene_version") != scene_version() \
            or man.get("version") != MANIFEST_VERSION:
        return []
    files, recipes = man.get("files"), man.get("model_recipes")
    if not isinstance(files, dict) or not isinstance(recipes, dict):
        return []
    return [m for m in MODELS if isinstance(files.get(m), str)
            and (models_dir / files[m]).is_file() and recipes.get(m) == model_recipe(m)]


def shipped_models(models_dir: str | Path) -> dict | None:
    """The manifest when every model of :data:`MODELS` is listed, exists and was trained for
    the current scene with its current recipe (:data:`MANIFEST_VERSION`,
    :func:`model_recipe`), else None (a stale or partial set is not run)."""
    d = Path(models_dir)
    man = _read_manifest(d)
    return man if len(_current(man, d)) == len(MODELS) else None


def aslip(argv: list[str]) -> int:
    """``aslip train|evaluate ARGS`` in this process: the command's own parser, defaults and
    exit codes."""
    from aslip_ros import cli
    return cli.main(argv)


def _simulate_demo(bags: Path, common: dict) -> list[Path]:
    from aslip_ros.scene.simulate import simulate
    r = RECIPE
    for cond in ("robot_moving", "robot_stationary"):
        _log(f"simulating {r[cond]} x {len(OBJECTS)} externally induced trials, {cond}, "
             f"{r['twist_fraction']:.0%} of the slipping pushes twisting")
        simulate(bags, "external", conditions=[cond], trials=r[cond],
                 twist_fraction=r["twist_fraction"], **common)
    _log(f"simulating {r['gravity_pivot']} x {len(OBJECTS)} gravity-pivot trials, "
         f"{PIVOT_CONDITION}")
    simulate(bags, "pivot", conditions=[PIVOT_CONDITION], trials=r["gravity_pivot"], **common)
    return [bags]


def simulate_arm_drawn(root: Path, common: dict, factor: int = 1) -> list[Path]:
    """``factor`` times the demo set's trials with the arm still, and its arm-moving trials
    plus arm-moving gravity pivots with each trial's arm drawn in ``arm_noise_range`` (a
    folder each); with another seed in ``common``, a fresh draw of the set
    (``benchmarks.stream_false_alarms``)."""
    from aslip_ros.scene.simulate import simulate
    r = {**RECIPE, **{c: RECIPE[c] * int(factor)
                      for c in ("robot_moving", "robot_stationary", "gravity_pivot")}}
    lo, hi = r["arm_noise_range"]
    moving, still = root / "bags_moving", root / "bags_still"
    _log(f"simulating the arm-moving trials with the arm {lo:g}-{hi:g} times as loud")
    simulate(moving, "external", conditions=["robot_moving"], trials=r["robot_moving"],
             twist_fraction=r["twist_fraction"], robot_noise_range=(lo, hi), **common)
    simulate(moving, "pivot", conditions=["robot_moving"], trials=r["gravity_pivot"],
             robot_noise_range=(lo, hi), **common)
    _log("simulating the trials with the arm still")
    simulate(still, "external", conditions=["robot_stationary"], trials=r["robot_stationary"],
             twist_fraction=r["twist_fraction"], **common)
    simulate(still, "pivot", conditions=["robot_stationary"], trials=r["gravity_pivot"],
             **common)
    return [moving, still]


def prepare_data(data_dir: str | Path = "data/demo", progress: bool = True,
                 sets: tuple[str, ...] = DATASETS) -> dict[str, Path]:
    """Simulate and export the training sets of the current scene; returns each one's
    dataset dir.

    Bags are reused when present (simulate resumes), so each scene version gets its own
    folder: audio from an older scene must never reach a model for the new one. The ``demo``
    bags come from ``aslip simulate --kind external --twist-fraction 0.3`` (each condition)
    and ``aslip simulate --kind pivot --conditions robot_stationary``; ``arm_drawn`` adds
    ``--robot-noise-range 0.5,4`` to its arm-moving trials."""
    from aslip_ros.data.export import ExportConfig, export

    r = RECIPE
    data = Path(data_dir) / f"scene-{scene_version()}"
    common = dict(objects=list(OBJECTS), duration_s=r["duration_s"], seed=r["seed"],
                  layout=DEFAULT_LAYOUT, progress=progress)
    out = {}
    for name in sets:
        root = data if name == "demo" else data / name
        bags = _simulate_demo(root / "bags", common) if name == "demo" \
            else simulate_arm_drawn(root, common)
        _log(f"exporting the {name} set")
        export(bags, root / "dataset",
               ExportConfig(window_s=r["window_s"], hop_s=r["hop_s"],
                            label_smoothing_s=r["label_smoothing_s"], overwrite=True,
                            progress=progress))
        out[name] = root / "dataset"
    return out


def _log(msg: str) -> None:
    print(f"[demo models {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def train_command(method: str, dataset: str | Path, out: str | Path,
                  threads: int = 2) -> list[str]:
    """``aslip train`` arguments of one demo model (:data:`MODELS`); the streaming part
    trains on the recipe's ``stream_threads``, whatever ``threads`` says."""
    r = RECIPE
    _, stage, calibration = MODELS[method]
    args = ["train", "--dataset", str(dataset), "--stage", stage, "--out", str(out),
            "--seed", str(r["seed"]), "--calibration", calibration]
    if stage == "svm":
        return args + ["--svm-max-train", str(r["svm_max_train"])]
    if stage == "stream":
        return args + ["--epochs", str(r["stream_epochs"]), "--time-budget",
                       str(r["stream_time_budget_s"]), "--threads", str(r["stream_threads"]),
                       "--stream-context", str(r["stream_context"])]
    return args + ["--epochs", str(r["epochs"]), "--time-budget", str(r["time_budget_s"]),
                   "--threads", str(threads)]


def _train_and_evaluate(method: str, ds: Path, out: Path, quiet: list[str],
                        threads: int) -> dict:
    name = MODELS[method][0]
    _log(f"training {method} on the {MODEL_DATA[method]} set: {' '.join(MODELS[method][1:])}")
    if aslip(train_command(method, ds, out / name, threads) + quiet) != 0:
        raise RuntimeError(f"training {method} failed")
    js = ds.parent / f"eval_{method}.json"
    _log(f"evaluating {method} on the test trials of its set")
    if aslip(["evaluate", "--checkpoint", str(out / name), "--dataset", str(ds),
              "--split", "test", "--json", str(js), "--threads", str(threads)]) != 0:
        raise RuntimeError(f"evaluating {method} failed")
    overall = json.loads(js.read_text())["overall"]
    got = {k: overall.get(k) for k in
           ("n_windows", "detection_accuracy", "precision", "recall", "direction_mae_deg",
            "direction_std_deg", "magnitude_rmse_mm", "magnitude_std_mm")}
    # The rotational figures, under whatever names the evaluation gives them.
    got.update({k: v for k, v in overall.items()
                if "rotation" in k and isinstance(v, (int, float))})
    return {**got, "test_set": MODEL_DATA[method]}


def train_models(models_dir: str | Path = "models", data_dir: str | Path = "data/demo",
                 progress: bool = True, threads: int = 2) -> dict:
    """Simulate, export, train and evaluate the models whose recipe changed (every model of
    a stale set), keep the others; returns the manifest written to models_dir."""
    t0 = time.perf_counter()
    out = Path(models_dir)
    old = _read_manifest(out)
    kept = _current(old, out)
    todo = [m for m in MODELS if m not in kept]
    if kept:
        _log(f"keeping {', '.join(kept)}: trained for this scene with their current recipe")
    sets = prepare_data(data_dir, progress, tuple(dict.fromkeys(MODEL_DATA[m] for m in todo)))
    out.mkdir(parents=True, exist_ok=True)
    quiet = [] if progress else ["--no-progress"]
    # A kept model's figures come from the manifest it was listed in (None where it has none).
    metrics = {m: (old.get("test_metrics") or {}).get(m) for m in kept}
    train_s = {m: (old.get("train_s_per_model") or {}).get(m) for m in kept}
    for method in todo:
        t1 = time.perf_counter()
        metrics[method] = _train_and_evaluate(method, sets[MODEL_DATA[method]], out, quiet,
                                              threads)
        train_s[method] = round(time.perf_counter() - t1, 1)
    files = {m: v[0] for m, v in MODELS.items()}
    hybrid_checkpoint(*(out / files[m] for m in DEFAULT_PARTS), out / DEFAULT_NAME)
    stream, window = (files[m] for m in DEFAULT_PARTS)
    recipes = {m: model_recipe(m) for m in MODELS}
    man = {"format": "aslip-demo-models", "version": MANIFEST_VERSION,
           "scene_version": scene_version(),
           "command": COMMAND, "recipe": dict(RECIPE), "objects": list(OBJECTS),
           "layout": DEFAULT_LAYOUT, "files": {**files, DEFAULT: DEFAULT_NAME},
           "calibration": {m: v[2] for m, v in MODELS.items()},
           "model_recipes": recipes,
           "train_commands": {**{m: "aslip " + " ".join(r["command"])
                                 for m, r in recipes.items()},
                              DEFAULT: f"aslip hybrid --stream models/{stream} --window "
                                       f"models/{window} --out models/{DEFAULT_NAME}"},
           "sizes_bytes": {f: (out / f).stat().st_size
                           for f in list(files.values()) + [DEFAULT_NAME]},
           "test_metrics": metrics, "train_s_per_model": train_s,
           "retrained": todo, "train_s": round(time.perf_counter() - t0, 1),
           "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    write_json(out / MANIFEST, man)
    _log(f"wrote {', '.join(man['files'].values())} and {MANIFEST} in {out}")
    return man
