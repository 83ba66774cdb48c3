"""``robot_sweeps``: robot-induced slip on hardware, the arm sweeping across a clamped probe.

The probe is held still in the world and lightly grasped; this node moves the arm, so the
slip in the grasp plane is minus the TCP velocity and a recording of the run is labelled
from ``/aslip/robot/tcp_pose`` (``aslip export`` with metadata ``induced: robot``). The
sweeps are :class:`aslip_ros.control.sweeps.SweepTask`: the scene's ``robot_sweeps``
statistics from the start TCP pose, in the grasp plane (``grasp_plane_in_tcp``), within
``sweep_radius_m`` of the start, the workspace box and the speed limit; after ``duration_s``
(0 = until the node is stopped) the arm returns to the start and stops.

The arm is chosen by name as in the controllers (:mod:`aslip_ros.nodes.arm_node`, whose
``arm_params`` this node shares): ``xarm`` (default) or ``module.path:factory``. ``sim`` is
refused: in the simulated scene the ``robot_induced`` scenario drives its own arm. The arm
measures its TCP (SDK report stream, or polled on the arm thread) and the node publishes it
on ``/aslip/robot/tcp_pose``, stamped when measured.

Every arm call runs on a thread of its own (:class:`~aslip_ros.control.arm_worker.ArmWorker`).
Lifecycle and safety are the controllers' (:class:`~aslip_ros.nodes.arm_node.ArmNode`):
``configure`` connects (an unreachable arm
leaves the node unconfigured), ``activate`` enables velocity mode and starts from the next
fresh pose; a stale pose stream (a one-shot deadline of ``pose_timeout_s``), any arm error,
``deactivate`` and shutdown stop the arm at once, and no velocity command follows a stop
until the next activation. With ``exit_when_done`` the process exits once the run has
ended (code 0 after a complete run, 1 otherwise), and with code 1 at once when autostart
could not start it (an unreachable arm): a recording must not wait for sweeps that never
come.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

from aslip_ros.control.sweeps import SweepConfig, SweepEnd, SweepState, SweepTask
from aslip_ros.nodes import common as c
from aslip_ros.nodes.arm_node import ArmNode, arm_params, check_arm
from aslip_ros.nodes.arms import LIMIT_PREFIX
from aslip_ros.runtime.process import run_node


def _arm(v) -> Optional[str]:
    if str(v) == "sim":
        return ("sim is not an arm for robot_sweeps: in the simulated scene the "
                "robot_induced scenario drives its own arm (scene_sim scenario:=robot_induced); "
                "use xarm or module.path:factory")
    return check_arm(v)


def sweep_params() -> list:
    """The parameters of ``robot_sweeps``: the arm's (the arm a real one by default), then
    the run's, with their defaults from :class:`~aslip_ros.control.sweeps.SweepConfig`."""
    shared = []
    for p in arm_params():
        if p.name == "arm":
            p = dataclasses.replace(p, default="xarm",
                                    description="xarm or module.path:factory (not sim)",
                                    check=c.Rule(_arm, "xarm, or module.path:factory"))
        shared.append(p)
    return shared + [
        c.from_config(SweepConfig, "seed", "seeds the sweeps (same seed, same sweeps)",
                      c.int_range(0, 2 ** 31 - 1)),
        c.from_config(SweepConfig, "duration_s", "sweeping time before the return to start "
                      "[s]; 0 = until the node is stopped", c.in_range(0.0, 86400.0)),
        c.from_config(SweepConfig, "sweep_radius_m",
                      "the TCP stays within this distance of the start position [m]",
                      c.in_range(0.001, 0.1)),
        c.from_config(SweepConfig, "return_speed_m_s", "speed of the return to start [m/s]",
                      c.in_range(1e-4, 0.1)),
        c.from_config(SweepConfig, "return_tolerance_m",
                      "the return ends this close to the start [m]", c.in_range(1e-4, 0.01)),
        c.from_config(SweepConfig, "return_timeout_s",
                      "a return still under way after this long stops where it is [s]",
                      c.in_range(0.1, 120.0)),
    ]


