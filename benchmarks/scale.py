"""``make scale`` (#38): export and training against hours of recordings.

For each number of hours (``--hours``, default 1, 4 and 16) the scene records that much
audio (external pushes, 10-minute trials, ``--rate`` Hz, in ``--sim-jobs`` processes; the
bags of the largest set are made once and the smaller sets are its first trials). Then,
each in a fresh child process that reports its own peak resident memory (``VmHWM``):

- ``aslip export --jobs 1`` and ``--jobs 2``: seconds, times real time, and the peak
  memory of the parent and of its largest worker;
- ``aslip train --stage scratch`` for ``--epochs`` epochs (no early stop, no time budget)
  on the exported dataset: the feature cache's build (memory-mapped on disk), seconds per
  epoch, and peak memory.

Disk: a set needs its bags and one dataset at a time (about 2.8 GB each an hour of 4
channels at 48 kHz, a third of that at 16 kHz); the benchmark checks the free space first
and says what to pass where it is short. Results: ``<out>/scale.json`` (merged across
calls by rate and hours), ``scale.md`` and ``scale.png``.

    python -m benchmarks.scale --out results/scale [--hours 1,4,16] [--rate 48000]
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import shutil
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from aslip_ros.util import read_json, write_json, write_text

TRIAL_S = 600.0
#: Bytes of one recorded second per channel and Hz (float32 audio, with the bag's
#: overhead), measured: a 120 s bag of 4 channels at 16 kHz is 36 MB.
BYTES_PER_SAMPLE = 4.7


#: An ``aslip`` command that writes its own peak resident memory on exit: ``VmHWM`` (every
#: resident page, the memory-mapped files' included) and the peak of ``RssAnon`` sampled
#: every 50 ms (the process's own memory; mapped file pages are the page cache's, which the
#: kernel reclaims). ``ru_maxrss`` from ``wait4`` keeps the peak of the process it was
#: started from.
_CHILD = """
import sys, threading, time
from aslip_ros.cli import main
from aslip_ros.util import peak_rss_mib, write_json
peak = [0]
def anon():
    with open('/proc/self/status') as f:
        for line in f:
            if line.startswith('RssAnon:'):
                return int(line.split()[1])
    return 0
def watch():
    while True:
        peak[0] = max(peak[0], anon())
        time.sleep(0.05)
