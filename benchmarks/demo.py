"""The paper's closed-loop tasks (Table III) in the scene: ``make demo``
(``python -m benchmarks.demo``).

Both tasks run through the real nodes and topics: ``scene_sim`` audio -> ``slip_inference``
-> ``slip_stop`` / ``slip_track`` -> ``/aslip/arm/cmd_vel`` -> the scene's simulated arm.

- slip-stop: the grasped object starts against a wall; the arm retracts 10 cm,
  re-approaches and must stop on slip. Success: the object touched the wall and the arm
  stopped before pushing past the object's length; error: travel past the wall contact.
- slip-track: an agent drags the object in the grasp; the arm follows the predicted slip.
  Metric: RMSE of the gripper-object relative position in the grasp plane.
- pivot-stop (issue #21): the object, held by one end, is lowered onto a surface that meets
  it off the grasp axis, so it turns between the pads; slip-stop must stop on the rotation.
  Metric: the angle turned before the arm is at rest [deg], for the package's estimator
  with an arm that acts on rotation and one that ignores it (same seeds, paired).

Five objects x ``--trials`` trials per task and method: the package's estimator (``aslip``:
the causal streaming model with the live per-grasp calibration, an estimate per 10 ms hop),
the 200 ms window CNN with that calibration (``aslip_window``) and without it
(``aslip_uncalibrated``), and the SVM baseline (calibrated); the scene couples every
microphone differently in every grasp (since scene version 3). A pool of worker processes
each runs many episodes in sequence (:mod:`benchmarks.demo_episode`: fresh context and
domain per episode, the node classes composed in the worker).

``--mode lockstep`` (default): each episode runs on simulated time, the scene stepping a
block once the graph has handled the one before and the compute time charged to simulated
time (``--charge budget``: each node's declared budget; ``measured``: this host's), so the
table is the same on a fast or a slow, idle or busy machine; one worker per CPU.
``--mode realtime``: the scene paces itself by the wall clock, as on a cell; the number of
workers comes from ``aslip check realtime``'s measurement of this machine, and a machine
too slow for even one real-time episode is said so instead of reporting its failures.

Results: ``<out>/summary.json``, ``<out>/table.md`` (beside the paper's numbers),
``<out>/*.png`` and per-episode traces in ``<out>/episodes/``.

Models: the shipped checkpoints (``models/aslip_stream.pt``, ``models/aslip_cnn.pt``,
``models/aslip_cnn_uncalibrated.pt``, ``models/svm.pt``) when they match the scene
(``models/manifest.json``), otherwise they are retrained first (``--train-models`` forces it;
:mod:`benchmarks.demo_models`). ``aslip``, the package's default estimator, is the hybrid
of the streaming model and the window CNN (learn/models/aslip_hybrid.py): the shipped
``models/aslip.pt`` where it was assembled from the two checkpoints in use, else their
hybrid assembled into ``--train-data`` (``demo_models.default_checkpoint``), unless
``--aslip`` names one.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import platform
import sys
import time
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Optional

import numpy as np

from aslip_ros.util import write_json, write_text
from benchmarks import demo_metrics as dm
from benchmarks.demo_episode import (CHARGES, LOCKSTEP_BUDGET_S, MODES, TASKS, Episode,
                                     PivotSettings, StopSettings, TrackSettings, save_trace)
from benchmarks import demo_models
from benchmarks.demo_models import OBJECTS

METHODS = (demo_models.DEFAULT,) + tuple(demo_models.MODELS)
#: What ``make demo`` runs: the package's estimator first, then its two parts and the two it
#: is measured by.
DEFAULT_METHODS = METHODS
#: Repeats of a trial that a watchdog ended on stale input (a stalled machine).
MAX_RERUNS = 2
#: Seeds are disjoint from the training set's (simulate derives those from seed 0).
SEED_BASE = {"slip_stop": 1000, "slip_track": 2000, "pivot_stop": 3000}


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``python -m benchmarks.demo``."""
    p.add_argument("--out", default="results/demo", help="output directory")
    p.add_argument("--models", default="models", help="directory of the shipped checkpoints")
    p.add_argument("--train-models", action="store_true",
                   help="(re)train the demo checkpoints into --models and exit")
    p.add_argument("--train-data", default="data/demo", help="scratch data for --train-models")
    p.add_argument("--stream", default=None,
                   help="aslip_stream: the streaming checkpoint (default: --models)")
    p.add_argument("--cnn", default=None,
                   help="aslip_window: window CNN checkpoint (default: --models)")
    p.add_argument("--cnn-uncalibrated", default=None,
                   help="window CNN checkpoint without calibration (default: --models)")
    p.add_argument("--svm", default=None, help="SVM checkpoint (default: --models)")
    p.add_argument("--aslip", default=None,
                   help="aslip: the default (hybrid) checkpoint (default: --models' "
                        "aslip.pt where it was assembled from the aslip_stream and "
                        "aslip_window checkpoints, else their hybrid assembled into "
                        "--train-data)")
    p.add_argument("--tasks", default=",".join(TASKS), help="comma-separated tasks")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help=f"comma-separated methods out of {','.join(METHODS)}")
    p.add_argument("--objects", default=",".join(OBJECTS), help="comma-separated objects")
    p.add_argument("--trials", type=int, default=10, help="trials per task, method, object")
    p.add_argument("--mode", choices=MODES, default=MODES[0],
                   help="lockstep: simulated time, the same table on any host; realtime: "
                        "the wall clock, to measure this machine")
    p.add_argument("--charge", choices=CHARGES, default=CHARGES[0],
                   help="lockstep: compute time charged per block, the nodes' declared "
                        "budgets or what this host measures")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: one per CPU in lockstep; in realtime "
                        "what `aslip check realtime` finds this machine can carry)")
    p.add_argument("--approach-speed", type=float, default=StopSettings.approach_speed_m_s,
                   help="slip-stop re-approach speed [m/s]")
    p.add_argument("--retract-speed", type=float, default=StopSettings.retract_speed_m_s,
                   help="slip-stop retract speed [m/s]")
    p.add_argument("--track-duration", type=float, default=TrackSettings.duration_s,
                   help="slip-track drag duration [s]")
    p.add_argument("--gain", type=float, default=TrackSettings.gain, help="slip-track gain")
    p.add_argument("--track-set", action="append", default=[], metavar="NAME=VALUE",
                   help="any other slip-track setting (a TrackSettings field, e.g. "
                        "velocity_window_s=0.1 or agent_hold_s=0); repeatable")
    p.add_argument("--stop-set", action="append", default=[], metavar="NAME=VALUE",
                   help="any other slip-stop setting (a StopSettings field, e.g. "
                        "debounce_count=2); repeatable")
    p.add_argument("--pivot-methods", default="",
                   help="pivot-stop: comma-separated estimators (default: the first of "
                        "--methods); each runs both arms, acting on rotation and ignoring it")
    p.add_argument("--pivot-arms", default=",".join(dm.PIVOT_ARMS),
                   help=f"pivot-stop arms out of {','.join(dm.PIVOT_ARMS)}")
    p.add_argument("--pivot-set", action="append", default=[], metavar="NAME=VALUE",
                   help="any pivot-stop setting (a PivotSettings field, e.g. "
                        "pivot_lever_m=0.08); repeatable")
    p.add_argument("--hogs", type=int, default=0,
                   help="run beside this many CPU-busy processes (a machine at about half "
                        "speed on 2 cores), as make latency's --hogs")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