def sweep_config(p: dict) -> SweepConfig:
    """The core's config from the parameter values (raises ValueError): those named like
    its fields, and the arm's limits (``arm_*``; an empty workspace corner = no box)."""
    kwargs = c.config_kwargs(SweepConfig, p)
    kwargs.update(c.config_kwargs(SweepConfig, p, LIMIT_PREFIX))
    for corner in ("workspace_min_m", "workspace_max_m"):
        if corner in kwargs and not kwargs[corner]:
            kwargs[corner] = None
    return SweepConfig(**kwargs)


def _cross_check(values: dict) -> Optional[str]:
    try:
        sweep_config(values)
    except ValueError as exc:
        return str(exc)
    return None


class RobotSweeps(ArmNode):
    """Sweeps the arm across a clamped probe (threads, lifecycle and safety:
    :class:`~aslip_ros.nodes.arm_node.ArmNode`)."""

    task_name = "robot_sweeps"
    task_word = "run"
    waiting_for = "waiting for a pose"

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("robot_sweeps", sweep_params(), _cross_check, **kwargs)

    def not_started(self) -> None:
        """A recording must not wait for sweeps that never come: exit 1 (exit_when_done)."""
        if self.p["exit_when_done"]:
            self.get_logger().error(f"the sweeps cannot start ({self.arm_error}): exiting "
                                    "with code 1 (exit_when_done)")
            self.exit_code, self.done = 1, True

    def reset_task(self) -> None:
        """At activation: a new run, from the next fresh pose."""
        self.task = SweepTask(sweep_config(self.p))

    def stop_detail(self) -> str:
        """The run's end detail."""
        return self.task.detail if self.task is not None else ""

    def control_step(self) -> None:
        """Start the run from a fresh pose, then step it; the end of the run."""
        with self._lock:
            if not self.active or self.worker is None or self.task is None:
                return
            now = self.now_s()
            task = self.task
            if task.state is SweepState.IDLE:
                if not self._pose_fed:
                    return
                try:
                    task.start(now=now)
                except RuntimeError:
                    return            # no fresh pose yet: next cycle
                except ValueError as exc:
                    task.fault(str(exc), now=now)
                else:
                    start = [round(float(x), 4) for x in task.start_pose[:3]]
                    self.get_logger().info(
                        f"sweeping from {start} m (link_base), seed {self.p['seed']}, "
                        f"radius {self.p['sweep_radius_m']} m, "
                        + (f"{self.p['duration_s']} s" if self.p["duration_s"] > 0
                           else "until stopped"))
            self.post(task.step(now))
            if task.state is SweepState.STOPPED and not self.done and \
                    self.p["exit_when_done"]:
                self.exit_code = 0 if task.end_reason is SweepEnd.DONE else 1
                self.done = True

    def diagnostic_values(self) -> dict:
        """The run's state, sweeps, offsets and end; the pose input (no slip here)."""
        values = {}
        task = self.task
        if task is not None:
            values.update(task_state=task.state.value, sweeps=task.sweeps,
                          offset_mm=task.offset_m() * 1e3,
                          max_offset_mm=task.max_offset_m * 1e3)
            if task.end_reason is not None:
                values.update(end_reason=task.end_reason.value, end_detail=task.detail)
        values.update({k: v for k, v in self.inputs.values().items()
                       if not k.startswith("slip_")})
        return values

    def diagnostic_level(self, values: dict):
        """A run that ended other than done is a warning."""
        if values.get("end_reason") not in (None, SweepEnd.DONE.value):
            return c.Diagnostics.WARN, f"stopped: {values['end_reason']}"
        return super().diagnostic_level(values)


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros robot_sweeps``."""
    return run_node(RobotSweeps, args)


if __name__ == "__main__":
    raise SystemExit(main())
