"""The closed loop where methods fail (issue #37): ``make demo-variants``
(``python -m benchmarks.demo_variants``).

Slip-stop and slip-track of :mod:`benchmarks.demo` with the shipped models, in the default
scene and under each stressor: the held-out scene variants (:mod:`aslip_ros.scene.variants`,
``make transfer``'s, none trained on) and the arm's operating noise 2 and 4 times as loud
(``robot2x``, ``robot4x``: ``Acoustics.robot_level``). ``--stressors`` also takes the arm's
noise at any other factor by the same name (``robot0x``: the arm silent, ``robot0.5x``), to
ask how much of a loop's error the arm's noise makes. A stressor reaches the scene as
``scene_sim``'s ``variant`` and ``robot_noise_x`` parameters (``Episode.variant``,
``Episode.robot_noise_x``); every stressor runs the same seeds as the default scene, so its
trials are paired with the default's. The episodes are the demo's (planning, the worker
pool, the metrics), in lockstep on simulated time with the nodes' declared compute budgets:
the same tables on any host.

Per stressor and method: slip-stop successes k/n with the 95 % Wilson interval; the stop
error |Delta x| [mm] (all trials, failures included, as ``make demo``) and the time from the
slip onset to the stop [ms], each its mean with the 95 % bootstrap interval of the mean;
slip-track pose RMSE [mm] likewise; the estimate's tracking delay in the loop [ms] (the lag
that best correlates it with the true slip, summed over the episodes) with a bootstrap
interval over episodes; and whether every slip-stop that stopped stayed stopped (no moving
arm command after the stop, over the ``settle_result_s`` the episode watches it).

``rate`` (audio at 44.1 kHz) is not run: the shipped checkpoints take 48 kHz only and
``slip_inference`` refuses the stream, so the loop never closes (a variant that changes the
sample rate is refused with that reason).

Results: ``<out>/variants.json``, ``<out>/variants.md``, ``<out>/variants.png`` and the
per-episode traces in ``<out>/episodes/``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from aslip_ros.scene.scenario import Scenario
from aslip_ros.scene.variants import CONFOUNDER_GAIN, LAB_MOCAP
from aslip_ros.util import write_json, write_text
from benchmarks import demo
from benchmarks import demo_metrics as dm
from benchmarks.demo_episode import (CHARGES, LOCKSTEP_BUDGET_S, MODES, Episode,
                                     StopSettings, TrackSettings, robot_noise_name)
from benchmarks.demo_models import OBJECTS

TASKS = ("slip_stop", "slip_track")
#: Trials per stressor, task, method and object: an episode costs about 2 CPU seconds
#: (1.9 s of a 2-worker pool's wall time, measured beside another benchmark), and 10
#: stressors x 2 tasks x 4 methods x 5 objects are 400 episodes a trial (about 13 min), so
#: 3 trials keep the run under an hour on 2 cores with room for a busier machine.
DEFAULT_TRIALS = 3
#: The arm's noise factors run as stressors of their own, named ``robot<x>x``.
ROBOT_NOISE_X = (2.0, 4.0)
#: A slip-stop that stopped must hold the stop for its settle_result_s, less this [s] (the
#: estimator's charge and a block's rounding).
HOLD_TOLERANCE_S = 0.02
#: Why a variant may be left out of the loop, by what it changes (see :func:`refusal`).
RATE_REFUSAL = ("changes the audio rate: the shipped checkpoints take 48 kHz only and "
                "slip_inference refuses another, so the loop never closes")
#: What a variant changes in these two closed loops (this scene version), for the table.
NOTES = {
    "one_sided": "shapes an agent's pushes in external_induced trials only: the wall push "
                 "has no agent and the drag path does not take its direction, so its trials "
                 "are the default scene's",
    "mocap": "the loop reads no motion capture (the TCP pose and the audio only); what "
             "changes is the rate of the scene's truth log the metrics are taken from "
             f"({LAB_MOCAP['mocap_rate_hz']:g} Hz instead of {Scenario.mocap_rate_hz:g} Hz)",
    "confounders": "its no-slip touches are an agent's in external_induced trials; here "
                   f"the hand's noise and clicks and the arm's noise {CONFOUNDER_GAIN:g} "
                   "times the default scene's",
}


def stressors(names: Sequence[str] = ()) -> dict[str, tuple[Optional[str], float]]:
    """Every stressor by name: ``(variant or None, robot noise factor)``; with those of
    ``names`` that name the arm's noise at another factor (:func:`robot_noise_factor`)."""
    from aslip_ros.scene.variants import VARIANTS
    out: dict = {"default": (None, 1.0)}
    out.update({v: (v, 1.0) for v in VARIANTS})
    out.update({robot_noise_name(x): (None, x) for x in ROBOT_NOISE_X})
    out.update({n: (None, x) for n in names if n not in out
                for x in [robot_noise_factor(n)] if x is not None})
    return out


