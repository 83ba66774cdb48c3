"""The report of ``make bench``: the latency-against-accuracy chart (``pareto.png``) and
``bench.md``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .common import fmt_num, markdown_table


def plot_pareto(result: dict[str, Any], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aslip_ros.util import atomic_path
    pts = result["points"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    colors = {"method": "tab:red", "size": "tab:blue", "features": "tab:green"}
    for ax, metric, label, front in (
            (axes[0], "dir_mae_deg", "direction MAE (deg)", result["pareto_latency_dir"]),
            (axes[1], "det_pct", "detection accuracy (%)", result["pareto_latency_det"])):
        for p in pts:
            if p.get(metric) is None:
                continue
            ax.scatter(p["latency_p99_ms"], p[metric], c=colors.get(p["sweep"], "k"),
                       marker="*" if p["name"] in front else "o", s=90 if p["name"] in front
                       else 35)
            ax.annotate(p["name"], (p["latency_p99_ms"], p[metric]), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
        sel = next((p for p in pts if p["name"] == result["smallest_within_1deg"]), None)
        if sel is not None and sel.get(metric) is not None:
            ax.scatter(sel["latency_p99_ms"], sel[metric], s=260, facecolors="none",
                       edgecolors="k", linewidths=1.5,
                       label="smallest within 1 deg of best dir.")
        ax.axvline(result.get("target_p99_ms", 3.0), color="gray", ls="--", lw=0.8,
                   label="p99 target 3 ms")
        ax.set_xlabel("p99 latency per window, 1 thread (ms)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for k, c in colors.items():
        axes[0].scatter([], [], c=c, label=f"sweep: {k}")
    axes[0].scatter([], [], c="k", marker="*", label="Pareto front")
    axes[0].legend(fontsize=7)
    fig.suptitle("A-SLIP on the scene: latency against accuracy (test split)")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def bench_markdown(result: dict[str, Any], bench: dict[str, Any]) -> str:
    hdr = ["name", "sweep", "params", "n params", "p5 ms", "p50 ms", "p99 ms",
           "features p50 ms",
           "Det. %", "Dir. MAE deg", "Mag. RMSE mm"]
    body = [[p["name"], p["sweep"], str(p["params"] or ""), p["n_params"],
             fmt_num(p.get("latency_p5_ms"), 2), fmt_num(p["latency_p50_ms"], 2),
             fmt_num(p["latency_p99_ms"], 2),
             fmt_num(p["features_p50_ms"], 2), fmt_num(p.get("det_pct")),
             fmt_num(p.get("dir_mae_deg")), fmt_num(p.get("mag_rmse_mm"), 2)]
            for p in result["points"]]
    s = ["# Latency against accuracy\n\n", markdown_table(hdr, body),
         f"\nSmallest model within 1 deg of the best direction MAE: "
         f"**{result['smallest_within_1deg']}**. Cheapest lossless feature setting: "
         f"**{result['feature_sweep']['cheapest_lossless']}**. Load average during the run: "
         f"{result['load_average']}.\n"]
    if "system" in bench:
        s.append(f"\nSystem: `{bench['system']}`\n")
    return "".join(s)
