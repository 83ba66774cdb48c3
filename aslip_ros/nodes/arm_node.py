"""The lifecycle shell of every node that drives an arm: the controllers
(:mod:`.controller`: ``slip_stop``, ``slip_track``) and ``robot_sweeps``.

Written once here: the arm's parameters, the arm chosen by name from :mod:`.arms` and
opened on its own thread (:mod:`.arm_link`), the TCP pose (from the topic, or measured by
the arm and republished on ``/aslip/robot/tcp_pose``, stamped when measured), the control
clock and the stale-pose deadline, the lifecycle transitions, halt and release, parameter
changes, and the diagnostics' frame. A subclass brings its task: its parameters, how a
task starts and steps (:meth:`ArmNode.control_step`), what its diagnostics add.

Safety, the same for every subclass: ``configure`` connects the arm (an unreachable arm
fails the transition and nothing moves), ``activate`` enables velocity mode, ``deactivate``,
``cleanup``, ``shutdown`` and the process's signals (``before_shutdown``, called by
``run_node``) stop the arm; a stale pose stream, any arm error and shutdown stop it at once,
and no velocity command follows a stop until the next activation (the
:class:`~aslip_ros.control.arm_worker.ArmWorker` latches the stop). Parameters are
validated when declared and when changed (:func:`~aslip_ros.nodes.common.declare_params`),
and a change applies to the next task.

Time: the steady clock, or, for a node with a ``lockstep`` parameter set, the simulated
time on ``/clock``: one control step per tick and no timer of its own (docs/nodes.md,
"Lockstep").
"""

from __future__ import annotations

import threading
import time
from typing import Optional

from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rosgraph_msgs.msg import Clock as ClockMsg

from aslip_ros import frames, poses, topics
from aslip_ros.arm import ArmError
from aslip_ros.control.command import DEFAULT_DURATION_S, VelocityCommand
from aslip_ros.control.limits import ArmLimits
from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S, ArrivalStats
from aslip_ros.hw.xarm_config import XArmConfig
from aslip_ros.nodes import common as c
from aslip_ros.nodes import convert
from aslip_ros.nodes.arm_link import OPEN_ERRORS, close_arm, open_arm
from aslip_ros.nodes.arms import ARMS, LIMIT_PREFIX, resolve_arm
from aslip_ros.runtime.process import ready
from aslip_ros.runtime.qos import CLOCK_QOS, SENSOR_QOS

IDENTITY = [float(x) for x in poses.IDENTITY_POSE]


def limit_params() -> list:
    """The speed and workspace limits of every arm but ``sim`` (the scene limits its own),
    their defaults :class:`~aslip_ros.control.limits.ArmLimits`'."""
    return [
        c.from_config(ArmLimits, "max_speed_m_s", "TCP speed limit of the xArm and of "
                      "module.path arms [m/s]", c.in_range(1e-4, 1.0), read_only=True,
                      prefix=LIMIT_PREFIX),
        c.from_config(ArmLimits, "max_acc_m_s2", "limit on the change of the commanded TCP "
                      "velocity of the xArm and of module.path arms [m/s^2] (a stop is never "
                      "delayed by it)", c.in_range(1e-3, 50.0), read_only=True,
                      prefix=LIMIT_PREFIX),
        c.from_config(ArmLimits, "workspace_min_m", "workspace lower corner of the xArm and "
                      "of module.path arms (link_base) [m]", c.vector3(allow_empty=True),
                      read_only=True, prefix=LIMIT_PREFIX),
        c.from_config(ArmLimits, "workspace_max_m", "workspace upper corner of the xArm and "
                      "of module.path arms (link_base) [m]", c.vector3(allow_empty=True),
                      read_only=True, prefix=LIMIT_PREFIX),
    ]


