"""The simulated acoustic slip scene (ROS-free core).

Usage (docs/design.md, "Scene streaming API")::

    from aslip_ros.scene import scenarios, World
    scn = scenarios.robot_induced(seed=0, object="chips_can", layout="4mic")
    world = World(scn)
    for chunk in world.stream(block_frames=480):
        ...
"""

from . import layouts, physics, scenarios
from .layouts import LAYOUTS, OBJECTS, PADS, get_layout, get_object, get_pad
from .physics import SCENE_VERSION, UNCOUPLED, Acoustics
from .scenario import Scenario
from .world import Chunk, MocapSample, SimArm, World

__all__ = ["SCENE_VERSION", "UNCOUPLED", "layouts", "physics", "scenarios", "LAYOUTS",
           "OBJECTS", "PADS", "get_layout", "get_object", "get_pad", "Acoustics", "Scenario",
           "Chunk", "MocapSample", "SimArm", "World"]
