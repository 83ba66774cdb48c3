"""PNG plots of the demo: arm and object trajectories, predicted against true slip, and the
pivot-stop's angle turned by each arm.

Reads the per-episode traces (``<out>/episodes/<key>.npz``) of the first trial of each
object and method. Every figure is written atomically (temporary file, then rename).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aslip_ros.slip import DEFAULT_THRESHOLD
from aslip_ros.util import atomic_path

COLORS = {"aslip": "tab:red", "aslip_stream": "tab:green", "aslip_window": "tab:blue",
          "aslip_uncalibrated": "tab:purple", "svm": "tab:orange"}
#: The slip-stop figure's zoom on the stop: the last seconds of each episode [s].
ZOOM_S = 1.0


def _load(out: Path, key: str):
    p = out / "episodes" / f"{key}.npz"
    return dict(np.load(p)) if p.is_file() else None


def _save(fig, path: Path) -> Path:
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    return path


class _Episodes:
    """The results of a demo run and their traces: the first trial of each object and method."""

    def __init__(self, out: Path, results: list[dict]) -> None:
        self.out = Path(out)
        self.results = results
        self.objects = sorted({r["object"] for r in results})
        self.methods = [m for m in COLORS if any(r["method"] == m for r in results)]

    def has(self, task: str) -> bool:
        return any(r["task"] == task for r in self.results)

    def first(self, task: str, method: str, obj: str):
        rs = sorted((r for r in self.results if r["task"] == task and r["method"] == method
                     and r["object"] == obj), key=lambda r: r["trial"])
        return rs[0] if rs else None

    def trace(self, task: str, method: str, obj: str):
        """(result, trace) of the first trial, or (result or None, None)."""
        r = self.first(task, method, obj)
        return r, (r and _load(self.out, f"{task}-{method}-{obj}-{r['trial']:02d}"))


def make_plots(out: Path, results: list[dict]) -> list[Path]:
    """Write the figures; returns their paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eps = _Episodes(out, results)
    written = []
    if eps.has("slip_stop"):
        written.append(_slip_stop_figure(plt, eps))
    if eps.has("slip_track"):
        written.append(_slip_track_figure(plt, eps))
    for task in ("slip_stop", "slip_track"):
        path = _prediction_figure(plt, eps, task)
        if path is not None:
            written.append(path)
    if eps.has("pivot_stop"):
        path = _pivot_figure(plt, eps)
        if path is not None:
            written.append(path)
    if any(isinstance(r.get("worker_timing"), dict) for r in results):
        written.append(_tail_figure(plt, eps))
    return written


def _pivot_figure(plt, eps: _Episodes) -> Path | None:
    """Pivot-stop, one column per arm (the first estimator that ran it): the angle the
    object turned over time, and the estimated against the true rotation rate, for the
    first trial of each object. None when no trace carries the scene's angle."""
    from benchmarks.demo_metrics import PIVOT_ARMS
    rows = [r for r in eps.results if r["task"] == "pivot_stop"]
    method = rows[0]["method"]
    arms = [a for a in PIVOT_ARMS if any(r.get("arm") == a for r in rows)]
    traces = {}
    for arm in arms:
        for obj in eps.objects:
            mine = sorted((r for r in rows if r["method"] == method and r.get("arm") == arm
                           and r["object"] == obj), key=lambda r: r["trial"])
            tr = _load(eps.out, f"pivot_stop-{method}-{arm}-{obj}-{mine[0]['trial']:02d}") \
                if mine else None
            if tr is not None and "angle" in tr:
                traces[(arm, obj)] = tr
    if not traces:
        return None
    fig, axes = plt.subplots(2, len(arms), figsize=(6 * len(arms), 7), squeeze=False,
                             sharey="row", constrained_layout=True)
    for j, arm in enumerate(arms):
        for obj in eps.objects:
            tr = traces.get((arm, obj))
            if tr is None:
                continue
            line, = axes[0][j].plot(tr["t"], np.degrees(np.abs(tr["angle"])), label=obj)
            if "w_rel" in tr:
                axes[1][j].plot(tr["t"], tr["w_rel"], color=line.get_color(), lw=1)
            if "pred_w" in tr:
                axes[1][j].plot(tr["pred_t"], tr["pred_w"], color=line.get_color(), lw=1,
                                ls=":")
        axes[0][j].set_title(f"pivot-stop, {method}, {arm.replace('_', ' ')}")
        axes[0][j].set_ylabel("angle turned [deg]")
        axes[1][j].set_title("rotation rate: true (solid), estimated (dotted)")
        axes[1][j].set_ylabel("angular velocity [rad/s]")
        for ax in axes[:, j]:
            ax.set_xlabel("time [s]")
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    path = _save(fig, eps.out / "pivot_stop_angle.png")
    plt.close(fig)
    return path