# --- worker side ---------------------------------------------------------------------------

def worker_log(log_dir: str | Path) -> Path:
    """This process's log file in ``log_dir``."""
    return Path(log_dir) / f"worker-{os.getpid()}.log"


def redirect_output(path: Path) -> None:
    """Send this process's stdout and stderr, C stdio included (rcutils logs through it),
    to ``path``: the nodes' log lines would otherwise break the parent's progress bar."""
    sys.stdout.flush()
    sys.stderr.flush()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)


def _worker_init(checkpoints: list, log_dir: str) -> None:
    """Per worker: output to its log file, quiet, single-threaded numerics, localhost
    discovery, warm models."""
    redirect_output(worker_log(log_dir))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ASLIP_DEMO_EXECUTOR", "events")
    os.environ["RCUTILS_LOGGING_SEVERITY_THRESHOLD"] = os.environ.get(
        "ASLIP_DEMO_LOG_LEVEL", "WARN")
    import torch
    torch.set_num_threads(1)
    from benchmarks.demo_episode import warm_up
    for ck in checkpoints:
        warm_up(ck)


def _worker_run(args: tuple) -> dict:
    ep, trace_dir = args
    from benchmarks.demo_episode import run_episode
    reruns = []
    for _ in range(1 + MAX_RERUNS):
        try:
            res = run_episode(ep)
        except Exception as exc:  # noqa: BLE001 - one broken episode must not end the demo
            return {"task": ep.task, "method": ep.method, "object": ep.object,
                    "trial": ep.trial, "seed": ep.seed,
                    "error": f"{type(exc).__name__}: {exc}"}
        why = str(res.get("controller_reason") or "")
        if not why.startswith("stale"):
            break
        # A watchdog stop on stale input says the shared machine stalled the pipeline
        # (a scheduling hiccup, not the method): the trial is repeated, as a rig fault
        # would be on hardware, and the repeat is recorded.
        reruns.append(why)
    res["reruns"] = reruns
    save_trace(Path(trace_dir) / f"{ep.key}.npz", res)
    res.pop("trace", None)
    return res


