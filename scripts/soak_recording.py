"""Soak: data-collection recordings whose nodes start in random order; every bag must hold
its metadata.

    make soak-recording                  # 50 recordings beside 2 CPU hogs
    make soak-recording SOAK=10 HOGS=0

Each recording is the simulated data-collection graph (scene_sim with a finite
``duration_s``, mocap_bridge reading the grasp-plane calibration from the metadata, and the
package's bag_recorder with its default topics), started one node at a time in a random
order with random pauses, on a ROS domain of its own, while ``HOGS`` busy loops compete
for the cores. When the scene has run its duration the recorder and the bridge get SIGINT
(as the launch's end does) and the bag is read back. A recording fails when the bag is
missing, has no metadata, or has no audio. Prints one line per recording and the count;
exit status 1 on any failure.
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from aslip_ros.data.bags import BagReader
from aslip_ros.runtime.child import NodeProcess
from aslip_ros import topics
from aslip_ros.util import cpu_hogs

DURATION_S = 6.0
#: Longest pause between two node starts [s]: with the nodes' start-up, the recorder is
#: still ready within the scene's DURATION_S in every order.
MAX_PAUSE_S = 1.0


def record_once(workdir: Path, rng: random.Random, domain: int) -> tuple[bool, str]:
    bag = workdir / "bag"
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    specs = {
        "scene_sim": {"scenario": "external_induced", "duration_s": DURATION_S,
                      "exit_when_done": True, "seed": rng.randrange(1000)},
        "mocap_bridge": {"calibration": "metadata"},
        "bag_recorder": {"output": str(bag)},
    }
    order = list(specs)
    rng.shuffle(order)
    procs = {}
    try:
        for name in order:
            procs[name] = NodeProcess(name, env, specs[name])
            time.sleep(rng.uniform(0.0, MAX_PAUSE_S))
        for name in order:
            procs[name].wait_ready(60.0)
        procs["scene_sim"].proc.wait(timeout=120)
        for name in ("bag_recorder", "mocap_bridge"):
            procs[name].proc.send_signal(2)
        rc = procs["bag_recorder"].proc.wait(timeout=60)
    except (AssertionError, subprocess.TimeoutExpired) as exc:
        return False, f"order {order}: {exc}"
    finally:
        for p in procs.values():
            p.stop()
    if rc != 0 or not bag.is_dir():
        return False, f"order {order}: no bag (recorder exit {rc})"
    with BagReader(bag) as r:
        counts = dict(r.info.counts)
        meta = r.read_metadata()
    ok = bool(meta) and counts.get(topics.AUDIO, 0) > 0
    return ok, (f"order {' -> '.join(order)}: metadata {'yes' if meta else 'MISSING'}, "
                f"{counts.get(topics.AUDIO, 0)} audio blocks")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--launches", type=int, default=50)
    ap.add_argument("--hogs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    from domain_coordinator import domain_id
    rng = random.Random(a.seed)
    failed = 0
    t0 = time.monotonic()
    with cpu_hogs(a.hogs):
        for k in range(a.launches):
            work = Path(tempfile.mkdtemp(prefix="aslip_soak_"))
            try:
                with domain_id() as did:
                    ok, line = record_once(work, rng, did)
            finally:
                shutil.rmtree(work, ignore_errors=True)
            failed += not ok
            print(f"{k + 1:3d} {'ok  ' if ok else 'FAIL'} {line}", flush=True)
    print(f"{a.launches - failed} of {a.launches} recordings with metadata and audio, "
          f"{failed} failed, beside {a.hogs} CPU hogs, {time.monotonic() - t0:.0f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
