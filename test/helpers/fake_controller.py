"""A test-only controller: what a new controller is (docs/design.md, "A new controller").

``Creep`` is the control law (ROS-free, like control/slip_stop.py): once started it creeps
the TCP along ``direction`` at ``speed_m_s`` until the slip estimates say slipping, then
stops for good. ``CreepNode`` is its node on the controllers' shell (arm, watchdogs,
lifecycle, diagnostics). ``ROW`` is its row of the node table, which its launch file
registers (test_extension_controller.py). Nothing of the package changes for it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Optional

import numpy as np

from aslip_ros.control.command import VelocityCommand
from aslip_ros.node_table import NodeSpec
from aslip_ros.nodes import common as c
from aslip_ros.nodes.controller import ControllerNode
from aslip_ros.runtime.process import run_node

ROW = NodeSpec("test_creep", "fake_controller", "CreepNode", drives_arm=True,
               default_model="svm.pt")


class CreepState(enum.Enum):
    IDLE = "idle"
    CREEPING = "creeping"
    STOPPED = "stopped"


@dataclass(frozen=True)
class CreepConfig:
    speed_m_s: float = 0.005
    command_duration_s: float = 0.1


class Creep:
    """Creep until slip, then stop (a latched stop, as every controller's)."""

    def __init__(self, config: CreepConfig, direction) -> None:
        self.config = config
        self.direction = np.asarray(direction, float) / np.linalg.norm(direction)
        self.state = CreepState.IDLE
        self.reason = ""
        self._halted = False

    def start(self, now: Optional[float] = None) -> None:
        self.state = CreepState.CREEPING

    def on_slip(self, slipping: bool) -> None:
        if slipping and self.state is CreepState.CREEPING:
            self._stop("slip")

    def on_tcp_pose(self, pose, now: Optional[float] = None) -> None:
        pass

    def fault(self, detail: str = "", now: Optional[float] = None) -> None:
        self._stop(f"fault: {detail}")

    def shutdown(self, now: Optional[float] = None) -> None:
        self._stop("shutdown")

    def _stop(self, reason: str) -> None:
        if self.state is not CreepState.STOPPED:
            self.state, self.reason = CreepState.STOPPED, reason

    def step(self, now: Optional[float] = None) -> Optional[VelocityCommand]:
        if self.state is CreepState.CREEPING:
            return VelocityCommand(self.config.speed_m_s * self.direction,
                                   self.config.command_duration_s)
        if self.state is CreepState.STOPPED and not self._halted:
            self._halted = True
            return VelocityCommand.halt(self.reason)
        return None


class CreepNode(ControllerNode):
    """The test controller's node: its parameters and the law's inputs."""

    task_name = "test_creep"

    def __init__(self, **kwargs) -> None:
        super().__init__("test_creep", **kwargs)

    def task_params(self) -> list:
        return [
            c.from_config(CreepConfig, "speed_m_s", "creep speed [m/s]", c.in_range(0.0, 0.05)),
            c.Param("direction", [1.0, 0.0, 0.0], "creep direction in link_base", c.vector3()),
        ]

    def make_task(self):
        return Creep(CreepConfig(self.p["speed_m_s"], self.p["command_duration_s"]),
                     self.p["direction"])

    def start_task(self, now: float) -> bool:
        self.task.start(now)
        self.get_logger().info(f"creeping with arm {self.p['arm']}, at most "
                               f"{self.p['arm_max_speed_m_s']:g} m/s")
        return True

    def feed_slip(self, slip, now: float) -> None:
        self.task.on_slip(bool(slip.slipping))

    def status(self) -> dict:
        return {"stop_reason": self.task.reason} if self.task is not None else {}


def main(args: Optional[list] = None) -> int:
    return run_node(CreepNode, args)