# --- planning -------------------------------------------------------------------------------

def settings_overrides(cls, items: list[str]) -> dict:
    """``NAME=VALUE`` strings as fields of the settings class ``cls`` (StopSettings,
    TrackSettings), each converted to the field's type."""
    kinds = {f.name: type(getattr(cls(), f.name)) for f in fields(cls)}
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in kinds:
            raise ValueError(f"{item!r} is not NAME=VALUE with NAME one of {sorted(kinds)}")
        out[name] = kinds[name](value) if kinds[name] is not bool else value == "true"
    return out


def plan_episodes(tasks, methods, objects, trials: int, checkpoints: dict,
                  stop: StopSettings, track: TrackSettings,
                  pivot: PivotSettings = PivotSettings(), pivot_methods=None,
                  arms=dm.PIVOT_ARMS, mode: str = MODES[0],
                  charge: str = CHARGES[0]) -> list[Episode]:
    """Every (task, method, object, trial); every method sees the same seeds. Pivot-stop
    runs ``pivot_methods`` (default: the first method) with each of ``arms`` on the same
    seeds, so its arms are paired trial by trial."""
    pivot_methods = list(pivot_methods or methods[:1])
    eps = []
    for trial in range(trials):
        for task in tasks:
            for obj in objects:
                seed = SEED_BASE[task] + 100 * OBJECTS.index(obj) + trial
                runs = [(m, a) for m in pivot_methods for a in arms] \
                    if task == "pivot_stop" else [(m, dm.PIVOT_ARMS[0]) for m in methods]
                for method, arm in runs:
                    eps.append(Episode(task, method, str(checkpoints[method]), obj, trial,
                                       seed, stop=stop, track=track, pivot=pivot, arm=arm,
                                       mode=mode, charge=charge))
    return eps


def resolve_models(args, methods=tuple(demo_models.MODELS)) -> dict:
    """Checkpoint per method: explicit, shipped and matching, or freshly trained."""
    d = Path(args.models)
    explicit = {"aslip_stream": args.stream, "aslip_window": args.cnn,
                "aslip_uncalibrated": args.cnn_uncalibrated, "svm": args.svm}
    need = [m for m in methods if m in explicit]
    default = demo_models.DEFAULT
    if default in methods and not args.aslip:        # assembled from its parts
        need += [m for m in demo_models.DEFAULT_PARTS if m not in need]
    if all(explicit[m] for m in need):
        out = {**{m: Path(p) for m, p in explicit.items() if p}, "source": "command line"}
    else:
        man = demo_models.shipped_models(d)
        if man is None:
            print(f"[demo] checkpoints in {d} missing or not of this scene version "
                  f"({demo_models.scene_version()}) and recipe: training those (up to 20 "
                  f"minutes on 2 cores)", file=sys.stderr, flush=True)
            man = demo_models.train_models(d, args.train_data, progress=not args.no_progress)
            source = "trained now"
        else:
            source = f"shipped ({d / demo_models.MANIFEST})"
        out = {**{m: Path(p or d / man["files"][m]) for m, p in explicit.items()},
               "source": source, "test_metrics": man.get("test_metrics")}
    if default in methods:
        out[default] = Path(args.aslip) if args.aslip else demo_models.default_checkpoint(
            d, *(out[m] for m in demo_models.DEFAULT_PARTS), args.train_data)
    return out


