"""Where the live path's time goes, per 10 ms hop, in process (``python -m benchmarks.live_cost``).

Scene audio (the simulated 4-microphone grasp, 48 kHz, 10 ms blocks) is fed block by block
through ``learn.inference.live.LiveEstimator`` for each shipped checkpoint, as
``slip_inference`` does (``accept`` in the audio callback, ``run`` on the window a hop makes
due), with ``torch_threads`` torch threads (the node's default: 1). Per hop it records:

- ``accept``: the audio thread's share (gate, ring buffer, per-grasp calibration; for a
  streaming model also its features and forward, as the node counts them);
- ``calibration``: the per-grasp calibration's share of ``accept``;
- ``dead_check``: the dead-microphone check;
- ``features``: what the node reports as features (``accept`` + ``last_features_s``, less
  the forward for a streaming model);
- ``forward``: ``last_forward_s``;
- ``total``: ``accept`` + ``run``: the per-hop cost end to end (no ROS);

as p50 / p99 [ms], and the process CPU seconds per second of audio (``cpu_per_audio_s``:
0.5 is half a core). ``--repeat`` passes (default 3) of ``--seconds`` of audio each; the
figures are the median over passes (the machine may be shared: say so beside the numbers).
``--hogs N`` runs N ``yes`` processes beside (as ``benchmarks.tail_latency``).

Writes ``live_cost.json`` (``--out``) and, with ``--before FILE`` (an earlier
``live_cost.json``), ``table.md``: one row per model and step, before / after.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from aslip_ros.util import write_json

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("models/aslip_stream.pt", "models/aslip_cnn.pt", "models/aslip_cnn_uncalibrated.pt",
          "models/svm.pt")
STEPS = ("accept", "calibration", "dead_check", "features", "forward", "total")
RATE = 48000.0
BLOCK = 480


def scene_blocks(seconds: float, seed: int = 3) -> list:
    """``AudioData`` blocks of a simulated external-induced grasp (4 microphones)."""
    from aslip_ros.audio_frame import AudioData
    from aslip_ros.hw.sources import build_world
    w = build_world(dict(scenario="external_induced", seed=seed, object="chips_can",
                         layout="4mic", pad="textured", condition="robot_stationary",
                         sample_rate=RATE, wall_distance_m=0.0, drag_speed_m_s=0.04))
    names = list(w.metadata()["channel_names"])
    out = []
    for _ in range(int(round(seconds * RATE / BLOCK))):
        c = w.step(BLOCK)
        stamp = 1_000_000_000_000 + int(round(c.first_sample_index * 1e9 / RATE))
        out.append(AudioData(c.first_sample_index, stamp, RATE, names, "4mic",
                             "aslip_sensor", np.ascontiguousarray(c.audio, np.float32)))
    return out


class _Clock:
    """Wraps a callable; accumulates the seconds spent in it (``take`` reads and zeroes)."""

    def __init__(self, fn: Any) -> None:
        self.fn, self.seconds = fn, 0.0

    def __call__(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - t0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.fn, name)

    def take(self) -> float:
        out, self.seconds = self.seconds, 0.0
        return out


def _instrument(est) -> tuple[_Clock | None, _Clock]:
    """Clocks on the calibration's ``push`` (when the checkpoint has one) and the
    dead-microphone check, wrapped in place (timing only)."""
    import aslip_ros.learn.inference.live as live
    pr = est.predictor
    cal = getattr(pr, "_stream_cal", None) or getattr(pr, "_cal", None)
    cal_clock = None
    if cal is not None:
        cal_clock = _Clock(cal.push)
        cal.push = cal_clock
    dead = live.dead_channels
    dead_clock = _Clock(dead.fn if isinstance(dead, _Clock) else dead)
    live.dead_channels = dead_clock
    return cal_clock, dead_clock


def run_pass(checkpoint: str, blocks: list, threads: int) -> dict:
    """One pass of ``blocks`` through a fresh estimator: per-hop samples [s] and CPU time."""
    import torch
    from aslip_ros.learn.inference.live import LiveConfig, LiveEstimator
    torch.set_num_threads(threads)
    est = LiveEstimator.from_checkpoint(checkpoint, LiveConfig(hop_s=0.01))
    cal_clock, dead_clock = _instrument(est)
    rec: dict[str, list[float]] = {s: [] for s in STEPS}
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for a in blocks:
        dead_clock.take()
        if cal_clock is not None:
            cal_clock.take()
        t0 = time.perf_counter()
        estimates, job = est.accept(a)
        t1 = time.perf_counter()
        t_run = 0.0
        if job is not None:
            est.run(job)
            t_run = time.perf_counter() - t1
        elif not estimates:
            continue
        acc = t1 - t0
        fwd = est.last_forward_s
        rec["accept"].append(acc)
        rec["calibration"].append(cal_clock.take() if cal_clock is not None else 0.0)
        rec["dead_check"].append(dead_clock.take())
        rec["features"].append(acc - fwd if est.streaming else acc + est.last_features_s)
        rec["forward"].append(fwd)
        rec["total"].append(acc + t_run)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    return {"samples": rec, "cpu_s": cpu, "wall_s": wall,
            "audio_s": len(blocks) * BLOCK / RATE}


def summarise(passes: list[dict]) -> dict:
    """Median over passes of each step's p50 / p99 [ms] and of the CPU per audio second."""
    out: dict[str, Any] = {"passes": len(passes), "hops": len(passes[0]["samples"]["total"])}
    for step in STEPS:
        for q, name in ((50, "p50"), (99, "p99")):
            vals = [float(np.percentile(p["samples"][step], q)) * 1e3 for p in passes]
            out[f"{step}_{name}_ms"] = statistics.median(vals)
    out["cpu_per_audio_s"] = statistics.median(p["cpu_s"] / p["audio_s"] for p in passes)
    out["wall_per_audio_s"] = statistics.median(p["wall_s"] / p["audio_s"] for p in passes)
    return out


