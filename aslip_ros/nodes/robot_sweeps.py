"""``robot_sweeps``: robot-induced slip on hardware, the arm sweeping across a clamped probe.

The probe is held still in the world and lightly grasped; this node moves the arm, so the
slip in the grasp plane is minus the TCP velocity and a recording of the run is labelled
from ``/aslip/robot/tcp_pose`` (``aslip export`` with metadata ``induced: robot``). The
sweeps are :class:`aslip_ros.control.sweeps.SweepTask`: the scene's ``robot_sweeps``
statistics from the start TCP pose, in the grasp plane (``grasp_plane_in_tcp``), within
``sweep_radius_m`` of the start, the workspace box and the speed limit; after ``duration_s``
(0 = until the node is stopped) the arm returns to the start and stops.

The arm is chosen by name as in the controllers (:mod:`aslip_ros.nodes.controller`, whose
``arm_params`` this node shares): ``xarm`` (default) or ``module.path:factory``. ``sim`` is
refused: in the simulated scene the ``robot_induced`` scenario drives its own arm. The arm
measures its TCP (SDK report stream, or polled on the arm thread) and the node publishes it
on ``/aslip/robot/tcp_pose``, stamped when measured.

Every arm call runs on a thread of its own (:class:`~aslip_ros.control.arm_worker.ArmWorker`).
Lifecycle and safety as in the controllers: ``configure`` connects (an unreachable arm
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
import threading
import time
from typing import Optional

from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn

from aslip_ros import frames
from aslip_ros.arm import ArmError
from aslip_ros.control.command import VelocityCommand
from aslip_ros.control.sweeps import SweepConfig, SweepEnd, SweepState, SweepTask
from aslip_ros.control.watchdog import ArrivalStats
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import ready, run_node
from aslip_ros.runtime.qos import SENSOR_QOS
from aslip_ros.nodes import convert
from aslip_ros.nodes.arm_link import OPEN_ERRORS, close_arm, open_arm
from aslip_ros.nodes.arms import LIMIT_PREFIX, resolve_arm
from aslip_ros.nodes.controller import arm_params

#: The controllers' parameters that have nothing to act on here: no slip input, no model
#: to recalibrate. The rest (arm choice and limits, rates, timeouts) are shared.
#: The controllers' parameters that robot_sweeps has no use for (it runs on the wall clock:
#: no lockstep mode).
_SLIP_ONLY = ("slip_timeout_s", "slip_topic", "start_after_messages", "recalibrate_service",
              "lockstep")


def _arm(v) -> Optional[str]:
    if str(v) == "sim":
        return ("sim is not an arm for robot_sweeps: in the simulated scene the "
                "robot_induced scenario drives its own arm (scene_sim scenario:=robot_induced); "
                "use xarm or module.path:factory")
    try:
        resolve_arm(str(v))
    except ValueError as exc:
        return str(exc)
    return None


def sweep_params() -> list:
    """The parameters of ``robot_sweeps``: the controllers' arm parameters that apply (the
    arm a real one by default), then the run's, with their defaults from
    :class:`~aslip_ros.control.sweeps.SweepConfig`."""
    shared = []
    for p in arm_params():
        if p.name in _SLIP_ONLY:
            continue
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


class RobotSweeps(LifecycleNode):
    """Sweeps the arm across a clamped probe.

    Threads as in the controllers: the executor's dispatch thread runs the control timer
    and the pose deadline (and the TCP subscription of an arm fed from the topic); an
    ArmWorker thread does every arm call and polls the pose; an SDK thread may deliver
    poses. ``_lock`` guards the task and is never held across arm I/O.
    """

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("robot_sweeps", **kwargs)
        self.p = c.declare_params(self, sweep_params(), self._on_change, _cross_check)
        self._lock = threading.Lock()
        self.arm = None
        self.worker = None
        self.task: Optional[SweepTask] = None
        self.active = False
        self.done = False
        self.exit_code = 0
        self.arm_error = ""
        self.last_pose_t: Optional[float] = None
        self.inputs = ArrivalStats()
        self._stop_logged = False
        self._pose_fed = False
        self.diag = c.Diagnostics(self, "aslip: robot_sweeps", self.p["arm"])
        self.arm_kind = resolve_arm(self.p["arm"])
        self.pub_tcp = None
        if self.arm_kind.pose_from_topic:
            self.create_subscription(PoseStamped, c.TCP_TOPIC, self._on_tcp, SENSOR_QOS)
        else:
            self.pub_tcp = self.create_publisher(PoseStamped, c.TCP_TOPIC, SENSOR_QOS)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(1.0 / self.p["control_rate_hz"], self._control, clock=steady)
        # Re-armed by every pose: a silent pose stream stops the arm when it goes stale.
        self._pose_deadline = self.create_timer(self.p["pose_timeout_s"], self._on_deadline,
                                                clock=steady, autostart=False)
        self.create_timer(1.0, self._diagnose)
        if self.p["autostart"]:
            self.trigger_configure()
            if self.arm is not None:
                self.trigger_activate()
            if not self.active and self.p["exit_when_done"]:
                self.get_logger().error(f"the sweeps cannot start ({self.arm_error}): exiting "
                                        "with code 1 (exit_when_done)")
                self.exit_code, self.done = 1, True
        ready(self, f"robot_sweeps, arm {self.p['arm']}, "
                    f"{'active' if self.active else 'not active'}")

    # -- lifecycle ---------------------------------------------------------------------------

    def on_configure(self, state) -> TransitionCallbackReturn:
        """Create and connect the arm; an unreachable arm fails the transition."""
        try:
            arm, worker = open_arm(self, self.arm_kind, self.p, self._on_arm_pose,
                                   self._on_arm_error, "robot_sweeps-arm-io")
        except OPEN_ERRORS as exc:
            self.arm_error = f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"arm not available ({self.arm_error}); the node stays "
                                    "unconfigured and commands nothing")
            self._diagnose()
            return TransitionCallbackReturn.FAILURE
        self.worker = worker
        self.arm = arm
        self.arm_error = ""
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        """Enable velocity mode; the run starts at the next control cycle with a fresh pose."""
        try:
            self.arm.enable_velocity_mode()
        except ArmError as exc:
            self.arm_error = str(exc)
            self.get_logger().error(f"cannot enable velocity mode: {exc}")
            return TransitionCallbackReturn.FAILURE
        with self._lock:
            self.task = SweepTask(sweep_config(self.p))
            self._pose_fed = False
            self._stop_logged = False
            self.active = True
            self.worker.rearm()
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        """Stop the arm and the run."""
        self._halt("deactivated")
        with self._lock:
            self.active = False
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        """Release the arm."""
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        """Stop and release the arm."""
        self.before_shutdown()
        return TransitionCallbackReturn.SUCCESS

    def before_shutdown(self) -> None:
        """Process exit: stop the run and the arm while the context still works."""
        self._halt("shutdown")
        self._release()

    # -- internals -----------------------------------------------------------------------------

    def _post(self, command: Optional[VelocityCommand]) -> None:
        """Hand a command to the arm thread (never blocks on the arm); ``_lock`` held."""
        if command is None or self.worker is None:
            return
        if command.stop and not self._stop_logged:
            self._stop_logged = True
            detail = self.task.detail if self.task is not None else ""
            self.get_logger().info(f"stopping the arm: {command.reason}"
                                   f"{' (' + detail + ')' if detail else ''}")
        self.worker.post(command)

    def _halt(self, why: str) -> None:
        with self._lock:
            task, worker = self.task, self.worker
            if task is not None:
                task.shutdown()
                self._post(task.step())
            if worker is not None:
                self._post(VelocityCommand.halt(why))
        if worker is not None and not worker.flush(2.0):
            self.get_logger().error(f"arm stop not confirmed within 2 s ({why})")

    def _release(self) -> None:
        with self._lock:
            arm, self.arm = self.arm, None
            worker, self.worker = self.worker, None
            self.active = False
        close_arm(arm, worker, self.get_logger())

    def _on_change(self, changed: dict) -> None:
        self.p.update(changed)
        self.get_logger().info(f"parameters changed: {changed}; they apply to the next run "
                               "(re-activate the node)")

    def _on_tcp(self, msg: PoseStamped) -> None:
        """An arm fed from the topic (an ArmKind with ``pose_from_topic``)."""
        try:
            stamp_ns, _, pose = convert.pose_from_msg(msg)
        except ValueError:
            return
        arm = self.arm
        if arm is not None:
            arm.set_pose(pose)
        self._take_pose(pose, time.monotonic())

    def _on_arm_pose(self, pose, now: float, stamp_ns: int) -> None:
        """A pose measured by the arm itself (report stream or poll), stamped when taken."""
        pub = self.pub_tcp
        if pub is not None:
            pub.publish(convert.pose_to_msg(pose, stamp_ns, frames.BASE))
        self._take_pose(pose, now)

    def _take_pose(self, pose, now: float) -> None:
        self._pose_deadline.reset()
        with self._lock:
            self.inputs.pose(now, self.last_pose_t)
            self.last_pose_t = now
            if self.task is not None:
                self._pose_fed = self.task.on_tcp_pose(pose, now) or self._pose_fed

    def _on_deadline(self) -> None:
        """The pose stream went silent: a control step now (the task finds it stale)."""
        self._pose_deadline.cancel()
        self._control()

    def _on_arm_error(self, exc) -> None:
        """Arm thread: an arm call failed (the worker has latched and tried a stop)."""
        self.arm_error = str(exc)
        self.get_logger().error(f"arm error, stopping: {exc}")
        with self._lock:
            if self.task is not None:
                self.task.fault(str(exc))
                self._post(self.task.step())

    def _control(self) -> None:
        with self._lock:
            if not self.active or self.worker is None or self.task is None:
                return
            now = time.monotonic()
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
            self._post(task.step(now))
            if task.state is SweepState.STOPPED and not self.done and \
                    self.p["exit_when_done"]:
                self.exit_code = 0 if task.end_reason is SweepEnd.DONE else 1
                self.done = True

    def _diagnose(self) -> None:
        state = getattr(self, "_state_machine", None)
        label = state.current_state[1] if state is not None else "?"
        values = {"lifecycle": label, "arm": self.p["arm"]}
        values.update(self.arm_kind.describe(self.p))
        with self._lock:
            task = self.task
            if task is not None:
                values.update(task_state=task.state.value, sweeps=task.sweeps,
                              offset_mm=task.offset_m() * 1e3,
                              max_offset_mm=task.max_offset_m * 1e3)
                if task.end_reason is not None:
                    values.update(end_reason=task.end_reason.value, end_detail=task.detail)
            values.update(self.inputs.values())
            worker = self.worker
        values = {k: v for k, v in values.items() if not k.startswith("slip_")}
        if worker is not None:
            values.update(arm_commands_sent=worker.sent,
                          arm_commands_dropped_after_stop=worker.dropped_after_stop)
        if self.arm_error:
            level, message = c.Diagnostics.ERROR, f"arm error: {self.arm_error}"
        elif not self.active:
            level, message = c.Diagnostics.WARN, "not active"
        elif values.get("end_reason") not in (None, SweepEnd.DONE.value):
            level, message = c.Diagnostics.WARN, f"stopped: {values['end_reason']}"
        else:
            level, message = c.Diagnostics.OK, values.get("task_state", "waiting for a pose")
        self.diag.publish(level, message, values)


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros robot_sweeps``."""
    return run_node(RobotSweeps, args)


if __name__ == "__main__":
    raise SystemExit(main())