def run_episodes(episodes: list[Episode], workers: int, trace_dir: Path,
                 progress: bool = True) -> list[dict]:
    """Run the episodes on a spawn pool of ``workers`` processes; results in plan order."""
    from tqdm import tqdm
    trace_dir.mkdir(parents=True, exist_ok=True)
    checkpoints = sorted({ep.checkpoint for ep in episodes})
    ctx = mp.get_context("spawn")
    results: list[Optional[dict]] = [None] * len(episodes)
    jobs = [(ep, str(trace_dir)) for ep in episodes]
    log_dir = trace_dir / "logs"
    log_dir.mkdir(exist_ok=True)
    with ctx.Pool(max(1, workers), initializer=_worker_init,
                  initargs=(checkpoints, str(log_dir)), maxtasksperchild=None) as pool, \
            tqdm(total=len(jobs), desc="demo episodes", unit="ep", disable=not progress,
                 file=sys.stderr) as bar:
        it = pool.imap(_worker_run, jobs, chunksize=1)
        for i, res in enumerate(it):
            results[i] = res
            bar.update(1)
            bar.set_postfix_str(_postfix(res))
    lines = sum(len(p.read_text(errors="replace").splitlines())
                for p in log_dir.glob("worker-*.log"))
    if lines:
        print(f"[demo] the nodes logged {lines} lines: "
              f"{log_dir}/worker-*.log", file=sys.stderr, flush=True)
    return [r for r in results if r is not None]


def _postfix(r: dict) -> str:
    if "error" in r:
        return f"{r['task']} {r['method']} ERROR"
    if r["task"] == "pivot_stop":
        a = r.get("angle_deg")
        return (f"pivot {r['method']} {r.get('arm', '')} {r['object']} "
                f"{r.get('controller_reason')} {'n/a' if a is None else f'{a:.1f} deg'}")
    if r["task"] == "slip_stop":
        e = r.get("stopping_error_m")
        return (f"stop {r['method']} {r['object']} {'ok' if r.get('success') else 'FAIL'} "
                f"{'n/a' if e is None else f'{e * 1e3:.1f} mm'}")
    return f"track {r['method']} {r['object']} {r['pose_rmse_m'] * 1e3:.1f} mm"


# --- outputs --------------------------------------------------------------------------------

def write_outputs(out: Path, results: list[dict], meta: dict, plots: bool = True) -> dict:
    """summary.json, table.md and the plots, each written atomically."""
    ok = [r for r in results if "error" not in r]
    summary = {"format": "aslip-demo-summary", "version": 1, "meta": meta,
               "units": "mm", "paper_table3": dm.PAPER_TABLE3,
               "table": dm.summarize(ok), "episodes": results,
               "errors": [r for r in results if "error" in r]}
    table = tables_md(summary["table"], ok)
    head = (f"# Table III in the scene ({meta['command']})\n\n"
            f"Slip-stop cells: successes/trials, |Delta x| mean ± std [mm] over all trials "
            f"(failures included); slip-track: pose RMSE mean ± std [mm]. A trial that was "
            f"run again after a watchdog stop on stale input counts as a failure "
            f"(`reruns` in summary.json). Paper columns from the A-SLIP paper, Table III "
            f"(real hardware). Pivot-stop (issue #21, no paper column): the angle the "
            f"object turned before the arm came to rest [deg], over all trials, with the "
            f"95 % bootstrap interval of the mean.\n\n{mode_sentence(meta)}\n\n")
    write_json(out / "summary.json", summary)
    write_text(out / "table.md", head + table + _notes(summary))
    if plots:
        from benchmarks.demo_plots import make_plots
        summary["plots"] = make_plots(out, ok)
    return summary


def mode_sentence(meta: dict) -> str:
    """How the run was timed, in one sentence for the table's head."""
    if meta.get("mode", "realtime") == "realtime":
        return ("Mode: real time (the scene paced by the wall clock): the figures measure "
                "this machine as well as the methods.")
    budget = meta.get("lockstep_budget_s") or {}
    charge = ("each node's declared compute budget per block ("
              + ", ".join(f"{k} {v * 1e3:g} ms" for k, v in budget.items()) + ")"
              if meta.get("charge") == "budget" else "the compute time this host measured")
    return ("Mode: lockstep on simulated time (the scene steps a block once the graph has "
            f"handled the one before; {charge} charged to simulated time): the same table "
            "on any host, idle or busy.")


def tables_md(table: dict, ok: list[dict]) -> str:
    """Every markdown table of a run: Table III, the methods, pivot-stop, the calibration
    and the tail."""
    return dm.format_table(table) + dm.methods_table(table) + dm.pivot_table(table) \
        + dm.calibration_table(ok) + dm.tail_table(ok)