def _tail_figure(plt, eps: _Episodes) -> Path:
    """The live path's tail: per method, each episode's worst SlipVector gap at the
    controller, executor gap in the worker and garbage-collector pause, sorted (the right
    end of each curve is the worst episode), beside the 50 ms stale-input watchdog."""
    from benchmarks.demo_metrics import TAIL_FIGURES, tail_values
    fig, axes = plt.subplots(1, len(TAIL_FIGURES), figsize=(5 * len(TAIL_FIGURES), 3.6),
                             sharey=True, squeeze=False)
    for ax, (key, where, what) in zip(axes[0], TAIL_FIGURES):
        for m in eps.methods:
            # 0 (no pause at all) drawn at 0.05 ms, the axis' floor
            v = np.maximum(np.sort(tail_values(eps.results, m, key, where)), 0.05)
            if v.size:
                ax.plot(100.0 * np.arange(1, v.size + 1) / v.size, v, color=COLORS[m],
                        label=m)
        ax.axhline(50.0, color="red", lw=0.8, ls="--", label="watchdog (50 ms)")
        ax.set_yscale("log")
        ax.set_ylim(bottom=0.04)
        ax.set_xlabel("episodes [%], sorted by their worst")
        ax.set_title(what, fontsize=9)
    axes[0][0].set_ylabel("worst in the episode [ms]")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    path = _save(fig, eps.out / "tail_latency.png")
    plt.close(fig)
    return path


def _slip_stop_figure(plt, eps: _Episodes) -> Path:
    """TCP and object along the push direction, relative to the wall contact; the second row
    zooms on the stop (the last ZOOM_S), where the stopping error is."""
    methods = eps.methods
    fig, axes = plt.subplots(2, len(methods), figsize=(6 * len(methods), 7.5),
                             squeeze=False, sharey="row", constrained_layout=True)
    for j, m in enumerate(methods):
        ends = []
        for obj in eps.objects:
            _, tr = eps.trace("slip_stop", m, obj)
            if tr is None:
                continue
            n = tr["push_dir"]
            ref = tr["tcp"][0] @ n
            tcp, obj_ = (tr["tcp"] @ n - ref) * 1e3, (tr["object"] @ n - ref) * 1e3
            ends.append((tr["t"][-1], tcp[-1], obj_[-1]))
            for ax in axes[:, j]:
                line, = ax.plot(tr["t"], tcp, label=f"{obj} arm")
                ax.plot(tr["t"], obj_, ls=":", color=line.get_color())
        axes[0][j].set_title(f"slip-stop, {m}: TCP (solid), object (dotted)")
        axes[1][j].set_title(f"the stop, last {ZOOM_S:g} s")
        if ends:
            t_end = max(e[0] for e in ends)
            lo = min(min(e[1:]) for e in ends)
            hi = max(max(e[1:]) for e in ends)
            axes[1][j].set_xlim(t_end - ZOOM_S, t_end)
            axes[1][j].set_ylim(min(lo, 0.0) - 2.0, hi + 2.0)
        for ax in axes[:, j]:
            ax.axhline(0.0, color="k", lw=0.8)
            ax.set_xlabel("time [s]")
            ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("along push direction, from the contact pose [mm]")
    axes[1][0].set_ylabel("along push direction [mm]")
    axes[0][0].legend(fontsize=7)
    path = _save(fig, eps.out / "slip_stop_trajectories.png")
    plt.close(fig)
    return path


