"""The tail of the live path: ``make latency`` (``python -m benchmarks.tail_latency``).

For every checkpoint (default: the default hybrid ``models/aslip.pt`` and the three other
shipped neural models; with ``--per-output MAIN SPEED`` also the ``per_output`` model of
MAIN's outputs with SPEED's speed),
``node_bench.measure_node_latency`` runs ``audio_capture`` (simulated scene, 4 channels at
48 kHz) and ``slip_inference`` as separate processes for ``--duration`` seconds, one
checkpoint after the other (never two at once), optionally beside ``--hogs`` CPU-busy
processes (``yes > /dev/null``, as the flake hunt's). Reported per checkpoint: the end-to-
end latency measured by a listener (AudioFrame arrival -> SlipVector arrival, p50 / p99 /
p99.9 / max) and the node's own figures per step of the live path from its diagnostics
(queue: middleware reception to the start of the processing; features: gate, buffers, per-
grasp calibration and features; forward: the model; publish: SlipVector and marker) and the
age of each block when the node's callback starts (source, transport and executor delay
together).

Writes ``tail.json`` and the chart ``tail.png`` (one panel per checkpoint, p50 / p99 /
p99.9 / max bars per step and end to end, log y axis) into ``--out``.

Latency is wall time on whatever machine runs this: ``tail.json`` records the load average
(``os.getloadavg``) before and after each run beside the numbers.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any, Sequence

from aslip_ros.node_table import DEFAULT_MODEL
from aslip_ros.util import write_json

ROOT = Path(__file__).resolve().parents[1]
MODELS = (f"models/{DEFAULT_MODEL}", "models/aslip_stream.pt", "models/aslip_cnn.pt",
          "models/aslip_cnn_uncalibrated.pt")
#: The node's steps (``step_<name>_*_ms`` in its diagnostics), in the order of the path.
STEPS = ("queue", "features", "forward", "publish")
STATS = ("p50", "p99", "p999", "max")
STAT_LABELS = {"p50": "p50", "p99": "p99", "p999": "p99.9", "max": "max"}


def run_one(checkpoint: str, duration_s: float, hogs: int) -> dict:
    """``measure_node_latency`` of one checkpoint beside ``hogs`` busy processes."""
    from benchmarks.node_bench import measure_node_latency
    load_before = list(os.getloadavg())
    from aslip_ros.util import cpu_hogs
    with cpu_hogs(hogs):
        res = measure_node_latency(checkpoint, duration_s)
    res.update(hogs=hogs, load_average_before=load_before)
    return res


def rows(result: dict) -> dict[str, dict[str, float | None]]:
    """Per step (and ``end_to_end`` from the listener, ``node_total`` from the node): the
    four statistics [ms] of one checkpoint's result."""
    node = result.get("node") or {}
    out = {"input_age": {s: node.get(f"input_age_{s}_ms") for s in STATS}}
    out.update({step: {s: node.get(f"step_{step}_{s}_ms") for s in STATS} for step in STEPS})
    out["node_total"] = {s: node.get(f"latency_{s}_ms") for s in STATS}
    out["end_to_end"] = {s: result.get(f"latency_{s}_ms") for s in STATS}
    return out


def plot(results: dict[str, dict], path: Path) -> None:
    """One panel per checkpoint: p50 / p99 / p99.9 / max per step, log y axis."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(results)
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 3.2 * max(1, len(names))),
                             squeeze=False)
    width = 0.2
    for ax, name in zip(axes[:, 0], names):
        table = rows(results[name])
        groups = list(table)
        x = np.arange(len(groups))
        for i, s in enumerate(STATS):
            vals = [table[g][s] for g in groups]
            ax.bar(x + (i - 1.5) * width, [v if v and v > 0 else np.nan for v in vals],
                   width, label=STAT_LABELS[s])
        ax.set_yscale("log")
        ax.set_xticks(x, [g.replace("_", " ") for g in groups])
        ax.set_ylabel("ms")
        r = results[name]
        load = r.get("load_average") or [float("nan")]
        ax.set_title(f"{name}: {r.get('paired', 0)} paired, {r.get('hogs', 0)} hogs, "
                     f"load {load[0]:.2f}, {r.get('slip_inference_cpu_cores', 0):.2f} cores",
                     fontsize=9)
        ax.grid(axis="y", which="both", alpha=0.3)
    axes[0, 0].legend(ncol=4, fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def summary_line(name: str, r: dict) -> str:
    t = rows(r)
    f = lambda v: "-" if v is None else f"{v:.2f}"      # noqa: E731
    parts = [f"{g} " + "/".join(f(t[g][s]) for s in STATS) for g in t]
    return f"{name}: paired {r.get('paired')} | " + " | ".join(parts) + " (p50/p99/p99.9/max ms)"


def per_output_model(main: Path, speed: Path, out: Path) -> Path:
    """A ``per_output`` checkpoint (learn/models/per_output.py) with p(slip), direction and,
    where it has one, the rotation of ``main`` and the speed of ``speed``: what ``aslip
    train``'s per-output choice writes when a speed regressor beats the CNN's speed.

    Parts trained in separate calls carry their own per-grasp calibration constants, and a
    ``per_output`` checkpoint has one: where both parts are calibrated, the speed part is
    given ``main``'s. Its estimates are then not the ones it was trained for, but its cost
    is the same, and the cost is all this checkpoint is for."""
    from aslip_ros.learn.checkpoint import estimates_rotation, load_checkpoint, save_checkpoint
    from aslip_ros.learn.models.per_output import assemble
    parts = {"main": load_checkpoint(main), "speed": load_checkpoint(speed)}
    calibration = [p.meta.get("calibration") for p in parts.values()]
    if None not in calibration and calibration[0] != calibration[1]:
        parts["speed"].meta["calibration"] = calibration[0]
    roles = {"detection": "main", "speed": "speed", "direction": "main"}
    if estimates_rotation(parts["main"].meta):
        roles["rotation"] = "main"
    ck = assemble(parts, roles)
    return save_checkpoint(out, ck.meta, ck.tensors)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=list(MODELS),
                    help="checkpoints, one bench each (default: the three shipped ones)")
    ap.add_argument("--duration", type=float, default=30.0, help="seconds per checkpoint")
    ap.add_argument("--hogs", type=int, default=0, help="CPU-busy processes beside")
    ap.add_argument("--out", default="results/latency")
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--per-output", nargs=2, metavar=("MAIN", "SPEED"),
                    help="also bench a per_output checkpoint of MAIN's detection, direction "
                         "and rotation with SPEED's speed (written to data/latency/)")
    a = ap.parse_args(argv)
    if a.duration <= 0 or a.hogs < 0:
        ap.error("--duration must be > 0 and --hogs >= 0")
    if a.per_output:
        built = per_output_model(*(ROOT / m for m in a.per_output),
                                 ROOT / "data" / "latency" / "per_output.pt")
        a.models = list(a.models) + [str(built)]
    results: dict[str, Any] = {}
    for m in a.models:
        path = Path(m) if Path(m).is_absolute() or Path(m).exists() else ROOT / m
        r = run_one(str(path), a.duration, a.hogs)
        results[Path(m).stem] = r
        print(summary_line(Path(m).stem, r), file=sys.stderr, flush=True)
    out = Path(a.out)
    write_json(out / "tail.json", {"duration_s": a.duration, "hogs": a.hogs,
                                   "results": results})
    if not a.no_plot:
        plot(results, out / "tail.png")
    print(f"wrote {out / 'tail.json'}" + ("" if a.no_plot else f" and {out / 'tail.png'}"),
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