def table(before: dict, after: dict) -> str:
    """Markdown: one row per model and step, p50 / p99 [ms] before and after."""
    lines = [f"Per 10 ms hop, in process, {after['repeat']} passes of {after['seconds']:g} s "
             f"of scene audio each (median over passes), torch threads {after['threads']}, "
             f"{after['hogs']} hogs; load average before {before['load_average_before'][0]:.2f}"
             f" / after {after['load_average_before'][0]:.2f} (a shared 2-core machine: "
             "timings are noisy).", "",
             "| model | step | before p50 / p99 [ms] | after p50 / p99 [ms] | p50 speed-up |",
             "|---|---|---|---|---|"]
    for name, a in after["results"].items():
        b = before["results"].get(name)
        if b is None:
            continue
        for step in STEPS:
            bp, bq = b[f"{step}_p50_ms"], b[f"{step}_p99_ms"]
            ap, aq = a[f"{step}_p50_ms"], a[f"{step}_p99_ms"]
            ratio = f"{bp / ap:.1f}x" if ap > 1e-4 else "-"
            lines.append(f"| {name} | {step} | {bp:.3f} / {bq:.3f} | {ap:.3f} / {aq:.3f} "
                         f"| {ratio} |")
        lines.append(f"| {name} | CPU s per audio s | {b['cpu_per_audio_s']:.3f} | "
                     f"{a['cpu_per_audio_s']:.3f} | "
                     f"{b['cpu_per_audio_s'] / max(a['cpu_per_audio_s'], 1e-9):.1f}x |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=list(MODELS))
    ap.add_argument("--seconds", type=float, default=6.0, help="audio per pass [s]")
    ap.add_argument("--repeat", type=int, default=3, help="passes per model (median)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (node: 1)")
    ap.add_argument("--hogs", type=int, default=0, help="CPU-busy processes beside")
    ap.add_argument("--before", default=None, help="an earlier live_cost.json: write table.md")
    ap.add_argument("--out", default="results/live_cost")
    a = ap.parse_args(argv)
    if a.seconds <= 0.3 or a.repeat < 1 or a.hogs < 0 or a.threads < 1:
        ap.error("need --seconds > 0.3, --repeat >= 1, --hogs >= 0, --threads >= 1")
    from aslip_ros.util import cpu_hogs
    blocks = scene_blocks(a.seconds)
    results: dict[str, Any] = {}
    load_before = list(os.getloadavg())
    with cpu_hogs(a.hogs):
        for m in a.models:
            path = Path(m) if Path(m).is_absolute() or Path(m).exists() else ROOT / m
            passes = [run_pass(str(path), blocks, a.threads) for _ in range(a.repeat)]
            r = results[Path(m).stem] = summarise(passes)
            print(f"{Path(m).stem}: " + " | ".join(
                f"{s} {r[f'{s}_p50_ms']:.3f}/{r[f'{s}_p99_ms']:.3f}" for s in STEPS)
                + f" ms p50/p99 | {r['cpu_per_audio_s']:.3f} CPU s/s", file=sys.stderr)
    doc = {"seconds": a.seconds, "repeat": a.repeat, "threads": a.threads, "hogs": a.hogs,
           "block_frames": BLOCK, "load_average_before": load_before,
           "load_average_after": list(os.getloadavg()), "results": results}
    out = Path(a.out)
    write_json(out / "live_cost.json", doc)
    if a.before:
        (out / "table.md").write_text(table(json.loads(Path(a.before).read_text()), doc))
    print(f"wrote {out / 'live_cost.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