def _slip_track_figure(plt, eps: _Episodes) -> Path:
    """Arm and object paths in the world (x, y) and the gripper-object offset over time."""
    methods = eps.methods
    # constrained_layout: the top row's x labels and the bottom row's titles overlapped.
    fig, axes = plt.subplots(2, len(methods), figsize=(6 * len(methods), 8),
                             squeeze=False, constrained_layout=True)
    for j, m in enumerate(methods):
        for obj in eps.objects:
            _, tr = eps.trace("slip_track", m, obj)
            if tr is None:
                continue
            t0 = tr["tcp"][0]
            line, = axes[0][j].plot((tr["object"][:, 0] - t0[0]) * 1e3,
                                    (tr["object"][:, 1] - t0[1]) * 1e3, ls=":")
            axes[0][j].plot((tr["tcp"][:, 0] - t0[0]) * 1e3,
                            (tr["tcp"][:, 1] - t0[1]) * 1e3, color=line.get_color(),
                            label=obj)
            rel = tr["rel"] - tr["rel"][0]
            axes[1][j].plot(tr["t"], np.linalg.norm(rel, axis=1) * 1e3,
                            color=line.get_color(), label=obj)
        axes[0][j].set_title(f"slip-track, {m}: arm (solid), object (dotted)")
        axes[0][j].set_xlabel("world x [mm]")
        axes[0][j].set_ylabel("world y [mm]")
        axes[0][j].axis("equal")
        axes[1][j].set_title("gripper-object offset from its start")
        axes[1][j].set_xlabel("time [s]")
        axes[1][j].set_ylabel("|relative position error| [mm]")
        for ax in axes[:, j]:
            ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    path = _save(fig, eps.out / "slip_track_trajectories.png")
    plt.close(fig)
    return path


def _prediction_figure(plt, eps: _Episodes, task: str) -> Path | None:
    """Predicted against true slip over time, one episode per method."""
    rows = [(m, eps.first(task, m, eps.objects[0])) for m in eps.methods]
    rows = [(m, r) for m, r in rows if r is not None]
    if not rows:
        return None
    fig, axes = plt.subplots(3, len(rows), figsize=(6 * len(rows), 7), squeeze=False,
                             sharex="col")
    for j, (m, r) in enumerate(rows):
        tr = _load(eps.out, f"{task}-{m}-{r['object']}-{r['trial']:02d}")
        if tr is None:
            continue
        for i, name in enumerate(("vx", "vz")):
            axes[i][j].plot(tr["t"], tr["v_rel"][:, i] * 1e3, color="k", lw=1,
                            label="true (scene)")
            axes[i][j].plot(tr["pred_t"], tr["pred_v"][:, i] * 1e3, color=COLORS[m],
                            lw=1, label=f"predicted ({m})")
            axes[i][j].set_ylabel(f"slip {name} [mm/s]")
            axes[i][j].grid(alpha=0.3)
        axes[2][j].plot(tr["pred_t"], tr["pred_p"], color=COLORS[m])
        axes[2][j].axhline(DEFAULT_THRESHOLD, color="k", lw=0.8, ls="--")
        axes[2][j].set_ylabel("p(slip)")
        axes[2][j].set_xlabel("time [s]")
        axes[0][j].set_title(f"{task.replace('_', '-')}, {m}, {r['object']}")
        axes[0][j].legend(fontsize=7)
    path = _save(fig, eps.out / f"{task}_slip_prediction.png")
    plt.close(fig)
    return path
