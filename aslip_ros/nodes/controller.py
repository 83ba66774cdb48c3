"""The lifecycle-node shell shared by ``slip_stop`` and ``slip_track``.

The task logic lives in :mod:`aslip_ros.control` (pure, clock-injectable); this module only
wires it to topics and an arm, chosen by name from :mod:`aslip_ros.nodes.arms` (``sim``: the
scene's arm over topics; ``xarm``; ``module.path:factory``, docs/design.md "Extending").
The TCP of an arm that measures it is republished on ``/aslip/robot/tcp_pose``, stamped
when measured. Each task start is a new grasp: the per-grasp calibration of
``slip_inference`` starts again then (:mod:`.grasp_calibration`).

Every arm call runs on a thread of its own (:mod:`aslip_ros.control.arm_worker`): the
control step only posts its command, so slip and pose callbacks never wait behind arm I/O.
A stale input is acted on by a one-shot deadline per stream, re-armed by each valid input,
so the stop leaves ``slip_timeout_s`` (or ``pose_timeout_s``) after the last valid input,
not at the next control tick.

Time: the steady clock, or in lockstep (``lockstep``, with ``use_sim_time``) the simulated
time on ``/clock`` that ``scene_sim`` publishes once the graph has handled a block: the
node then runs one control step per tick and no timer of its own, so a trial depends on
simulated time only, never on how fast the host is (docs/nodes.md, "Lockstep").

Lifecycle: ``configure`` connects the arm (an unreachable xArm fails the transition and
nothing moves), ``activate`` enables velocity mode and starts the task, ``deactivate``/
``cleanup``/``shutdown`` stop the arm; ``autostart`` (default) does the first two. Stale
slip or TCP input, any arm error and shutdown stop the arm, and no velocity command
follows a stop until the next activation.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Optional

from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rosgraph_msgs.msg import Clock as ClockMsg
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import String

from aslip_ros import frames, poses, topics
from aslip_ros.arm import ArmError
from aslip_ros.control.command import DEFAULT_DURATION_S, VelocityCommand
from aslip_ros.control.limits import ArmLimits
from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S, ArrivalStats
from aslip_ros.hw.xarm_config import XArmConfig
from aslip_ros.msg import SlipVector
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import ready
from aslip_ros.runtime.qos import CLOCK_QOS, LATCHED_QOS, RELIABLE_QOS, SENSOR_QOS
from aslip_ros.nodes import convert
from aslip_ros.nodes.arm_link import OPEN_ERRORS, close_arm, open_arm
from aslip_ros.nodes.arms import ARMS, LIMIT_PREFIX, resolve_arm
from aslip_ros.nodes.grasp_calibration import DEFAULT_SERVICE, GraspCalibration

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
    """Parameters that choose and limit the arm (shared by both controllers)."""
    return [
        c.Param("arm", "sim", "sim (scene_sim over topics), xarm, or module.path:factory",
                c.Rule(_arm, _ARM_CHOICES), read_only=True),
        c.Param("xarm_ip", "192.168.1.222", "xArm controller IP", c.non_empty, read_only=True),
        c.from_config(XArmConfig, "connect_timeout_s", "xArm unreachable after this long [s]",
                      c.in_range(0.1, 60.0), read_only=True, prefix="xarm_"),
    ] + limit_params() + [
        c.Param("control_rate_hz", 100.0, "control loop rate [Hz]", c.in_range(1.0, 250.0),
                read_only=True),
        c.Param("slip_timeout_s", DEFAULT_TIMEOUT_S, "stop when no SlipVector for this long "
                "[s] (raise only on a busy computer)", c.in_range(1e-3, 1.0)),
        c.Param("pose_timeout_s", DEFAULT_TIMEOUT_S, "stop when no TCP pose for this long [s]",
                c.in_range(1e-3, 1.0)),
        c.Param("command_duration_s", DEFAULT_DURATION_S,
                "each velocity command expires on the arm after this long [s]",
                c.in_range(0.005, 0.5)),
        c.Param("slip_topic", c.SLIP_TOPIC, "SlipVector input topic", c.non_empty,
                read_only=True),
        c.Param("grasp_plane_in_tcp", list(IDENTITY),
                "grasp-plane pose in the TCP frame (x y z qx qy qz qw) [m]", c.pose7),
        c.Param("start_after_messages", 10,
                "start moving only after this many consecutive SlipVectors, each within "
                "slip_timeout_s of the previous one (a steady stream, not the first one)",
                c.int_range(1, 1000),
                read_only=True),
        c.Param("recalibrate_service", DEFAULT_SERVICE, "called at each task start (a new "
                "grasp) to restart the per-grasp calibration; '' = never", read_only=True),
        c.Param("autostart", True, "configure and activate at start", read_only=True),
        c.Param("lockstep", False, f"step once per {topics.CLOCK} tick (scene_sim's lockstep "
                "mode; set use_sim_time too) instead of on a steady-clock timer",
                read_only=True),
        c.Param("exit_when_done", False, "exit once the task has ended", read_only=True),
    ]


_ARM_CHOICES = f"one of {', '.join(ARMS)}, or module.path:factory"


def _arm(v) -> Optional[str]:
    try:
        resolve_arm(str(v))
    except ValueError as exc:
        return str(exc)
    return None


class ControllerNode(LifecycleNode):
    """Lifecycle shell: subclasses provide ``task_params``, ``task_config``, ``make_task``,
    ``feed_slip`` and optionally ``after_step``.

    Threads: the executor's one dispatch thread runs the input callbacks, the control timer
    and the two deadline timers; an :class:`~aslip_ros.control.arm_worker.ArmWorker` thread
    does every arm call; the xArm SDK's report thread delivers poses. ``_lock`` guards the
    task and the input bookkeeping and is never held across arm I/O.
    """

    task_name = "controller"

    def __init__(self, name: str, **kwargs) -> None:
        super().__init__(name, **kwargs)
        self.p = c.declare_params(self, arm_params() + self.task_params(), self._on_change,
                                  self.cross_check)
        self.lockstep = bool(self.p["lockstep"])
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
        self.rejected_slip = 0
        self.slip_count = 0
        self.last_slip_t: Optional[float] = None
        self.last_pose_t: Optional[float] = None
        self.steady_slip = 0    # consecutive SlipVectors, each within slip_timeout_s
        self.inputs = ArrivalStats(self.now_s if self.lockstep else time.time)
        self._stop_report: Optional[dict] = None
        self._task_fed = False
        self._pose_fed = False
        self._started = False
        self.meta: Optional[dict] = None
        self.diag = c.Diagnostics(self, f"aslip: {name}", self.p["arm"])
        self.arm_kind = resolve_arm(self.p["arm"])
        self.pub_tcp = None
        self.calibration = GraspCalibration(self, self.p["recalibrate_service"],
                                            clock=self.now_s)
        # One dispatch thread (common._executor): callback groups would change nothing.
        self.create_subscription(SlipVector, self.p["slip_topic"], self._on_slip,
                                 RELIABLE_QOS)
        self.create_subscription(String, c.METADATA_TOPIC, self._on_metadata, LATCHED_QOS)
        if self.arm_kind.pose_from_topic:
            self.create_subscription(PoseStamped, c.TCP_TOPIC, self._on_tcp, SENSOR_QOS)
        else:
            self.pub_tcp = self.create_publisher(PoseStamped, c.TCP_TOPIC, SENSOR_QOS)
        self._slip_deadline = self._pose_deadline = None
        if self.lockstep:
            # Every tick is a control step, which also judges staleness (no deadlines).
            self.create_subscription(ClockMsg, topics.CLOCK, self._on_clock, CLOCK_QOS)
        else:
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            self.create_timer(1.0 / self.p["control_rate_hz"], self._control, clock=steady)
            # One-shot deadlines, re-armed by every valid input: a stale stream is acted on
            # at the exact moment it goes stale, not at the next control tick.
            self._slip_deadline = self.create_timer(
                self.p["slip_timeout_s"], lambda: self._on_deadline(self._slip_deadline),
                clock=steady, autostart=False)
            self._pose_deadline = self.create_timer(
                self.p["pose_timeout_s"], lambda: self._on_deadline(self._pose_deadline),
                clock=steady, autostart=False)
        self.create_timer(1.0, self._diagnose)
        if self.p["autostart"]:
            self.trigger_configure()
            if self.arm is not None:
                self.trigger_activate()
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
        self._control()
        self.control_steps += 1

    # -- subclass hooks ------------------------------------------------------------------------

    def task_params(self) -> list:
        """Parameter specs of the task."""
        return []

    def task_config(self, values: dict):
        """The core controller's config built from parameter ``values`` (raises ValueError)."""
        return None

    def cross_check(self, values: dict) -> Optional[str]:
        """Error text when the task's parameters do not make a valid core config: the core's
        own validation of the combination (e.g. approach distance > retract distance)."""
        try:
            self.task_config(values)
        except ValueError as exc:
            return str(exc)
        return None

    def make_task(self):
        """Build the core controller; None while its inputs (e.g. metadata) are missing."""
        raise NotImplementedError

    def feed_slip(self, slip: convert.SlipData, now: float) -> None:
        """Hand one slip estimate to the task."""
        raise NotImplementedError

    def feed_pose(self, pose, now: float, stamp_ns: int) -> None:
        """Hand one TCP pose (and its measurement stamp) to the task."""
        self.task.on_tcp_pose(pose, now)

    def start_task(self, now: float) -> bool:
        """Start the task; False to retry on the next cycle."""
        self.task.start()
        return True

    def after_step(self, now: float) -> None:
        """Called after each control cycle (results, end of task), with ``_lock`` held."""

    def status(self) -> dict:
        """Task values for the diagnostics."""
        return {}

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
        """Enable velocity mode; the task starts on the next control cycle."""
        try:
            self.arm.enable_velocity_mode()
        except ArmError as exc:
            self.arm_error = str(exc)
            self.get_logger().error(f"cannot enable velocity mode: {exc}")
            return TransitionCallbackReturn.FAILURE
        with self._lock:
            self.task = None
            self._started = False
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

    # -- internals -----------------------------------------------------------------------------

    def post(self, command) -> None:
        """Hand a controller output to the arm thread (never blocks on the arm)."""
        if command is not None and self.worker is not None:
            if command.stop and self._stop_report is None:
                self._stop_report = {"reason": command.reason,
                                     "last_slip_t": self.last_slip_t,
                                     "last_pose_t": self.last_pose_t,
                                     "posted_t": self.now_s()}
                # Once per activation: why the arm stopped is in the log, not only on
                # the diagnostics.
                self.get_logger().info(f"stopping the arm: {command.reason}")
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

    def _on_change(self, changed: dict) -> None:
        self.p.update(changed)
        self.get_logger().info(f"parameters changed: {changed}; they apply to the next task "
                               "(re-activate the node)")

    def _on_metadata(self, msg: String) -> None:
        try:
            self.meta = json.loads(msg.data)
        except ValueError as exc:
            self.get_logger().error(f"unreadable /aslip/metadata: {exc}")

    def _on_slip(self, msg: SlipVector) -> None:
        now = self.now_s()
        try:
            slip = convert.slip_from_msg(msg)
        except ValueError as exc:
            self.rejected_slip += 1
            self.get_logger().warning(f"SlipVector rejected: {exc}", throttle_duration_sec=1.0)
            return
        _rearm(self._slip_deadline)
        with self._lock:
            self.slip_count += 1
            fresh = self.last_slip_t is not None and \
                now - self.last_slip_t <= self.p["slip_timeout_s"]
            self.steady_slip = self.steady_slip + 1 if fresh else 1
            self.inputs.slip(now, self.last_slip_t,
                             msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
            self.last_slip_t = now
            if self.task is not None:
                self.feed_slip(slip, now)
                self._task_fed = True

    def _on_tcp(self, msg: PoseStamped) -> None:
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
        _rearm(self._pose_deadline)
        with self._lock:
            self.inputs.pose(now, self.last_pose_t)
            self.last_pose_t = now
            if self.task is not None:
                self.feed_pose(pose, now, stamp_ns)
                self._pose_fed = True

    def _on_deadline(self, timer) -> None:
        """An input stream went silent: a control step now (the core decides it is stale,
        against the same arrival times); the deadline then waits for the next input."""
        timer.cancel()
        self._control()

    def _on_arm_error(self, exc) -> None:
        """Arm thread: an arm call failed (the worker has latched and tried a stop)."""
        self.arm_error = str(exc)
        self.get_logger().error(f"arm error, stopping: {exc}")
        with self._lock:
            if self.task is not None:
                self.task.fault(str(exc))
                self.post(self.task.step())

    def _control(self) -> None:
        with self._lock:
            if not self.active or self.worker is None:
                return
            now = self.now_s()
            if self.task is None:
                self.task = self.make_task()
                if self.task is None:
                    return
                self._started = False
                self._task_fed = False
                self._pose_fed = False
            if not self._started:
                if not (self._task_fed and self._pose_fed) or \
                        now - self.last_slip_t > self.p["slip_timeout_s"] or \
                        self.steady_slip < self.p["start_after_messages"]:
                    # A task never starts on silent slip or pose streams, nor on the
                    # first estimates of a stream that is still warming up.
                    return
                try:
                    self._started = self.start_task(now)
                except RuntimeError:
                    return  # no fresh pose yet: try again next cycle
                if self._started:
                    self.calibration.begin()
            self.post(self.task.step(now))
            self.after_step(now)

    def stop_latency(self) -> dict:
        """When the last stop left, measured from the newest valid inputs before it [s]."""
        rep, worker = self._stop_report, self.worker
        if rep is None or worker is None or worker.last_stop_sent is None:
            return {}
        out = {"stop_reason": rep["reason"]}
        for key in ("slip", "pose"):
            t = rep[f"last_{key}_t"]
            if t is not None:
                out[f"stop_after_{key}_s"] = worker.last_stop_sent - t
        return out

    def _diagnose(self) -> None:
        state = getattr(self, "_state_machine", None)
        label = state.current_state[1] if state is not None else "?"
        values = {"lifecycle": label, "arm": self.p["arm"], "slip_received": self.slip_count,
                  "slip_rejected": self.rejected_slip}
        values.update(self.arm_kind.describe(self.p))
        with self._lock:
            if self.task is not None:
                values["task_state"] = self.task.state.value
            values.update(self.status())
            values.update(self.inputs.values())
            values.update(self.stop_latency())
            values.update(self.calibration.values())
            worker = self.worker
        if worker is not None:
            values.update(arm_commands_sent=worker.sent,
                          arm_commands_dropped_after_stop=worker.dropped_after_stop)
        if self.arm_error:
            level, message = c.Diagnostics.ERROR, f"arm error: {self.arm_error}"
        elif not self.active:
            level, message = c.Diagnostics.WARN, "not active"
        else:
            level, message = c.Diagnostics.OK, values.get("task_state", "waiting for inputs")
        self.diag.publish(level, message, values)


def _rearm(deadline) -> None:
    """Restart a stale-input deadline (none in lockstep: each tick judges staleness)."""
    if deadline is not None:
        deadline.reset()