def robot_noise_factor(name: str) -> Optional[float]:
    """The factor a ``robot<x>x`` name gives the arm's noise (``robot0.5x``: 0.5), or None
    for any other name. One name a factor: ``x`` as ``%g`` writes it, finite and >= 0."""
    if not (name.startswith("robot") and name.endswith("x")):
        return None
    try:
        x = float(name[len("robot"):-1])
    except ValueError:
        return None
    return x if math.isfinite(x) and x >= 0.0 and name == robot_noise_name(x) else None


def refusal(variant: Optional[str]) -> Optional[str]:
    """Why ``variant`` cannot run in the loop with the shipped checkpoints, or None."""
    if variant is None:
        return None
    from aslip_ros.scene import scenarios
    from aslip_ros.scene.variants import VARIANTS
    base = scenarios.wall_push(seed=0)
    return RATE_REFUSAL if VARIANTS[variant](base).sample_rate != base.sample_rate else None


def default_stressors() -> list[str]:
    """All the stressors the loop can run: the default scene, every variant but those
    refused, louder robot noise."""
    return [name for name, (v, _) in stressors().items() if refusal(v) is None]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``python -m benchmarks.demo_variants``."""
    p.add_argument("--out", default="results/demo_variants", help="output directory")
    p.add_argument("--models", default="models", help="directory of the shipped checkpoints")
    p.add_argument("--train-data", default="data/demo",
                   help="scratch data when the checkpoints must be trained first")
    for opt, what in (("--stream", "aslip_stream: the streaming checkpoint"),
                      ("--cnn", "aslip_window: window CNN checkpoint"),
                      ("--cnn-uncalibrated", "window CNN checkpoint without calibration"),
                      ("--svm", "SVM checkpoint"),
                      ("--aslip", "aslip: the default (hybrid) checkpoint (else assembled "
                                  "from the aslip_stream and aslip_window checkpoints)")):
        p.add_argument(opt, default=None, help=f"{what} (default: --models)")
    p.add_argument("--stressors", default=None,
                   help="comma-separated stressors (default: every one the loop can run: "
                        "default, the scene variants but rate, robot2x, robot4x; the arm's "
                        "noise at any other factor x >= 0 as robot<x>x, robot0x: silent)")
    p.add_argument("--tasks", default=",".join(TASKS), help="comma-separated tasks")
    p.add_argument("--methods", default=",".join(demo.DEFAULT_METHODS),
                   help=f"comma-separated methods out of {','.join(demo.METHODS)}")
    p.add_argument("--objects", default=",".join(OBJECTS), help="comma-separated objects")
    p.add_argument("--trials", type=int, default=DEFAULT_TRIALS,
                   help="trials per stressor, task, method and object (default "
                        f"{DEFAULT_TRIALS}: 15 per stressor, task and method; with the 10 "
                        "stressors of this scene 1200 episodes, about 40 min on 2 cores)")
    p.add_argument("--charge", choices=CHARGES, default=CHARGES[0],
                   help="compute time charged per lockstep block: the nodes' declared "
                        "budgets or what this host measures")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: one per CPU)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG chart")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def plan(tasks, methods, objects, trials: int, checkpoints: dict, names: Sequence[str],
         charge: str = CHARGES[0]) -> list[Episode]:
    """The demo's episodes (:func:`benchmarks.demo.plan_episodes`, lockstep), each under
    every stressor of ``names``: the same seeds in every scene."""
    table = stressors(names)
    base = demo.plan_episodes(tasks, methods, objects, trials, checkpoints, StopSettings(),
                              TrackSettings(), mode=MODES[0], charge=charge)
    return [replace(ep, variant=table[n][0], robot_noise_x=table[n][1])
            for ep in base for n in names]


# --- metrics --------------------------------------------------------------------------------

def wilson_interval(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a success rate k/n (95 % by default; NaN for n = 0)."""
    if n <= 0:
        return math.nan, math.nan
    p = k / n
    den = 1.0 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, mid - half), min(1.0, mid + half)