def arm_params() -> list:
    """Parameters that choose and limit the arm and run it (every arm node's)."""
    return [
        c.Param("arm", "sim", "sim (scene_sim over topics), xarm, or module.path:factory",
                c.Rule(check_arm, _ARM_CHOICES), read_only=True),
        c.Param("xarm_ip", "192.168.1.222", "xArm controller IP", c.non_empty, read_only=True),
        c.from_config(XArmConfig, "connect_timeout_s", "xArm unreachable after this long [s]",
                      c.in_range(0.1, 60.0), read_only=True, prefix="xarm_"),
    ] + limit_params() + [
        c.Param("control_rate_hz", 100.0, "control loop rate [Hz]", c.in_range(1.0, 250.0),
                read_only=True),
        c.Param("pose_timeout_s", DEFAULT_TIMEOUT_S, "stop when no TCP pose for this long [s]",
                c.in_range(1e-3, 1.0)),
        c.Param("command_duration_s", DEFAULT_DURATION_S,
                "each velocity command expires on the arm after this long [s]",
                c.in_range(0.005, 0.5)),
        c.Param("grasp_plane_in_tcp", list(IDENTITY),
                "grasp-plane pose in the TCP frame (x y z qx qy qz qw) [m]", c.pose7),
        c.Param("autostart", True, "configure and activate at start", read_only=True),
        c.Param("exit_when_done", False, "exit once the task has ended", read_only=True),
    ]


_ARM_CHOICES = f"one of {', '.join(ARMS)}, or module.path:factory"


def check_arm(v) -> Optional[str]:
    """Error text when ``v`` names no arm (:func:`~aslip_ros.nodes.arms.resolve_arm`)."""
    try:
        resolve_arm(str(v))
    except ValueError as exc:
        return str(exc)
    return None


def rearm(deadline) -> None:
    """Restart a stale-input deadline (none in lockstep: each tick judges staleness)."""
    if deadline is not None:
        deadline.reset()


