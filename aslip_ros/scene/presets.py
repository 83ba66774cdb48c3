"""The default datasets (``make datasets``): simulate bags, then export them, per layout.

For every microphone layout this builds two datasets from the scene, following the paper's
protocol (Sec. IV) at a reduced scale:

- ``<out>/datasets/<layout>/pretrain``: robot-induced slip (arm sweeps over a stationary
  probe, ``pla_rod``), labels from robot state;
- ``<out>/datasets/<layout>/finetune``: externally induced slip on the five objects, robot
  stationary / moving / off, labels from motion capture.

Bags are kept under ``<out>/bags/<layout>/{robot,external}/`` so other window lengths can be
exported later (``aslip export``). Both steps resume: existing bags are reused, existing
datasets kept unless ``overwrite``.

Scales (robot-induced trials; externally induced trials per object for robot stationary /
moving / off; seconds per trial):

- ``tiny``: 2; 1 / 1 / 1 on two objects; 4 s (smoke tests)
- ``default``: 24; 3 / 1 / 2 on the five objects; 10 s
- ``paper``: 60; 30 / 10 / 20 on the five objects; 30 s

``default`` gives 4 min of pretraining and 5 min of finetuning audio per layout (about 2,400
and 3,000 windows of 200 ms at a 100 ms hop), which trains in minutes on 2 CPU cores. The
paper does not give the size of its robot-induced set; 60 trials of 30 s is an assumption.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

from aslip_ros.data.export import (DEFAULT_HOP_S, DEFAULT_WINDOW_S, ExportConfig, export,
                                   labelled_as)

from .layouts import LAYOUTS
from .simulate import simulate

PAPER_OBJECTS = ("pla_rod", "glass_cleaner", "chips_can", "mustard_container", "cracker_box")
PROBE = "pla_rod"

SCALES = {
    # tiny: 3 robot trials, the fewest whose split by trial leaves one for validation.
    "tiny": {"robot_trials": 3, "objects": ("chips_can", "pla_rod"),
             "external": {"robot_stationary": 1, "robot_moving": 1, "robot_off": 1},
             "duration_s": 4.0},
    "default": {"robot_trials": 24, "objects": PAPER_OBJECTS,
                "external": {"robot_stationary": 3, "robot_moving": 1, "robot_off": 2},
                "duration_s": 10.0},
    "paper": {"robot_trials": 60, "objects": PAPER_OBJECTS,
              "external": {"robot_stationary": 30, "robot_moving": 10, "robot_off": 20},
              "duration_s": 30.0},
}


def build_default_datasets(out_dir: str | Path, scale: str = "default",
                           layouts: tuple[str, ...] | None = None, seed: int = 0,
                           pad: str = "textured", window_s: float = DEFAULT_WINDOW_S,
                           hop_s: float = DEFAULT_HOP_S, overwrite: bool = False,
                           progress: bool = True) -> dict:
    """Simulate and export the default datasets; returns (and writes) a summary.

    The summary (``<out>/datasets/summary.json``) lists every dataset with its number of
    trials, windows, audio seconds, size on disk and the seconds spent simulating and
    exporting it.
    """
    if scale not in SCALES:
        raise ValueError(f"scale must be one of {sorted(SCALES)}, got {scale!r}")
    spec = SCALES[scale]
    out = Path(out_dir)
    layouts = tuple(layouts) if layouts else tuple(LAYOUTS)     # every layout of the scene
    cfg = ExportConfig(window_s=window_s, hop_s=hop_s, overwrite=overwrite,
                       progress=progress)
    summary: dict = {"scale": scale, "seed": seed, "pad": pad, "window_s": window_s,
                     "hop_s": hop_s, "datasets": {}}
    for layout in layouts:
        jobs = {
            "pretrain": ("robot", dict(objects=[PROBE], conditions=["robot_moving"],
                                       trials=spec["robot_trials"])),
            "finetune": ("external", None),
        }
        for name, (kind, kw) in jobs.items():
            bag_dir = out / "bags" / layout / kind
            t0 = time.perf_counter()
            if kw is not None:
                simulate(bag_dir, kind, duration_s=spec["duration_s"], seed=seed,
                         layout=layout, pad=pad, progress=progress, **kw)
            else:
                # Trials per condition differ, so one simulate call per condition.
                for cond, n in spec["external"].items():
                    simulate(bag_dir, kind, objects=list(spec["objects"]), conditions=[cond],
                             trials=n, duration_s=spec["duration_s"], seed=seed,
                             layout=layout, pad=pad, progress=progress)
            t_sim = time.perf_counter() - t0
            ds_path = out / "datasets" / layout / name
            entry = {"path": str(ds_path), "bags": str(bag_dir),
                     "simulate_s": round(t_sim, 1)}
            if ds_path.exists() and not overwrite and labelled_as(ds_path, cfg):
                entry["export"] = "kept existing"
            else:
                # A dataset labelled otherwise (raw poses, before the smoothing) is replaced.
                res = export([bag_dir], ds_path, replace(cfg, overwrite=True))
                entry.update(windows=res.kept, dropped=res.dropped,
                             audio_s=round(res.audio_s, 1), export_s=round(res.elapsed_s, 1),
                             trials=len([b for b in res.bags if not b.error]))
            entry["dataset_mib"] = round(_du(ds_path) / 2**20, 1)
            entry["bags_mib"] = round(_du(bag_dir) / 2**20, 1)
            summary["datasets"][f"{layout}/{name}"] = entry
            if progress:
                print(f"{layout}/{name}: {json.dumps(entry)}", file=sys.stderr)
    (out / "datasets").mkdir(parents=True, exist_ok=True)
    from aslip_ros.util import write_json
    write_json(out / "datasets" / "summary.json", summary)
    return summary


def _du(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) if path.exists() else 0


def main(argv: list[str] | None = None) -> int:
    """``python -m aslip_ros.scene.presets --out data --scale default`` (``make datasets``)."""
    p = argparse.ArgumentParser(prog="python -m aslip_ros.scene.presets",
                                description="build the default simulated datasets")
    p.add_argument("--out", type=Path, default=Path("data"), help="root (default %(default)s)")
    p.add_argument("--scale", choices=sorted(SCALES), default="default")
    p.add_argument("--layouts", help="comma-separated layouts (default: all of the scene's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--window", type=float, default=DEFAULT_WINDOW_S)
    p.add_argument("--hop", type=float, default=DEFAULT_HOP_S)
    p.add_argument("--overwrite", action="store_true", help="re-export existing datasets")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    layouts = tuple(v.strip() for v in a.layouts.split(",")) if a.layouts else None
    try:
        s = build_default_datasets(a.out, a.scale, layouts, a.seed, window_s=a.window,
                                   hop_s=a.hop, overwrite=a.overwrite,
                                   progress=not a.no_progress)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(s, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
