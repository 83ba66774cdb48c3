"""Label smoothers against the scene's truth: ``python -m benchmarks.label_smoother``.

The scene's externally induced trials are run with their motion-capture noise and dropouts;
each candidate smoother (:class:`aslip_ros.data.stream_labels.Smoother`) sees only the noisy
poses and is scored against the scene's true slip velocity. It chose
``stream_labels.DEFAULT_SMOOTHER`` (docs/streaming.md): ``--trials 6 --json
results/lag/label_smoother.json``.

``--windows``: the 200 ms window labels of ``aslip export`` instead, read from the raw poses
at the window's ends and from the poses smoothed over each candidate length
(``data.labels.mocap_window_velocity``), scored against the true mean slip of the window at
the scene's default motion capture and at a lab's (``--variant mocap``): the noise of the
label, how often its slip flag agrees with the truth's, and its direction and speed errors
in slip windows. It chose ``data.labels.DEFAULT_LABEL_SMOOTHING_S`` (docs/results.md,
"Window labels from smoothed poses").
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from aslip_ros.data.labels import DEFAULT_EPSILON_M_S, PoseTrack, mocap_window_velocity
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


def _window_truth(truth: dict, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """The true mean slip velocity (x, z) over each window: the integral of ``v_rel``."""
    t, v = truth["t"], truth["v_rel"]
    path = np.concatenate([np.zeros((1, 2)),
                           np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], axis=0)])
    at = [np.column_stack([np.interp(tq, t, path[:, j]) for j in range(2)]) for tq in (t0, t1)]
    return (at[1] - at[0]) / (t1 - t0)[:, None]


def _window_scores(label: np.ndarray, truth: np.ndarray, eps: float) -> dict:
    e = label - truth
    slip_t, slip_l = np.hypot(*truth.T) > eps, np.hypot(*label.T) > eps
    both = slip_t & slip_l
    turn = np.angle((label[both, 0] + 1j * label[both, 1])
                    * np.conj(truth[both, 0] + 1j * truth[both, 1]))
    speed = np.hypot(*label[slip_t].T) - np.hypot(*truth[slip_t].T)
    return {"rmse_mm_s": float(np.sqrt((e ** 2).sum(1).mean()) * 1e3),
            "slip_flag_agrees_pct": float((slip_t == slip_l).mean() * 100),
            "direction_mae_deg": float(np.degrees(np.abs(turn)).mean()),
            "speed_rmse_mm_s": float(np.sqrt((speed ** 2).mean()) * 1e3),
            "windows": int(truth.shape[0]), "slip_pct": float(slip_t.mean() * 100)}


def compare_window_labels(n_trials: int = 6, duration_s: float = 20.0, seed: int = 100,
                          variant: str | None = None, lengths=(0.05, 0.1, 0.15, 0.25),
                          window_s: float = 0.2) -> dict:
    """Window labels from raw and from smoothed poses against the true mean slip of each
    window (the export's grid: ``window_s`` every 100 ms), pooled over ``n_trials``
    externally induced trials alternating still and moving gripper."""
    from aslip_ros.scene.variants import VARIANTS
    objs = ("chips_can", "pla_rod", "cracker_box")
    found: dict[str, list] = {"raw": []} | {f"smoothed_{s * 1e3:.0f}ms": [] for s in lengths}
    truths = []
    for i in range(n_trials):
        scn = sc.external_induced(seed + i, object=objs[i % len(objs)],
                                  condition=("robot_stationary", "robot_moving")[i % 2]
                                  ).with_(duration_s=duration_s)
        world = World(VARIANTS[variant](scn) if variant else scn, record=True)
        samples = [s for ch in world.stream() for s in ch.mocap]
        ts = np.array([s.t for s in samples])
        fin = PoseTrack(ts, np.array([s.finger_pose for s in samples]))
        obj = PoseTrack(ts, np.array([s.object_pose for s in samples]))
        t0 = np.arange(0.5, duration_s - 0.5 - window_s, 0.1)
        t1 = t0 + window_s
        labels = {"raw": mocap_window_velocity(fin, obj, t0, t1)}
        for s in lengths:
            labels[f"smoothed_{s * 1e3:.0f}ms"] = mocap_window_velocity(fin, obj, t0, t1,
                                                                        smoothing_s=s)
        ok = labels["raw"].valid
        truths.append(_window_truth(world.trajectory(), t0, t1)[ok])
        for k, lab in labels.items():
            found[k].append(lab.slip_velocity[ok])
    truth = np.concatenate(truths)
    return {k: _window_scores(np.concatenate(v), truth, DEFAULT_EPSILON_M_S)
            for k, v in found.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="streaming label smoothers against scene truth")
    p.add_argument("--trials", type=int, default=6)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--json", default=None, help="write the table here")
    p.add_argument("--windows", action="store_true",
                   help="the export's 200 ms window labels instead of the streaming labels")
    p.add_argument("--variant", default=None, help="scene variant (--windows; e.g. mocap)")
    a = p.parse_args(argv)
    if a.windows:
        res = compare_window_labels(a.trials, a.duration, variant=a.variant)
        for k, v in res.items():
            print(f"{k:16s} " + "  ".join(f"{n} {x:.2f}" for n, x in v.items()))
        if a.json:
            write_json(a.json, res)
        return 0
    res = compare_with_truth(a.trials, a.duration)
    for k, v in res.items():
        print(f"{k:16s} rmse {v['rmse_mm_s']:6.2f} mm/s  p95 {v['p95_abs_mm_s']:6.2f} mm/s")
    if a.json:
        write_json(a.json, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