def delay_interval(curves: list, n_boot: int = 500, seed: int = 0) -> tuple[float, float]:
    """95 % bootstrap interval (over episodes) of the tracking delay [ms] of lag curves."""
    curves = [c for c in curves if c is not None and len(c) == len(dm.LAGS_S)]
    if len(curves) < 2:
        return math.nan, math.nan
    arr = np.asarray(curves, dtype=float)
    idx = np.random.default_rng(seed).integers(0, len(arr), (n_boot, len(arr)))
    lags = dm.LAGS_S[np.argmax(arr[idx].sum(axis=1), axis=1)] * 1e3
    return float(np.percentile(lags, 2.5)), float(np.percentile(lags, 97.5))


def _mean_ci(values) -> dict:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    lo, hi = dm.mean_interval(v)
    return {"mean": dm._num(float(v.mean())) if v.size else None, "n": int(v.size),
            "ci95": [dm._num(lo), dm._num(hi)]}


def held(r: dict, settle_s: float = StopSettings.settle_result_s) -> Optional[bool]:
    """Whether a slip-stop episode whose controller stopped stayed stopped: it ends on a
    stop, held ``settle_s`` (less :data:`HOLD_TOLERANCE_S`) with no moving command after it;
    None when the controller never said it stopped (a miss, not a broken stop)."""
    h = r.get("stop_hold")
    if r.get("controller_reason") is None or not h:
        return None
    return bool(h["ends_on_stop"] and h["held_s"] >= settle_s - HOLD_TOLERANCE_S)


def stop_cell(rows: list[dict]) -> dict:
    """Slip-stop of one stressor and method."""
    k = sum(1 for r in rows if dm.succeeded("slip_stop", r))
    lo, hi = wilson_interval(k, len(rows))
    holds = [held(r) for r in rows]
    return {"trials": len(rows), "successes": k, "success_ci95": [dm._num(lo), dm._num(hi)],
            "error_mm": _mean_ci(abs(r["stopping_error_m"]) * 1e3 for r in rows
                                 if r.get("stopping_error_m") is not None),
            "onset_to_stop_ms": _mean_ci(r["onset_to_stop_s"] * 1e3 for r in rows
                                         if r.get("onset_to_stop_s") is not None),
            "stopped": sum(h is not None for h in holds),
            "stop_held": sum(h is True for h in holds)}


def track_cell(rows: list[dict]) -> dict:
    """Slip-track of one stressor and method."""
    curves = [r.get("lag_curve") for r in rows]
    lo, hi = delay_interval(curves)
    return {"trials": len(rows),
            "rmse_mm": _mean_ci(r["pose_rmse_m"] * 1e3 for r in rows
                                if r.get("pose_rmse_m") is not None),
            "delay_ms": {"value": dm.tracking_delay_ms(curves),
                         "ci95": [dm._num(lo), dm._num(hi)]}}