threading.Thread(target=watch, daemon=True).start()
code = main(sys.argv[2:])
peak[0] = max(peak[0], anon())
write_json(sys.argv[1], {'peak_rss_mib': peak_rss_mib(), 'peak_anon_mib': peak[0] / 1024})
sys.exit(code)
"""


def _aslip(args: list[str], log: Path) -> dict[str, Any]:
    """Run ``aslip ARGS`` in a child process: its wall seconds and its own peak resident
    memory [MiB] (its workers' not included)."""
    peak = log.with_suffix(".peak.json")
    t = time.perf_counter()
    with open(log, "w") as out:
        code = subprocess.call([sys.executable, "-c", _CHILD, str(peak), *args],
                               stdout=out, stderr=subprocess.STDOUT)
    if code:
        raise RuntimeError(f"aslip {' '.join(args[:2])} ... failed ({code}): see {log}")
    got = read_json(peak)
    return {"wall_s": round(time.perf_counter() - t, 2),
            "peak_rss_mib": round(got["peak_rss_mib"], 1),
            "peak_anon_mib": round(got["peak_anon_mib"], 1)}


def _simulate_part(out: str, trials: int, seed: int, rate: float, trial_s: float) -> float:
    from aslip_ros.scene.simulate import simulate
    return simulate(out, "external", trials=trials, duration_s=trial_s, seed=seed,
                    progress=False, sample_rate=rate)["audio_s"]


def record(bags: Path, hours: float, rate: float, jobs: int, log,
           trial_s: float = TRIAL_S) -> list[Path]:
    """The first ``hours`` of trials, made where missing (``jobs`` processes)."""
    n = max(1, math.ceil(hours * 3600.0 / trial_s))
    parts = [(k, n // jobs + (k < n % jobs)) for k in range(jobs)]
    parts = [(k, m) for k, m in parts if m]
    t = time.perf_counter()
    # Spawned, not forked: a fork of a process that already runs threads (torch's, rclpy's)
    # can crash the child (a segmentation fault in a worker's garbage collection, seen in a
    # fresh-clone CI run of the tests); ``aslip export --jobs`` spawns its workers too.
    with ProcessPoolExecutor(len(parts), mp_context=multiprocessing.get_context("spawn")) \
            as pool:
        made = sum(pool.map(_simulate_part, [str(bags / f"part{k}") for k, _ in parts],
                            [m for _, m in parts], [1000 * k for k, _ in parts],
                            [rate] * len(parts), [trial_s] * len(parts)))
    log(f"  {n} trials of {trial_s:.0f} s in {bags} ({made / 3600:.1f} h recorded now, "
        f"{time.perf_counter() - t:.0f} s)")
    # Trial by trial across the parts, so that a smaller set is the start of a larger.
    each = [sorted(p for p in (bags / f"part{k}").iterdir() if p.is_dir())
            for k in range(jobs) if (bags / f"part{k}").is_dir()]
    paths = [p for row in zip(*[e + [None] * (n - len(e)) for e in each]) for p in row
             if p is not None]
    return paths[:n]


def export_run(bags: list[Path], ds: Path, jobs: int, work: Path) -> dict[str, Any]:
    shutil.rmtree(ds, ignore_errors=True)
    summary = work / f"export_j{jobs}.json"
    got = _aslip(["export", *map(str, bags), "-o", str(ds), "--jobs", str(jobs),
                  "--no-progress", "--summary-json", str(summary)],
                 work / f"export_j{jobs}.log")
    s = read_json(summary)
    return {"jobs": jobs, "wall_s": got["wall_s"], "audio_s": s["audio_s"],
            "x_real_time": round(s["audio_s"] / got["wall_s"], 1),
            "peak_rss_mib": got["peak_rss_mib"], "peak_anon_mib": got["peak_anon_mib"],
            "worker_peak_rss_mib": s.get("worker_peak_rss_mib"), "windows": s["kept"]}


def train_run(ds: Path, epochs: int, work: Path) -> dict[str, Any]:
    from aslip_ros.learn.checkpoint import load_checkpoint
    ckpt = work / "scale.pt"
    shutil.rmtree(ds / ".feature_cache", ignore_errors=True)
    got = _aslip(["train", "--dataset", str(ds), "--stage", "scratch", "--epochs",
                  str(epochs), "--patience", str(epochs), "--time-budget", "1e9",
                  "--no-progress", "--out", str(ckpt)], work / "train.log")
    tr = load_checkpoint(ckpt).meta["provenance"]["training"]
    cache = sum(f.stat().st_size for f in (ds / ".feature_cache").rglob("*") if f.is_file())
    return {"wall_s": got["wall_s"], "peak_rss_mib": got["peak_rss_mib"],
            "peak_anon_mib": got["peak_anon_mib"], "epochs": tr["epochs_run"],
            "s_per_epoch": round(tr["train_time_s"] / max(1, tr["epochs_run"]), 2),
            "feature_time_s": round(tr["feature_time_s"], 1),
            "n_train_windows": tr["n_train_windows"],
            "feature_cache_gib": round(cache / 2 ** 30, 2)}


def _free_gib(path: Path) -> float:
    return shutil.disk_usage(path).free / 2 ** 30


def needed_gib(hours: float, rate: float, channels: int = 4) -> float:
    """Bags and one dataset of ``hours`` [GiB]."""
    return 2 * hours * 3600 * rate * channels * BYTES_PER_SAMPLE / 2 ** 30


def report(rows: list[dict[str, Any]], out: Path) -> None:
    rows = sorted(rows, key=lambda r: (r["rate"], r["hours"]))
    lines = ["| rate | hours | export 1 job | export 2 jobs | 2 jobs / 1 | export peak "
             "(parent / worker) | train s/epoch | train peak resident (own memory) | "
             "feature cache |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        e1, e2, t = r["export"].get("1"), r["export"].get("2"), r.get("train") or {}
        ratio = (f"{e2['x_real_time'] / e1['x_real_time']:.2f}x" if e1 and e2 else "-")
        lines.append(
            f"| {r['rate'] / 1000:g} kHz | {r['hours']:g} | "
            + (f"{e1['x_real_time']:.0f}x real time, {e1['peak_rss_mib']:.0f} MiB" if e1
               else "-") + " | "
            + (f"{e2['x_real_time']:.0f}x" if e2 else "-") + f" | {ratio} | "
            + (f"{e2['peak_rss_mib']:.0f} / {e2.get('worker_peak_rss_mib') or 0:.0f} MiB"
               if e2 else "-") + " | "
            + (f"{t['s_per_epoch']:.1f} s ({t['n_train_windows']} windows)" if t else "-")
            + " | " + (f"{t['peak_rss_mib'] / 1024:.2f} GiB" if t else "-")
            + (f" ({t['peak_anon_mib'] / 1024:.2f} GiB)" if t.get("peak_anon_mib") else "")
            + " | "
            + (f"{t['feature_cache_gib']:.2f} GiB, built in {t['feature_time_s']:.0f} s"
               if t else "-") + " |")
    write_text(out / "scale.md", "\n".join(lines) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for rate in sorted({r["rate"] for r in rows}):
        rs = [r for r in rows if r["rate"] == rate]
        for jobs, mark in (("1", "o-"), ("2", "s--")):
            pts = [(r["hours"], r["export"][jobs]["x_real_time"]) for r in rs
                   if jobs in r["export"]]
            if pts:
                ax[0].plot(*zip(*pts), mark, label=f"{rate / 1000:g} kHz, {jobs} job(s)")
        tr = [(r["hours"], r["train"].get("peak_anon_mib", r["train"]["peak_rss_mib"])
               / 1024, r["train"]["s_per_epoch"]) for r in rs if r.get("train")]
        if tr:
            ax[1].plot([x[0] for x in tr], [x[1] for x in tr], "o-",
                       label=f"{rate / 1000:g} kHz: peak own memory [GiB]")
            ax[1].plot([x[0] for x in tr], [x[2] / 60 for x in tr], "s--",
                       label=f"{rate / 1000:g} kHz: minutes per epoch")
    ax[0].set(xscale="log", xlabel="hours of audio", ylabel="export speed [x real time]",
              title="aslip export")
    ax[1].set(xscale="log", xlabel="hours of audio", title="aslip train --stage scratch")
    ax[1].axhline(4.0, color="grey", lw=0.8, ls=":")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "scale.png", dpi=120)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.scale", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=Path("results/scale"))
    p.add_argument("--work", type=Path, default=Path("data/scale"),
                   help="where the bags and datasets go (removed set by set)")
    p.add_argument("--hours", default="1,4,16")
    p.add_argument("--rate", type=float, default=48000.0, help="audio sample rate [Hz]")
    p.add_argument("--sim-jobs", type=int, default=2)
    p.add_argument("--epochs", type=int, default=2)
    p.add_argument("--trial-s", type=float, default=TRIAL_S, help="seconds per trial")
    p.add_argument("--keep", action="store_true", help="keep the bags and datasets")
    p.add_argument("--report-only", action="store_true",
                   help="rewrite scale.md and scale.png from scale.json")
    args = p.parse_args(argv)
    if args.report_only:
        report(read_json(args.out / "scale.json")["rows"], args.out)
        return 0
    hours = sorted(float(h) for h in args.hours.split(",") if h)
    args.out.mkdir(parents=True, exist_ok=True)
    args.work.mkdir(parents=True, exist_ok=True)
    need, free = needed_gib(hours[-1], args.rate), _free_gib(args.work)
    if need > 0.9 * free:
        print(f"scale: {hours[-1]:g} h at {args.rate:g} Hz needs about {need:.0f} GiB in "
              f"{args.work}, which has {free:.0f} GiB free: pass --work on a larger disk, "
              "fewer --hours, or a lower --rate", file=sys.stderr)
        return 1
    results = args.out / "scale.json"
    rows = read_json(results)["rows"] if results.is_file() else []
    bags = args.work / f"bags_{args.rate:g}_{args.trial_s:g}"
    for h in hours:
        print(f"scale: {h:g} h at {args.rate:g} Hz", flush=True)
        paths = record(bags, h, args.rate, args.sim_jobs, print, args.trial_s)
        work = args.work / f"run_{args.rate:g}_{h:g}"
        work.mkdir(exist_ok=True)
        ds = work / "dataset"
        row: dict[str, Any] = {"rate": args.rate, "hours": h, "trials": len(paths),
                               "trial_s": args.trial_s,
                               "export": {}, "cpus": os.cpu_count()}
        for jobs in (2, 1):     # the one-job dataset is kept for training
            row["export"][str(jobs)] = export_run(paths, ds, jobs, work)
            print(f"  export --jobs {jobs}: {row['export'][str(jobs)]}", flush=True)
        row["train"] = train_run(ds, args.epochs, work)
        print(f"  train: {row['train']}", flush=True)
        rows = [r for r in rows if (r["rate"], r["hours"]) != (args.rate, h)] + [row]
        write_json(results, {"rows": rows})
        report(rows, args.out)
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    if not args.keep:
        shutil.rmtree(bags, ignore_errors=True)
    print(json.dumps(rows[-1], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