def _notes(summary: dict) -> str:
    m = summary["meta"]
    beside = f", beside {m['hogs']} CPU hogs" if m.get("hogs") else ""
    lines = ["", f"Wall time {m.get('wall_s', float('nan')):.0f} s with {m['workers']} "
             f"workers on {m['cpus']} CPUs{beside} (load average at the start "
             f"{m.get('load_start', 'n/a')}, at the end {m.get('load_end', 'n/a')}).",
             f"Episodes that fell behind real time (scene blocks skipped): "
             f"{m.get('episodes_behind', 0)}; trials repeated after a watchdog stop on "
             f"stale input: {m.get('reruns', 0)}."]
    reruns = [f"{task} {method}: {cells['overall']['reruns']} reruns in "
              f"{cells['overall']['trials_rerun']} trials"
              for task, methods in summary["table"].items()
              for method, cells in methods.items() if cells["overall"].get("reruns")]
    if reruns:
        lines.append("Reruns after a watchdog stop on stale input (per method and object in "
                     "summary.json, `reruns`): " + "; ".join(reruns) + ".")
    if summary["errors"]:
        lines.append(f"Episodes that raised errors: {len(summary['errors'])}.")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    """Entry point of ``python -m benchmarks.demo``."""
    t0 = time.perf_counter()
    if args.train_models:
        man = demo_models.train_models(args.models, args.train_data,
                                       progress=not args.no_progress)
        print(json.dumps(man["test_metrics"], indent=2))
        return 0
    tasks = [t for t in args.tasks.split(",") if t]
    methods = [m for m in args.methods.split(",") if m]
    objects = [o for o in args.objects.split(",") if o]
    pivot_methods = [m for m in args.pivot_methods.split(",") if m] or methods[:1]
    arms = [a for a in args.pivot_arms.split(",") if a]
    bad = [t for t in tasks if t not in TASKS] + [m for m in methods + pivot_methods
                                                  if m not in METHODS] + \
        [o for o in objects if o not in OBJECTS] + [a for a in arms if a not in dm.PIVOT_ARMS]
    if bad or args.trials < 1:
        print(f"benchmarks.demo: unknown task/method/object/arm {bad} or --trials < 1",
              file=sys.stderr)
        return 2
    # The methods whose checkpoints the run needs: pivot-stop runs only its own.
    used = list(methods) if set(tasks) - {"pivot_stop"} else []
    if "pivot_stop" in tasks:
        used += [m for m in pivot_methods if m not in used]
    models = resolve_models(args, used)
    missing = [m for m in used if m not in models or not Path(models[m]).is_file()]
    if missing:
        print(f"benchmarks.demo: no checkpoint for {missing}: "
              f"{[str(models.get(m)) for m in missing]}",
              file=sys.stderr)
        return 1
    try:
        stop = replace(StopSettings(), approach_speed_m_s=args.approach_speed,
                       retract_speed_m_s=args.retract_speed,
                       **settings_overrides(StopSettings, args.stop_set))
        track = replace(TrackSettings(), duration_s=args.track_duration, gain=args.gain,
                        **settings_overrides(TrackSettings, args.track_set))
        pivot = replace(PivotSettings(), **settings_overrides(PivotSettings, args.pivot_set))
    except (TypeError, ValueError) as exc:
        print(f"benchmarks.demo: --stop-set/--track-set/--pivot-set: {exc}", file=sys.stderr)
        return 2
    eps = plan_episodes(tasks, methods, objects, args.trials, models, stop, track, pivot,
                        pivot_methods, arms, args.mode, args.charge)
    out = Path(args.out)
    from aslip_ros.util import cpu_hogs
    with cpu_hogs(args.hogs):
        return _run_planned(args, t0, eps, models, used, out, asked_meta(
            tasks, methods, objects, stop, track, pivot, pivot_methods, arms))


def asked_meta(tasks, methods, objects, stop, track, pivot, pivot_methods, arms) -> dict:
    """What the run was asked, for ``summary.json``'s ``meta``."""
    return {"tasks": tasks, "methods": methods, "objects": objects,
            "stop_settings": asdict(stop), "track_settings": asdict(track),
            "pivot_settings": asdict(pivot), "pivot_methods": pivot_methods,
            "pivot_arms": arms}