def summarize(results: list[dict], names: Sequence[str], methods: Sequence[str]) -> list:
    """One row per stressor and method (episodes that raised are counted, not scored)."""
    rows = []
    for s in names:
        for m in methods:
            mine = [r for r in results if r.get("stressor", "default") == s
                    and r["method"] == m]
            ok = [r for r in mine if "error" not in r]
            stop = [r for r in ok if r["task"] == "slip_stop"]
            track = [r for r in ok if r["task"] == "slip_track"]
            rows.append({"stressor": s, "method": m, "errors": len(mine) - len(ok),
                         "slip_stop": stop_cell(stop) if stop else None,
                         "slip_track": track_cell(track) if track else None})
    return rows


def same_as_default(results: list[dict], names: Sequence[str]) -> list[str]:
    """The stressors whose every episode scored as the default scene's on the same seed
    (what the loop sees did not change)."""
    def score(r):
        return (r.get("stopping_error_m"), r.get("success"), r.get("pose_rmse_m"))
    base = {(r["task"], r["method"], r["seed"]): score(r) for r in results
            if r.get("stressor", "default") == "default" and "error" not in r}
    out = []
    for s in names:
        mine = [r for r in results if r.get("stressor") == s and "error" not in r]
        if s != "default" and mine and all(base.get((r["task"], r["method"], r["seed"]))
                                           == score(r) for r in mine):
            out.append(s)
    return out


# --- outputs --------------------------------------------------------------------------------

def _ci(cell: Optional[dict], digits: int = 1) -> str:
    if not cell or cell.get("mean") is None:
        return "n/a"
    lo, hi = cell["ci95"]
    span = "" if lo is None else f" [{lo:.{digits}f}, {hi:.{digits}f}]"
    return f"{cell['mean']:.{digits}f}{span}"