class ArmNode(LifecycleNode):
    """Lifecycle shell of a node that drives an arm. Subclasses provide ``control_step``
    and, as they need, the hooks below (``create_inputs``, ``reset_task``, ``feed_pose``,
    ``stop_inputs``, ``stop_detail``, ``diagnostic_values``, ``diagnostic_level``,
    ``not_started``).

    Threads: the executor's one dispatch thread runs the input callbacks, the control timer
    (or ``/clock`` ticks) and the deadline timers; an
    :class:`~aslip_ros.control.arm_worker.ArmWorker` thread does every arm call; an arm's
    SDK thread may deliver poses. ``_lock`` guards the task and the input bookkeeping and is
    never held across arm I/O.
    """

    #: The node's task, in its log and ready lines.
    task_name = "arm node"
    #: What a parameter change applies to: the next ``task_word``.
    task_word = "task"
    #: The diagnostics' message while active and the task has no state yet.
    waiting_for = "waiting for inputs"

    def __init__(self, name: str, specs: list, cross_check=None, **kwargs) -> None:
        """``specs``: the node's parameters (:func:`arm_params` and its task's);
        ``cross_check(values)``: error text when they do not combine; ``kwargs`` go to
        ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__(name, **kwargs)
        self.p = c.declare_params(self, specs, self._on_change, cross_check)
        self.lockstep = bool(self.p.get("lockstep", False))
        self._sim_now = 0.0            # lockstep: the newest /clock tick [s]
        self.control_steps = 0         # lockstep: ticks handled
        self.pose_count = 0            # TCP pose messages received (valid or not)
        self._lock = threading.Lock()
        self.arm = None
        self.worker = None
        self.task = None
        self.active = False
        self.done = False
        self.exit_code = 0
        self.arm_error = ""
        self.last_pose_t: Optional[float] = None
        self.inputs = ArrivalStats(self.now_s if self.lockstep else time.time)
        self._stop_report: Optional[dict] = None
        self._pose_fed = False
        self.diag = c.Diagnostics(self, f"aslip: {name}", self.p["arm"])
        self.arm_kind = resolve_arm(self.p["arm"])
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.pub_tcp = None
        # One dispatch thread (runtime.process._executor): callback groups would change nothing.
        self.create_inputs()
        if self.arm_kind.pose_from_topic:
            self.create_subscription(PoseStamped, c.TCP_TOPIC, self._on_tcp, SENSOR_QOS)
        else:
            self.pub_tcp = self.create_publisher(PoseStamped, c.TCP_TOPIC, SENSOR_QOS)
        if self.lockstep:
            # Every tick is a control step, which also judges staleness (no deadlines).
            self.create_subscription(ClockMsg, topics.CLOCK, self._on_clock, CLOCK_QOS)
        else:
            self.create_timer(1.0 / self.p["control_rate_hz"], self.control_step,
                              clock=self._steady)
        self._pose_deadline = self.deadline(self.p["pose_timeout_s"])
        self.create_timer(1.0, self._diagnose)
        if self.p["autostart"]:
            self.trigger_configure()
            if self.arm is not None:
                self.trigger_activate()
            if not self.active:
                self.not_started()
        ready(self, f"{self.task_name}, arm {self.p['arm']}, "
                    f"{'active' if self.active else 'not active'}")

    # -- time --------------------------------------------------------------------------------

    def now_s(self) -> float:
        """The node's monotonic time [s]: steady, or the newest ``/clock`` tick in lockstep."""
        return self._sim_now if self.lockstep else time.monotonic()

    def _on_clock(self, msg: ClockMsg) -> None:
        """Lockstep: simulated time advanced; one control step at the new time."""
        t = msg.clock.sec + msg.clock.nanosec * 1e-9
        self._sim_now = max(self._sim_now, t)
        self.control_step()
        self.control_steps += 1

    def deadline(self, timeout_s: float):
        """A one-shot steady-clock deadline for a stale input stream, re-armed (:func:`rearm`)
        by every valid input: the stream is acted on at the exact moment it goes stale, not
        at the next control tick. None in lockstep, where every tick judges staleness."""
        if self.lockstep:
            return None
        timer = self.create_timer(timeout_s, lambda: self._on_deadline(timer),
                                  clock=self._steady, autostart=False)
        return timer

    # -- subclass hooks ------------------------------------------------------------------------

    def create_inputs(self) -> None:
        """Create the task's own subscriptions, publishers and deadlines."""

    def control_step(self) -> None:
        """One control cycle: step the task and post its command (:meth:`post`)."""
        raise NotImplementedError

    def reset_task(self) -> None:
        """At activation, with ``_lock`` held: forget the previous task."""
        self.task = None

    def feed_pose(self, pose, now: float, stamp_ns: int) -> Optional[bool]:
        """Hand one TCP pose (and its measurement stamp) to the task; False when the task
        refused it."""
        return self.task.on_tcp_pose(pose, now)

    def stop_inputs(self) -> dict:
        """When each input last arrived (``{name: t}``), for the stop's latency."""
        return {"pose": self.last_pose_t}

    def stop_detail(self) -> str:
        """Why the task stops, beyond the command's reason ('' for none); ``_lock`` held."""
        return ""

    def diagnostic_values(self) -> dict:
        """The task's values for the diagnostics, with ``_lock`` held."""
        return self.inputs.values()

    def diagnostic_level(self, values: dict):
        """(level, message) of an active node without an arm error."""
        return c.Diagnostics.OK, values.get("task_state", self.waiting_for)

    def not_started(self) -> None:
        """Autostart could not activate the node (an unreachable arm)."""

    # -- lifecycle ---------------------------------------------------------------------------

    def on_configure(self, state) -> TransitionCallbackReturn:
        """Create and connect the arm; an unreachable arm fails the transition."""
        try:
            arm, worker = open_arm(self, self.arm_kind, self.p, self._on_arm_pose,
                                   self._on_arm_error, f"{self.get_name()}-arm-io",
                                   clock=self.now_s)
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
        """Enable velocity mode; the task starts on a later control cycle."""
        try:
            self.arm.enable_velocity_mode()
        except ArmError as exc:
            self.arm_error = str(exc)
            self.get_logger().error(f"cannot enable velocity mode: {exc}")
            return TransitionCallbackReturn.FAILURE
        with self._lock:
            self.reset_task()
            self._pose_fed = False
            self._stop_report = None
            self.active = True
            self.worker.rearm()
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        """Stop the arm and the task."""
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
        """Process exit: stop the task and the arm while the context still works."""
        self._halt("shutdown")
        self._release()

    # -- the arm -------------------------------------------------------------------------------

    def post(self, command: Optional[VelocityCommand]) -> None:
        """Hand a task output to the arm thread (never blocks on the arm); ``_lock`` held."""
        if command is None or self.worker is None:
            return
        if command.stop and self._stop_report is None:
            self._stop_report = {"reason": command.reason, "inputs": self.stop_inputs(),
                                 "posted_t": self.now_s()}
            # Once per activation: why the arm stopped is in the log, not only on the
            # diagnostics.
            detail = self.stop_detail()
            self.get_logger().info(f"stopping the arm: {command.reason}"
                                   f"{' (' + detail + ')' if detail else ''}")
        self.worker.post(command)

    def _halt(self, why: str) -> None:
        with self._lock:
            task, worker = self.task, self.worker
            if task is not None:
                task.shutdown()
                self.post(task.step())
            if worker is not None:
                self.post(VelocityCommand.halt(why))
        if worker is not None and not worker.flush(2.0):
            self.get_logger().error(f"arm stop not confirmed within 2 s ({why})")

    def _release(self) -> None:
        with self._lock:
            arm, self.arm = self.arm, None
            worker, self.worker = self.worker, None
            self.active = False
        close_arm(arm, worker, self.get_logger())

    def _on_arm_error(self, exc) -> None:
        """Arm thread: an arm call failed (the worker has latched and tried a stop)."""
        self.arm_error = str(exc)
        self.get_logger().error(f"arm error, stopping: {exc}")
        with self._lock:
            if self.task is not None:
                self.task.fault(str(exc))
                self.post(self.task.step())

    def stop_latency(self) -> dict:
        """When the last stop left, measured from the newest valid inputs before it [s]."""
        rep, worker = self._stop_report, self.worker
        if rep is None or worker is None or worker.last_stop_sent is None:
            return {}
        out = {"stop_reason": rep["reason"]}
        for key, t in rep["inputs"].items():
            if t is not None:
                out[f"stop_after_{key}_s"] = worker.last_stop_sent - t
        return out

    # -- inputs --------------------------------------------------------------------------------

    def _on_change(self, changed: dict) -> None:
        self.p.update(changed)
        self.get_logger().info(f"parameters changed: {changed}; they apply to the next "
                               f"{self.task_word} (re-activate the node)")

    def _on_tcp(self, msg: PoseStamped) -> None:
        """An arm fed from the topic (an ArmKind with ``pose_from_topic``)."""
        self.pose_count += 1
        now = self.now_s()
        try:
            stamp_ns, _, pose = convert.pose_from_msg(msg)
        except ValueError:
            return
        arm = self.arm
        if arm is not None:
            arm.set_pose(pose)
        self._take_pose(pose, now, stamp_ns)

    def _on_arm_pose(self, pose, now: float, stamp_ns: int) -> None:
        """A pose measured by the arm itself (report stream or poll), stamped when taken."""
        pub = self.pub_tcp
        if pub is not None:
            pub.publish(convert.pose_to_msg(pose, stamp_ns, frames.BASE))
        self._take_pose(pose, now, stamp_ns)

    def _take_pose(self, pose, now: float, stamp_ns: int) -> None:
        rearm(self._pose_deadline)
        with self._lock:
            self.inputs.pose(now, self.last_pose_t)
            self.last_pose_t = now
            if self.task is not None and self.feed_pose(pose, now, stamp_ns) is not False:
                self._pose_fed = True

    def _on_deadline(self, timer) -> None:
        """An input stream went silent: a control step now (the task decides it is stale,
        against the same arrival times); the deadline then waits for the next input."""
        timer.cancel()
        self.control_step()

    # -- diagnostics ---------------------------------------------------------------------------

    def _diagnose(self) -> None:
        state = getattr(self, "_state_machine", None)
        label = state.current_state[1] if state is not None else "?"
        values = {"lifecycle": label, "arm": self.p["arm"]}
        values.update(self.arm_kind.describe(self.p))
        with self._lock:
            values.update(self.diagnostic_values())
            worker = self.worker
        if worker is not None:
            values.update(arm_commands_sent=worker.sent,
                          arm_commands_dropped_after_stop=worker.dropped_after_stop)
        if self.arm_error:
            level, message = c.Diagnostics.ERROR, f"arm error: {self.arm_error}"
        elif not self.active:
            level, message = c.Diagnostics.WARN, "not active"
        else:
            level, message = self.diagnostic_level(values)
        self.diag.publish(level, message, values)
