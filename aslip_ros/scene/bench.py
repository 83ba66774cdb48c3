"""Speed and memory of scene generation: ``python -m aslip_ros.scene.bench``.

Speed is simulated seconds per second of this process's CPU time (one thread: run with
``OMP_NUM_THREADS=1``), so other load on a shared machine does not distort it. Memory is
the peak of Python allocations (tracemalloc) while streaming, which is what grows if
something keeps whole recordings; numpy reports its buffers to tracemalloc.
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc

from . import scenarios
from .layouts import DEFAULT_LAYOUT
from .world import World


def measure(duration_s: float = 60.0, layout: str = DEFAULT_LAYOUT, block_frames: int = 480,
            kind: str = "external_induced", condition: str = "robot_moving",
            seed: int = 0, trace_memory: bool = True) -> dict[str, float]:
    """Stream one trial and return ``x_real_time``, ``cpu_s``, ``wall_s``, ``peak_mib``.

    Only chunk sizes are touched, so nothing but the generator's own state is held.
    """
    if not duration_s > 0:
        raise ValueError(f"duration_s must be positive, got {duration_s!r}")
    make = getattr(scenarios, kind, None)
    if kind not in ("robot_induced", "external_induced") or make is None:
        raise ValueError(f"kind must be robot_induced or external_induced, got {kind!r}")
    scn = make(seed=seed, layout=layout, condition=condition, duration_s=duration_s)
    if trace_memory:
        tracemalloc.start()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    world = World(scn)
    n = 0
    for chunk in world.stream(block_frames=block_frames):
        n += chunk.audio.shape[0]
    cpu = time.process_time() - cpu0
    wall = time.perf_counter() - wall0
    peak = 0.0
    if trace_memory:
        peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
        tracemalloc.stop()
    sim_s = n / scn.sample_rate
    return {"sim_s": sim_s, "cpu_s": cpu, "wall_s": wall, "x_real_time": sim_s / cpu,
            "x_real_time_wall": sim_s / wall, "peak_mib": peak}


def main(argv: list[str] | None = None) -> None:
    """Print speed (x real time) and peak traced memory for each scenario kind."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--layout", default=DEFAULT_LAYOUT)
    args = parser.parse_args(argv)
    for kind, cond in (("external_induced", "robot_moving"),
                       ("external_induced", "robot_off"), ("robot_induced", "robot_moving")):
        speed = measure(args.duration, args.layout, kind=kind, condition=cond,
                        trace_memory=False)
        mem = measure(min(args.duration, 20.0), args.layout, kind=kind, condition=cond)
        print(f"{kind:17s} {cond:16s} {args.layout}: {speed['x_real_time']:5.1f}x real time "
              f"(CPU), {speed['x_real_time_wall']:5.1f}x (wall), peak traced memory "
              f"{mem['peak_mib']:.1f} MiB", flush=True)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process peak RSS (interpreter, numpy, scipy included): {rss:.0f} MiB")


if __name__ == "__main__":
    main()
