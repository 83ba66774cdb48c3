"""The parameters that describe a simulated scene, shared by ``scene_sim`` and the ``sim``
source of ``audio_capture`` (the world itself is built by
:func:`aslip_ros.hw.sources.build_world`)."""

from __future__ import annotations

from aslip_ros.hw.sources import CONDITIONS, NO_VARIANT, SCENARIOS
from aslip_ros.nodes import common as c

#: The pivot's lever arm by default [m]: an object held 10 cm from where it meets the surface.
PIVOT_LEVER_M = 0.1


def scene_params(prefix: str = "") -> list:
    """Parameter specs describing a scene, each name preceded by ``prefix``; the defaults
    are :class:`~aslip_ros.scene.scenarios.Scenario`'s (``wall_distance_m`` excepted: 0, the
    object starts in contact with the wall)."""
    from aslip_ros.scene import LAYOUTS, OBJECTS, PADS
    from aslip_ros.scene.scenario import Scenario
    from aslip_ros.scene.variants import VARIANTS
    return [
        c.Param(prefix + "scenario", "external_induced",
                f"scene task: {', '.join(SCENARIOS)}", c.one_of(*SCENARIOS), read_only=True),
        c.Param(prefix + "seed", 0, "scenario seed (deterministic)",
                c.at_least(0), read_only=True),
        c.from_config(Scenario, "object", "grasped object", c.one_of(*OBJECTS),
                      read_only=True, prefix=prefix),
        c.from_config(Scenario, "layout", "microphone layout", c.one_of(*LAYOUTS),
                      read_only=True, prefix=prefix),
        c.from_config(Scenario, "pad", "finger pad", c.one_of(*PADS), read_only=True,
                      prefix=prefix),
        c.from_config(Scenario, "condition", "robot condition (external_induced only; the "
                      "others imply robot_moving)", c.one_of(*CONDITIONS), read_only=True,
                      prefix=prefix),
        c.from_config(Scenario, "sample_rate", "audio sample rate [Hz]",
                      c.in_range(8000.0, 192000.0), read_only=True, prefix=prefix),
        c.Param(prefix + "wall_distance_m", 0.0,
                "wall_push: wall distance ahead of the object [m] (0 = start in contact)",
                c.non_negative, read_only=True),
        c.Param(prefix + "pivot_lever_m", PIVOT_LEVER_M,
                "pivot: where the surface below meets the object, along the fingers from "
                "the grasp axis [m]", c.in_range(0.02, 0.5), read_only=True),
        c.from_config(Scenario, "drag_speed_m_s", "drag: agent drag speed [m/s]", c.positive,
                      read_only=True, prefix=prefix),
        c.from_config(Scenario, "drag_hold_s", "drag: the agent holds the object still this "
                      "long after the grasp before its first pull [s]",
                      c.in_range(0.0, 60.0), read_only=True, prefix=prefix),
        c.Param(prefix + "variant", NO_VARIANT,
                f"held-out scene variant (docs/scene.md, \"Variants\"): {NO_VARIANT} = the "
                f"default scene; {', '.join(VARIANTS)}", c.one_of(NO_VARIANT, *VARIANTS),
                read_only=True),
        c.Param(prefix + "robot_noise_x", 1.0,
                "the arm's operating noise this many times as loud as the scene's "
                "(Acoustics.robot_level; after the variant)", c.in_range(0.0, 100.0),
                read_only=True),
    ]