def _run_planned(args, t0: float, eps: list, models: dict, used: list, out: Path,
                 asked: dict) -> int:
    """Choose the workers, run the episodes, write the outputs."""
    load0 = _load()
    workers, headroom = choose_workers(args, [str(models[m]) for m in used])
    if workers < 1:
        print(f"[demo] {headroom['why']}: no real-time table from this machine. The default "
              "--mode lockstep gives the table on any host.", file=sys.stderr, flush=True)
        return 1
    mode = f"{args.mode} ({args.charge} charge)" if args.mode == "lockstep" else args.mode
    print(f"[demo] {len(eps)} {mode} episodes on {workers} workers; models: "
          f"{models['source']}", file=sys.stderr, flush=True)
    t_run = time.perf_counter()
    results = run_episodes(eps, workers, out / "episodes", not args.no_progress)
    meta = {"command": command_line(), **asked, "hogs": args.hogs, "mode": args.mode,
            "charge": args.charge if args.mode == "lockstep" else None,
            "lockstep_budget_s": LOCKSTEP_BUDGET_S if args.mode == "lockstep" else None,
            "headroom": headroom,
            "trials": args.trials, "workers": workers, "cpus": os.cpu_count(),
            "checkpoints": {m: str(models[m]) for m in used},
            "models_source": models["source"], "model_test_metrics": models.get("test_metrics"),
            "scene_version": demo_models.scene_version(), "host": platform.node(),
            "episodes_s": round(time.perf_counter() - t_run, 1),
            "wall_s": round(time.perf_counter() - t0, 1), "load_start": load0,
            "load_end": _load(),
            "episodes_behind": sum(1 for r in results if r.get("skipped_blocks", 0) > 0),
            "reruns": sum(len(r.get("reruns", [])) for r in results)}
    summary = write_outputs(out, results, meta, plots=not args.no_plots)
    print(tables_md(summary["table"], [r for r in results if "error" not in r]))
    print(f"results: {out / 'summary.json'}, {out / 'table.md'}")
    if summary.get("plots"):
        print("plots: " + ", ".join(str(p) for p in summary["plots"]))
    print(f"wall time {time.perf_counter() - t0:.0f} s")
    return 0 if not summary["errors"] else 1


def choose_workers(args, checkpoints: list[str]) -> tuple[int, Optional[dict]]:
    """Worker processes: ``--workers`` when given; in lockstep one per CPU (a busy worker
    only slows the run, never changes it); in real time what this machine carries (0: too
    slow), with the measurement: ``aslip check realtime``'s per-hop figures of each model,
    and what a whole episode's graph costs here beyond them (the middleware and the nodes'
    Python: one short lockstep episode per model, CPU seconds per scene second)."""
    if args.workers is not None:
        return max(1, args.workers), None
    if args.mode == "lockstep":
        return max(1, os.cpu_count() or 1), None
    from aslip_ros.bringup import realtime
    reports = [realtime.measure(ck) for ck in checkpoints]
    episode = {ck: episode_cores(ck) for ck in checkpoints}
    extra = max(episode[r.checkpoint] - r.worker_cores for r in reports)
    middleware = round(max(0.0, extra), 2)
    n = realtime.demo_workers(reports, middleware_cores=middleware)
    doc = {"workers": n, "reports": [r.to_dict() for r in reports],
           "episode_cores": episode, "middleware_cores": middleware,
           "why": realtime.workers_line(n, reports, middleware_cores=middleware)}
    for r in reports:
        print(f"[demo] headroom: {r.text()}", file=sys.stderr, flush=True)
    print(f"[demo] headroom: {doc['why']}", file=sys.stderr, flush=True)
    return n, doc


def episode_cores(checkpoint: str) -> float:
    """CPU cores one real-time episode of ``checkpoint`` needs on this machine: a short
    lockstep slip-track episode (which runs as fast as the CPU allows) in this process, its
    CPU seconds per second of scene time."""
    from benchmarks.demo_episode import run_episode, warm_up
    warm_up(checkpoint)
    ep = Episode("slip_track", "headroom", checkpoint, OBJECTS[0], 0, SEED_BASE["slip_track"],
                 track=TrackSettings(duration_s=1.0))
    cpu0 = time.process_time()
    r = run_episode(ep, keep_trace=False)
    return (time.process_time() - cpu0) / max(r["scene_s"], 1e-3)


def command_line(module: str = "demo") -> str:
    """``python -m benchmarks.<module>`` with this run's options when it was started so."""
    started_here = Path(sys.argv[0]).resolve() == Path(__file__).with_name(f"{module}.py") \
        .resolve()
    return " ".join([f"python -m benchmarks.{module}", *(sys.argv[1:] if started_here else [])])


def _load() -> Optional[float]:
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def _finite(x) -> bool:
    return x is not None and math.isfinite(x)


__all__ = ["add_arguments", "run", "plan_episodes", "run_episodes", "write_outputs",
           "np"]


if __name__ == "__main__":
    from benchmarks.cli import main
    sys.exit(main("demo"))
