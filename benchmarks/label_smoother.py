"""Streaming label smoothers against the scene's truth: ``python -m benchmarks.label_smoother``.

The scene's externally induced trials are run with their motion-capture noise and dropouts;
each candidate smoother (:class:`aslip_ros.data.stream_labels.Smoother`) sees only the noisy
poses and is scored against the scene's true slip velocity. It chose
``stream_labels.DEFAULT_SMOOTHER`` (docs/streaming.md): ``--trials 6 --json
results/lag/label_smoother.json``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from aslip_ros.data.labels import PoseTrack
from aslip_ros.data.stream_labels import Smoother, relative_track, track_velocity
from aslip_ros.scene import scenarios as sc
from aslip_ros.scene.world import World
from aslip_ros.util import write_json


def compare_with_truth(n_trials: int = 6, duration_s: float = 10.0, seed: int = 0,
                       smoothers: tuple = ()) -> dict:
    """RMSE (mm/s) of candidate label velocities against the scene's true slip velocity.

    The scene's externally induced trials are run with their motion-capture noise and
    dropouts; each candidate sees only the noisy poses, and is scored at the true
    velocity's instants (the mocap capture times).
    """
    cands = list(smoothers) or [Smoother(w, p) for w in (0.05, 0.1, 0.15, 0.25)
                                for p in (2, 3)]
    err = {"diff_20ms": []} | {f"sg_{s.window_s * 1e3:.0f}ms_p{s.polyorder}": []
                               for s in cands}
    objs = ("chips_can", "pla_rod", "cracker_box")
    for i in range(n_trials):
        scn = sc.external_induced(seed + i, object=objs[i % len(objs)],
                                  condition="robot_moving").with_(duration_s=duration_s)
        world = World(scn, record=True)
        samples = [s for ch in world.stream() for s in ch.mocap]
        truth = world.trajectory()
        ts = np.array([s.t for s in samples])
        fin = PoseTrack(ts, np.array([s.finger_pose for s in samples]))
        obj = PoseTrack(ts, np.array([s.object_pose for s in samples]))
        tr = relative_track("mocap", fin, np.array([0, 0, 0, 0, 0, 0, 1.0]), obj)
        tq, vt = truth["t"], truth["v_rel"]
        inner = (tq > 0.3) & (tq < duration_s - 0.3)
        d = track_velocity(tr, tq, Smoother(0.02, 1))[0]
        err["diff_20ms"].append(d[inner][:, [0, 2]] - vt[inner])
        for s in cands:
            v = track_velocity(tr, tq, s)[0]
            name = f"sg_{s.window_s * 1e3:.0f}ms_p{s.polyorder}"
            err[name].append(v[inner][:, [0, 2]] - vt[inner])
    out = {}
    for k, e in err.items():
        e = np.concatenate(e)
        out[k] = {"rmse_mm_s": float(np.sqrt((e ** 2).sum(1).mean()) * 1e3),
                  "p95_abs_mm_s": float(np.percentile(np.hypot(e[:, 0], e[:, 1]), 95) * 1e3)}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="streaming label smoothers against scene truth")
    p.add_argument("--trials", type=int, default=6)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--json", default=None, help="write the table here")
    a = p.parse_args(argv)
    res = compare_with_truth(a.trials, a.duration)
    for k, v in res.items():
        print(f"{k:16s} rmse {v['rmse_mm_s']:6.2f} mm/s  p95 {v['p95_abs_mm_s']:6.2f} mm/s")
    if a.json:
        write_json(a.json, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