def table_md(rows: list[dict]) -> str:
    """The markdown table: a row per stressor and method."""
    lines = ["| stressor | method | slip-stop success [95 % Wilson] | stop error mm "
             "[95 % CI] | onset to stop ms [95 % CI] | stops held | slip-track RMSE mm "
             "[95 % CI] | tracking delay ms [95 % CI] | errors |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s, t = r["slip_stop"], r["slip_track"]
        if s:
            lo, hi = s["success_ci95"]
            stop = [f"{s['successes']}/{s['trials']} [{lo:.2f}, {hi:.2f}]",
                    _ci(s["error_mm"]), _ci(s["onset_to_stop_ms"], 0),
                    f"{s['stop_held']}/{s['stopped']}"]
        else:
            stop = ["-"] * 4
        if t:
            d = t["delay_ms"]
            delay = "n/a" if d["value"] is None else f"{d['value']:.0f}" + (
                "" if d["ci95"][0] is None else f" [{d['ci95'][0]:.0f}, {d['ci95'][1]:.0f}]")
            track = [_ci(t["rmse_mm"]), delay]
        else:
            track = ["-"] * 2
        lines.append("| " + " | ".join([r["stressor"], r["method"], *stop, *track,
                                        str(r["errors"])]) + " |")
    return "\n".join(lines) + "\n"


def report_md(doc: dict) -> str:
    """variants.md: what was run, the table, the notes."""
    meta = doc["meta"]
    stops = [r["slip_stop"] for r in doc["rows"] if r["slip_stop"]]
    broken = sum(s["stopped"] - s["stop_held"] for s in stops)
    lines = [f"# The closed loop under stressors ({meta['command']})", "",
             f"{meta['trials']} trial(s) per stressor, task, method and object "
             f"({', '.join(meta['objects'])}); every stressor on the default scene's seeds. "
             "Slip-stop: successes with the 95 % Wilson interval; |Delta x| over all trials "
             "(failures included) and slip onset to stop, mean with the 95 % bootstrap "
             "interval of the mean; stops held: slip-stops whose controller stopped and sent "
             "no moving command after the stop while the episode watched "
             f"(settle_result_s). Slip-track: pose RMSE likewise; tracking delay: the lag "
             "that best correlates the estimate with the true slip, with a bootstrap "
             "interval over episodes.", "", demo.mode_sentence(meta), "",
             table_md(doc["rows"]),
             f"Stops not held (a moving command after a stop): {broken} of "
             f"{sum(s['stopped'] for s in stops)} slip-stops that stopped."]
    if doc["same_as_default"]:
        lines.append("Scored exactly as the default scene on every seed (the stressor "
                     "changes nothing these loops see): " + ", ".join(doc["same_as_default"])
                     + ".")
    for name, note in NOTES.items():
        if name in meta["stressors"]:
            lines.append(f"- `{name}`: {note}.")
    lines.append(f"- `rate` is not run: it {RATE_REFUSAL}.")
    lines.append(f"\nWall time {meta['wall_s']:.0f} s with {meta['workers']} workers on "
                 f"{meta['cpus']} CPUs; episodes that raised errors: {len(doc['errors'])}.")
    return "\n".join(lines) + "\n"


def write_outputs(out: Path, results: list[dict], meta: dict, plots: bool = True) -> dict:
    """variants.json, variants.md and variants.png, each written atomically."""
    names, methods = meta["stressors"], meta["methods"]
    known = stressors(names)
    ok = [r for r in results if "error" not in r]
    doc = {"format": "aslip-demo-variants", "version": 1, "meta": meta,
           "stressors": {n: dict(zip(("variant", "robot_noise_x"), known[n]))
                         for n in names},
           "rows": summarize(results, names, methods),
           "same_as_default": same_as_default(ok, names),
           "episodes": results, "errors": [r for r in results if "error" in r]}
    if plots:
        doc["plots"] = [str(plot(out / "variants.png", doc["rows"], names, methods))]
    write_json(out / "variants.json", doc)
    write_text(out / "variants.md", report_md(doc))
    return doc


def _panels():
    """The chart's panels: (title, how to read a row's cell -> (value, lo, hi))."""
    def mean(task, key):
        def get(row):
            c = (row[task] or {}).get(key) or {}
            lo, hi = c.get("ci95") or (None, None)
            return c.get("mean"), lo, hi
        return get

    def success(row):
        c = row["slip_stop"]
        return (None, None, None) if not c else (c["successes"] / max(c["trials"], 1),
                                                 *c["success_ci95"])

    def delay(row):
        c = (row["slip_track"] or {}).get("delay_ms") or {}
        return c.get("value"), *(c.get("ci95") or (None, None))
    return [("slip-stop success rate", success), ("slip-stop |error| [mm]",
                                                  mean("slip_stop", "error_mm")),
            ("slip onset to stop [ms]", mean("slip_stop", "onset_to_stop_ms")),
            ("slip-track pose RMSE [mm]", mean("slip_track", "rmse_mm")),
            ("slip-track tracking delay [ms]", delay)]


def plot(path: Path, rows: list[dict], names: Sequence[str], methods: Sequence[str]) -> Path:
    """Each method's loop against each stressor: a panel per metric, the stressors along x,
    a marker per method with its 95 % interval."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.demo_plots import COLORS, _save
    panels = _panels()
    fig, axes = plt.subplots(len(panels), 1, figsize=(max(6.0, 1.0 * len(names) + 2), 13),
                             sharex=True)
    x = np.arange(len(names))
    width = 0.7 / max(len(methods), 1)
    for ax, (title, get) in zip(axes, panels):
        for j, m in enumerate(methods):
            vals = [get(next(r for r in rows if r["stressor"] == s and r["method"] == m))
                    for s in names]
            y = np.array([np.nan if v is None else v for v, _, _ in vals], dtype=float)
            lo = np.array([np.nan if a is None else a for _, a, _ in vals], dtype=float)
            hi = np.array([np.nan if b is None else b for _, _, b in vals], dtype=float)
            err = np.vstack([np.where(np.isfinite(lo), y - lo, 0.0),
                             np.where(np.isfinite(hi), hi - y, 0.0)])
            ax.errorbar(x + (j - (len(methods) - 1) / 2) * width, y, yerr=err, fmt="o",
                        ms=4, capsize=2, color=COLORS.get(m), label=m)
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-0.05, 1.05)
    axes[-1].set_xticks(x)
    axes[-1].set_xticklabels(names, rotation=30, ha="right")
    fig.suptitle("The closed loop under each stressor (95 % intervals)", fontsize=10, y=0.998)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="upper center", fontsize=8,
               ncol=len(methods), bbox_to_anchor=(0.5, 0.983))
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.955))
    path.parent.mkdir(parents=True, exist_ok=True)
    _save(fig, path)
    plt.close(fig)
    return path


# --- entry point ----------------------------------------------------------------------------

def _lists(args) -> tuple[list, list, list, list, list]:
    """Tasks, methods, objects, stressors from the command line, and what is wrong."""
    def split(text):
        return [x for x in text.split(",") if x]
    tasks, methods, objects = split(args.tasks), split(args.methods), split(args.objects)
    names = split(args.stressors) if args.stressors else default_stressors()
    table = stressors(names)
    bad = [t for t in tasks if t not in TASKS] + [m for m in methods if m not in demo.METHODS] \
        + [o for o in objects if o not in OBJECTS] + [s for s in names if s not in table]
    bad += [f"{s} ({refusal(table[s][0])})" for s in names
            if s in table and refusal(table[s][0])]
    return tasks, methods, objects, names, bad


def run(args: argparse.Namespace) -> int:
    """Entry point of ``python -m benchmarks.demo_variants``."""
    t0 = time.perf_counter()
    tasks, methods, objects, names, bad = _lists(args)
    if bad or args.trials < 1 or not (tasks and methods and objects and names):
        print(f"benchmarks.demo_variants: unknown or refused task/method/object/stressor "
              f"{bad} (stressors: {', '.join(stressors())}, robot<x>x), or --trials < 1",
              file=sys.stderr)
        return 2
    models = demo.resolve_models(args, methods)
    missing = [m for m in methods if m not in models or not Path(models[m]).is_file()]
    if missing:
        print(f"benchmarks.demo_variants: no checkpoint for {missing}", file=sys.stderr)
        return 1
    eps = plan(tasks, methods, objects, args.trials, models, names, args.charge)
    workers = max(1, args.workers or os.cpu_count() or 1)
    print(f"[demo-variants] {len(eps)} lockstep episodes ({len(names)} stressors) on "
          f"{workers} workers; models: {models['source']}", file=sys.stderr, flush=True)
    out = Path(args.out)
    results = demo.run_episodes(eps, workers, out / "episodes", not args.no_progress)
    assert len(results) == len(eps), "run_episodes returns a result per episode, in order"
    for ep, r in zip(eps, results):
        r.setdefault("stressor", ep.stressor)
    meta = {"command": demo.command_line("demo_variants"), "tasks": tasks, "methods": methods,
            "objects": objects, "stressors": names, "trials": args.trials,
            "mode": MODES[0], "charge": args.charge, "lockstep_budget_s": LOCKSTEP_BUDGET_S,
            "stop_settings": asdict(StopSettings()), "track_settings": asdict(TrackSettings()),
            "workers": workers, "cpus": os.cpu_count(), "host": platform.node(),
            "checkpoints": {m: str(models[m]) for m in methods},
            "models_source": models["source"],
            "wall_s": round(time.perf_counter() - t0, 1)}
    doc = write_outputs(out, results, meta, plots=not args.no_plots)
    print(table_md(doc["rows"]))
    print(f"results: {out / 'variants.json'}, {out / 'variants.md'}"
          + (f", {doc['plots'][0]}" if doc.get("plots") else ""))
    print(f"wall time {time.perf_counter() - t0:.0f} s")
    return 0 if not doc["errors"] else 1


if __name__ == "__main__":
    from benchmarks.cli import main
    sys.exit(main("demo_variants"))
