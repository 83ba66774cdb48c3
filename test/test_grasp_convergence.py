"""The per-grasp calibration of the shipped estimator converges at the grasp: within the 2 s
bound on scene grasps (held still for the calibration, as grasp_calibration asks), through
the same live estimator the node runs, and with no slip needed."""

from __future__ import annotations

from pathlib import Path

import pytest

from aslip_ros.audio_frame import AudioData
from aslip_ros.learn.inference.live import (UNCONVERGED_DIRECTION_SIGMA, LiveConfig,
                                            LiveEstimator)
from aslip_ros.scene import World
from aslip_ros.scene import scenarios as sc

ROOT = Path(__file__).resolve().parents[1]
CHECKPOINT = ROOT / "models" / "aslip_stream.pt"
BOUND_S = 2.0          # issue #26: converged within 2 s of a new grasp
HOLD_S = 1.0           # the demo's hold at the grasp (benchmarks.demo_episode.TrackSettings)


def _blocks(world: World, seconds: float, block: int = 480):
    fs = world.fs
    names = list(world.layout.channel_names)
    for i in range(int(seconds * fs) // block):
        chunk = world.step(block)
        yield AudioData(i * block, 1_000_000_000 + int(i * block / fs * 1e9), fs, names,
                        world.scenario.layout, "aslip_sensor", chunk.audio)


@pytest.mark.parametrize("obj", ["pla_rod", "glass_cleaner", "chips_can",
                                 "mustard_container", "cracker_box"])
def test_the_shipped_estimator_converges_within_the_bound_on_a_held_scene_grasp(obj):
    est = LiveEstimator.from_checkpoint(CHECKPOINT, LiveConfig())
    world = World(sc.external_drag(seed=4242, object=obj, drag_hold_s=HOLD_S))
    sigmas, converged_at = [], None
    for a in _blocks(world, BOUND_S + 0.2):
        for e in est.feed(a):
            sigmas.append(e.direction_sigma)
        if converged_at is None and est.calibration_converged:
            converged_at = est.predictor.calibration_summary()["calibration_converged_after_s"]
    assert converged_at is not None and converged_at <= BOUND_S, (obj, converged_at)
    assert any(e.kind == "converged" for e in est.take_events())
    # Until then the estimates say they know no direction; after it, they do.
    assert sigmas[0] == UNCONVERGED_DIRECTION_SIGMA and sigmas[-1] < UNCONVERGED_DIRECTION_SIGMA
