"""Stale-input benchmark: how fast the controllers stop on a dead slip stream, and whether
they ever stop without one on a busy machine.

Each episode runs the installed node executables as separate processes, as a launch file
does: ``scene_sim`` (wall push), ``slip_inference`` with a checkpoint and ``slip_stop``, on a
ROS domain of its own. Two kinds:

- ``fault``: ``slip_inference`` is killed (SIGKILL) during the approach. Measured: when the
  stop left after the last valid slip estimate (the controller's own clock), when the
  scene's arm was at rest (that plus the braking time to below 1 mm/s in the scene's true
  trajectory), and any velocity command after the stop.
- ``load``: no fault, ``--hogs`` CPU-busy processes (``yes >/dev/null``) beside the loop; a
  stale-input stop is a false stop.

Usage, from the repository root (``source install/setup.bash`` first; ``-P`` and the root
after the install on the path keep the installed ``aslip_ros``, with its messages)::

    PYTHONPATH=$PYTHONPATH:$PWD python -P -m benchmarks.stale_input --fault 20 --load 50 \\
        --hogs 2 --out results/stale_input.json
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import tempfile
import threading
import time
from pathlib import Path
from typing import Optional

import numpy as np

from aslip_ros.util import write_json

ROOT = Path(__file__).resolve().parents[1]
#: Below this TCP speed the arm counts as at rest [m/s] (the issue's 1 mm/s).
REST_M_S = 1e-3
STALE = ("stale_slip", "stale_pose")


class _Probe:
    """Records arm commands and the slip-stop result on the episode's domain."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from geometry_msgs.msg import TwistStamped
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import String

        from aslip_ros.nodes import common as c
        from aslip_ros.runtime.qos import LATCHED_QOS, RELIABLE_QOS
        from aslip_ros.nodes.slip_stop import RESULT_TOPIC
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("aslip_stale_input_probe", context=self.ctx)
        self.cmds: list = []
        self.results: list = []
        self.meta: Optional[dict] = None
        self.node.create_subscription(TwistStamped, c.CMD_VEL_TOPIC, self._on_cmd,
                                      RELIABLE_QOS)
        self.node.create_subscription(String, RESULT_TOPIC, self._on_result, LATCHED_QOS)
        self.node.create_subscription(String, c.METADATA_TOPIC, self._on_meta, LATCHED_QOS)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            try:
                self.ex.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - context shut down at the end
                return

    def _on_cmd(self, m) -> None:
        v = np.array([m.twist.linear.x, m.twist.linear.y, m.twist.linear.z])
        self.cmds.append((time.monotonic(), v))

    def _on_result(self, m) -> None:
        self.results.append(json.loads(m.data))

    def _on_meta(self, m) -> None:
        self.meta = json.loads(m.data)

    def final(self) -> Optional[dict]:
        done = [r for r in self.results if r.get("final")]
        return done[-1] if done else None

    def close(self) -> None:
        import rclpy
        self._stop.set()
        self._thread.join(2)
        self.ex.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def _wait(pred, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.01)
    return bool(pred())


def stop_to_rest_s(traj_path: Path) -> Optional[float]:
    """Scene time from the arm starting to brake to below :data:`REST_M_S` [s].

    From the scene's true trajectory: the final rest, and before it the last sample still at
    95 % of the speed the arm had in the half second before. Scene time, so a scene that
    lags the wall clock does not distort it; None if the arm never came to rest.
    """
    d = np.load(traj_path)
    t, tcp = d["t"], d["tcp"][:, :3]
    v = np.linalg.norm(np.diff(tcp, axis=0), axis=1) / np.maximum(np.diff(t), 1e-9)
    moving = np.nonzero(v >= REST_M_S)[0]
    if moving.size == 0 or moving[-1] + 1 >= len(v):
        return None
    rest = int(moving[-1]) + 1
    window = np.nonzero(t[:rest] >= t[rest] - 0.5)[0]
    peak = float(v[window].max())
    braking = window[v[window] >= 0.95 * peak]
    return float(t[rest] - t[int(braking[-1])])


