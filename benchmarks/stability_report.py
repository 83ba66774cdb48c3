"""The breakdown criterion of ``make stability`` and its report: one chart per stressor and
``stability.md``.

A method breaks down at the first level (benign to harsh) where its detection drops below
``DET_MIN_PCT`` or its direction error exceeds ``DIR_MAX_DEG``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .common import fmt_num, fmt_pm, markdown_table

DET_MIN_PCT = 70.0
DIR_MAX_DEG = 30.0


def breakdown(levels: Sequence[Any], det_pct: Sequence[float | None],
              dir_deg: Sequence[float | None], det_min: float = DET_MIN_PCT,
              dir_max: float = DIR_MAX_DEG) -> dict[str, Any] | None:
    """The first level (in the given order, benign to harsh) where detection drops below
    ``det_min`` or direction MAE exceeds ``dir_max``; ``None`` when it never does."""
    for lvl, d, a in zip(levels, det_pct, dir_deg):
        why = []
        if d is not None and d < det_min:
            why.append(f"detection {d:.1f} % < {det_min:g} %")
        if a is not None and a > dir_max:
            why.append(f"direction MAE {a:.1f} deg > {dir_max:g} deg")
        if why:
            return {"level": lvl, "reason": "; ".join(why)}
    return None


def plot_stressor(name: str, sweep: dict[str, Any], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aslip_ros.util import atomic_path
    levels = [str(x) for x in sweep["levels"]]
    xs = np.arange(len(levels))
    methods = sorted({m for r in sweep["results"] for m in r})
    # One colour per method (a "_seen" variant shares its method's colour, dashed), used by
    # its curve and by its breakdown line, which the legend names.
    base = sorted({m.removesuffix("_seen") for m in methods})
    color = {m: f"C{base.index(m.removesuffix('_seen'))}" for m in methods}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, metric, label, limit in ((axes[0], "det_pct", "detection accuracy (%)",
                                      DET_MIN_PCT),
                                     (axes[1], "dir_mae_deg", "direction MAE (deg)",
                                      DIR_MAX_DEG)):
        for m in methods:
            ys = [r.get(m, {}).get(metric) for r in sweep["results"]]
            ys = [np.nan if y is None else y for y in ys]
            ax.plot(xs, ys, marker="o", ls="--" if m.endswith("_seen") else "-", label=m,
                    color=color[m])
        ax.axhline(limit, color="gray", ls=":", lw=1, label="breakdown limit")
        for m, b in sweep.get("breakdown", {}).items():
            if b is not None:
                ax.axvline(levels.index(str(b["level"])), ls=":", lw=1.2,
                           color=color.get(m, "gray"), label=f"{m} breaks down")
        ax.set_xticks(xs)
        ax.set_xticklabels(levels, rotation=30, ha="right", fontsize=8)
        ax.set_xlabel(sweep["x_label"])
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"stressor: {name}")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def stability_markdown(out: dict[str, Any]) -> str:
    s = ["# Stability under stressors\n\n",
         f"Breakdown: detection < {DET_MIN_PCT:g} % or direction MAE > {DIR_MAX_DEG:g} deg.\n"]
    for name, sw in out["stressors"].items():
        methods = sorted({m for r in sw["results"] for m in r})
        hdr = [sw["x_label"]] + [f"{m} det % / dir deg" for m in methods]
        body = [[str(lvl)] + [f"{fmt_num(r.get(m, {}).get('det_pct'))} / "
                              f"{fmt_num(r.get(m, {}).get('dir_mae_deg'))}" for m in methods]
                for lvl, r in zip(sw["levels"], sw["results"])]
        s.append(f"\n## {name} ({name}.png)\n\n" + markdown_table(hdr, body))
        for m, b in sw["breakdown"].items():
            s.append(f"- {m}: " + ("no breakdown in the swept range" if b is None else
                                   f"breaks down at **{b['level']}** ({b['reason']})") + "\n")
        for m, objs in sw.get("failing", {}).items():
            s.append(f"- {m}: failing objects when left out: {objs or 'none'}\n")
    if "training_seeds" in out:
        ts = out["training_seeds"]
        s.append("\n## Training stability (default model, 4 mics, seeds "
                 f"{[r['seed'] for r in ts['runs']]})\n\n")
        for k, v in ts["summary"].items():
            s.append(f"- {k}: {fmt_pm(v['mean'], v['std'], 2)} (min {v['min']:.2f}, max "
                     f"{v['max']:.2f})\n")
        s.append(f"- pretrain + finetune time per seed: mean {ts['train_time_s']['mean']:.0f}"
                 f" s, max {ts['train_time_s']['max']:.0f} s\n")
    s.append(f"\nRun time {out.get('elapsed_s', 0) / 60:.1f} min.\n")
    return "".join(s)