def run_episode(kind: str, checkpoint: str, seed: int, rng: random.Random,
                timeout_s: Optional[float] = None,
                pose_timeout_s: Optional[float] = None) -> dict:
    """One ``fault`` or ``load`` episode; returns its measurements. ``timeout_s`` and
    ``pose_timeout_s``: the controller's slip and pose watchdogs (default: the node's)."""
    from domain_coordinator import domain_id

    from aslip_ros.runtime.child import NodeProcess

    from benchmarks.demo_episode import StopSettings
    from aslip_ros.scene.layouts import get_object
    s = StopSettings()
    obj = "chips_can"
    ctl = {"approach_speed_m_s": s.approach_speed_m_s,
           "retract_distance_m": s.retract_distance_m,
           "retract_speed_m_s": s.retract_speed_m_s, "settle_s": s.settle_s,
           "max_approach_distance_m": s.retract_distance_m + get_object(obj).length_m
           + s.overshoot_limit_m, "debounce_count": s.debounce_count,
           "settle_result_s": s.settle_result_s}
    if timeout_s is not None:
        ctl["slip_timeout_s"] = timeout_s
    if pose_timeout_s is not None:
        ctl["pose_timeout_s"] = pose_timeout_s
    out: dict = {"kind": kind, "seed": seed}
    with domain_id() as did, tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   PYTHONUNBUFFERED="1")
        traj = Path(tmp) / "traj.npz"
        probe = _Probe(did)
        inf = NodeProcess("slip_inference", env, {"checkpoint": checkpoint})
        stop = NodeProcess("slip_stop", env, ctl)
        procs = [inf, stop]
        try:
            if not (inf.ready.wait(60) and stop.ready.wait(60)):
                return dict(out, error="nodes did not start")
            scene = {"scenario": "wall_push", "seed": seed, "object": obj,
                     "wall_distance_m": 0.0, "trajectory_out": str(traj)}
            sim = NodeProcess("scene_sim", env, scene)
            procs.append(sim)
            if not _wait(lambda: probe.meta is not None, 30):
                return dict(out, error="no scene metadata")
            n = np.asarray(probe.meta["task"]["push_direction"], dtype=float)
            if not _wait(lambda: any(v @ n > 0 for _, v in probe.cmds), 30):
                return dict(out, error="no approach", result=probe.final())
            approach_t = next(t for t, v in probe.cmds if v @ n > 0)
            if kind == "fault":
                time.sleep(rng.uniform(0.2, 0.8))
                inf.proc.send_signal(signal.SIGKILL)
                out["killed_t"] = time.monotonic()
            _wait(lambda: probe.final() is not None, 30)
            time.sleep(0.5)     # commands after the stop, if any, have had time to arrive
            sim.stop(signal.SIGINT)
        finally:
            for p in procs:
                p.stop(signal.SIGINT)
            probe.close()
        res = probe.final()
        if res is None:
            return dict(out, error="no final result")
        out.update(reason=res["reason"], success=res["success"],
                   stop_after_slip_s=res.get("stop_after_slip_s"))
        # Zero twists before the approach are the settle phase's, not a stop.
        stops = [t for t, v in probe.cmds if t > approach_t and not np.any(v)]
        first_stop = stops[0] if stops else None
        out["moves_after_stop"] = 0 if first_stop is None else \
            sum(1 for t, v in probe.cmds if t > first_stop and np.any(v))
        if "killed_t" in out:
            after = [t for t in stops if t > out["killed_t"]]
            out["stop_after_kill_s"] = after[0] - out["killed_t"] if after else None
        braking = stop_to_rest_s(traj) if traj.is_file() else None
        if braking is not None and out["stop_after_slip_s"] is not None:
            # The scene brakes from the moment the stop reaches it (a local topic: well
            # under a millisecond, neglected here).
            out["at_rest_after_slip_s"] = out["stop_after_slip_s"] + braking
    return out


def _pct(values: list, q: float) -> Optional[float]:
    v = [x for x in values if x is not None]
    return float(np.percentile(v, q)) if v else None


def summarize(episodes: list) -> dict:
    """p50/p99/max of the stop latency and at-rest time (fault episodes), and the number of
    stale-input stops without a fault (load episodes)."""
    fault = [e for e in episodes if e["kind"] == "fault" and "error" not in e]
    load = [e for e in episodes if e["kind"] == "load" and "error" not in e]
    out = {"fault_episodes": len(fault), "load_episodes": len(load),
           "errors": [e for e in episodes if "error" in e]}
    for key in ("stop_after_slip_s", "at_rest_after_slip_s"):
        vals = [e.get(key) for e in fault]
        out[key] = {"p50": _pct(vals, 50), "p99": _pct(vals, 99),
                    "max": max([v for v in vals if v is not None], default=None)}
    out["fault_not_stale"] = [e for e in fault if e.get("reason") not in STALE]
    out["moves_after_stop"] = sum(e.get("moves_after_stop", 0) for e in episodes)

    def early(e) -> bool:       # stopped on a stale input before the approach (no fault yet)
        return e.get("error") == "no approach" and \
            (e.get("result") or {}).get("reason") in STALE
    loaded = [e for e in episodes if e["kind"] == "load"]
    out["false_stops"] = sum(1 for e in loaded if e.get("reason") in STALE or early(e))
    out["false_stops_before_fault"] = sum(1 for e in episodes
                                          if e["kind"] == "fault" and early(e))
    out["load_reasons"] = sorted({str(e.get("reason") or (e.get("result") or {}).get("reason"))
                                  for e in loaded})
    return out


def main(argv: Optional[list] = None) -> int:
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--fault", type=int, default=10, help="fault-injection episodes")
    ap.add_argument("--load", type=int, default=10, help="episodes beside the CPU hogs")
    ap.add_argument("--hogs", type=int, default=2, help="CPU-busy processes in load episodes")
    ap.add_argument("--checkpoint", default=str(ROOT / "models" / "aslip_cnn.pt"))
    ap.add_argument("--slip-timeout", type=float, default=None,
                    help="slip_timeout_s for the controller (default: the node's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="write the episodes and summary (JSON)")
    a = ap.parse_args(argv)
    rng = random.Random(a.seed)
    episodes = []
    for i in range(a.fault):
        episodes.append(run_episode("fault", a.checkpoint, 1201 + i, rng, a.slip_timeout))
        print(json.dumps(episodes[-1]), flush=True)
    from aslip_ros.util import cpu_hogs
    with cpu_hogs(a.hogs if a.load else 0):
        for i in range(a.load):
            episodes.append(run_episode("load", a.checkpoint, 2201 + i, rng, a.slip_timeout))
            print(json.dumps(episodes[-1]), flush=True)
    summary = summarize(episodes)
    summary.update(hogs=a.hogs, slip_timeout_s=a.slip_timeout, load_average=os.getloadavg())
    print(json.dumps(summary, indent=1), flush=True)
    if a.out:
        write_json(a.out, {"summary": summary, "episodes": episodes})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
