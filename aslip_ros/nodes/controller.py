"""The lifecycle-node shell shared by ``slip_stop`` and ``slip_track``.

The task logic lives in :mod:`aslip_ros.control` (pure, clock-injectable); this module only
wires it to topics and an arm:

- ``arm:=sim``: :class:`TopicArm` publishes ``/aslip/arm/cmd_vel`` (TwistStamped,
  ``link_base``), which ``scene_sim`` executes on the scene's simulated arm, and reads the TCP
  from ``/aslip/robot/tcp_pose``.
- ``arm:=xarm``: :class:`aslip_ros.hw.xarm.XArmAdapter` at ``xarm_ip``; the TCP is polled
  every control cycle and republished on ``/aslip/robot/tcp_pose``.

Lifecycle: ``configure`` builds and connects the arm (an unreachable xArm fails the
transition, is reported on diagnostics and leaves the node unconfigured: nothing moves),
``activate`` enables velocity mode and starts the task, ``deactivate``/``cleanup``/
``shutdown`` stop the arm. With ``autostart`` (default) the node configures and activates
itself. Safety: stale slip or TCP input (watchdogs in the core), any arm error and process
shutdown all stop the arm.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Optional

import numpy as np
from geometry_msgs.msg import PoseStamped, TwistStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import String

from aslip_ros.msg import SlipVector
from aslip_ros.nodes import common as c
from aslip_ros.nodes import convert

IDENTITY = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]


class TopicArm:
    """An :class:`aslip_ros.control.arm.Arm` whose commands go out as TwistStamped.

    The receiver (``scene_sim``) holds each command for its ``command_timeout_s``, which
    plays the role of ``duration_s``; a zero twist is a stop.
    """

    poll_pose = False

    def __init__(self, node, topic: str = c.CMD_VEL_TOPIC, frame_id: str = "link_base"):
        self._node = node
        self._pub = node.create_publisher(TwistStamped, topic, c.RELIABLE_QOS)
        self._frame = frame_id
        self._pose: Optional[np.ndarray] = None
        self._enabled = False
        self.commands = 0

    def connect(self) -> None:
        """Nothing to open: the topic exists once the publisher does."""

    def enable_velocity_mode(self) -> None:
        """Accept velocity commands from now on."""
        self._enabled = True

    def send_velocity(self, v_xyz_m_s, duration_s: float) -> None:
        """Publish a velocity command [m/s, ``link_base``]."""
        from aslip_ros.control.arm import ArmError
        if not self._enabled:
            raise ArmError("velocity mode is not enabled")
        now = self._node.get_clock().now().nanoseconds
        self._pub.publish(convert.twist_to_msg(v_xyz_m_s, now, self._frame))
        self.commands += 1

    def stop(self) -> None:
        """Publish a zero twist (a stop)."""
        now = self._node.get_clock().now().nanoseconds
        self._pub.publish(convert.twist_to_msg([0.0, 0.0, 0.0], now, self._frame))

    def set_pose(self, pose: np.ndarray) -> None:
        """Newest TCP pose from the TCP topic."""
        self._pose = pose

    def tcp_pose(self) -> np.ndarray:
        """Newest TCP pose received."""
        from aslip_ros.control.arm import ArmError
        if self._pose is None:
            raise ArmError("no TCP pose received yet")
        return self._pose.copy()

    def close(self) -> None:
        """Stop; the publisher goes with the node."""
        self.stop()
        self._enabled = False


def arm_params() -> list:
    """Parameters that choose and limit the arm (shared by both controllers)."""
    return [
        c.Param("arm", "sim", "sim (scene_sim over topics) or xarm", c.one_of("sim", "xarm"),
                read_only=True),
        c.Param("xarm_ip", "192.168.1.222", "xArm controller IP", c.non_empty, read_only=True),
        c.Param("xarm_max_speed_m_s", 0.1, "xArm TCP speed limit [m/s]", c.in_range(1e-4, 1.0),
                read_only=True),
        c.Param("xarm_connect_timeout_s", 5.0, "xArm unreachable after this long [s]",
                c.in_range(0.1, 60.0), read_only=True),
        c.Param("xarm_workspace_min_m", [0.15, -0.45, 0.02], "xArm workspace lower corner [m]",
                c.vector3(allow_empty=True), read_only=True),
        c.Param("xarm_workspace_max_m", [0.70, 0.45, 0.60], "xArm workspace upper corner [m]",
                c.vector3(allow_empty=True), read_only=True),
        c.Param("control_rate_hz", 100.0, "control loop rate [Hz]", c.in_range(1.0, 250.0),
                read_only=True),
        c.Param("slip_timeout_s", 0.1, "stop when no SlipVector for this long [s]",
                c.in_range(1e-3, 0.1)),
        c.Param("pose_timeout_s", 0.1, "stop when no TCP pose for this long [s]",
                c.in_range(1e-3, 1.0)),
        c.Param("command_duration_s", 0.1,
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
        c.Param("autostart", True, "configure and activate at start", read_only=True),
        c.Param("exit_when_done", False, "exit once the task has ended", read_only=True),
    ]


class ControllerNode(LifecycleNode):
    """Lifecycle shell: subclasses provide ``task_params``, ``task_config``, ``make_task``,
    ``feed_slip`` and optionally ``after_step``."""

    task_name = "controller"

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.p = c.declare_params(self, arm_params() + self.task_params(), self._on_change,
                                  self.cross_check)
        self._lock = threading.RLock()
        self.arm = None
        self.task = None
        self.active = False
        self.done = False
        self.exit_code = 0
        self.arm_error = ""
        self.rejected_slip = 0
        self.slip_count = 0
        self.last_slip_t: Optional[float] = None
        self.steady_slip = 0    # consecutive SlipVectors, each within slip_timeout_s
        self._task_fed = False
        self._pose_fed = False
        self._started = False
        self.meta: Optional[dict] = None
        self.diag = c.Diagnostics(self, f"aslip: {name}", self.p["arm"])
        self.pub_tcp = None
        inputs = MutuallyExclusiveCallbackGroup()
        self.create_subscription(SlipVector, self.p["slip_topic"], self._on_slip,
                                 c.RELIABLE_QOS, callback_group=inputs)
        self.create_subscription(String, c.METADATA_TOPIC, self._on_metadata, c.LATCHED_QOS,
                                 callback_group=inputs)
        if self.p["arm"] == "sim":
            self.create_subscription(PoseStamped, c.TCP_TOPIC, self._on_tcp, c.SENSOR_QOS,
                                     callback_group=inputs)
        else:
            self.pub_tcp = self.create_publisher(PoseStamped, c.TCP_TOPIC, c.SENSOR_QOS)
        # Arm I/O may block (xArm SDK); it gets its own group so inputs keep flowing.
        self.create_timer(1.0 / self.p["control_rate_hz"], self._control,
                          callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(1.0, self._diagnose, callback_group=MutuallyExclusiveCallbackGroup())
        if self.p["autostart"]:
            self.trigger_configure()
            if self.arm is not None:
                self.trigger_activate()
        c.ready(self, f"{self.task_name}, arm {self.p['arm']}, "
                      f"{'active' if self.active else 'not active'}")

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
        """Called after each control cycle (results, end of task)."""

    def status(self) -> dict:
        """Task values for the diagnostics."""
        return {}

    # -- lifecycle ---------------------------------------------------------------------------

    def on_configure(self, state) -> TransitionCallbackReturn:
        """Create and connect the arm; an unreachable arm fails the transition."""
        from aslip_ros.control.arm import ArmError
        try:
            arm = self._make_arm()
            arm.connect()
        except (ArmError, ValueError, ImportError, OSError) as exc:
            self.arm_error = f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"arm not available ({self.arm_error}); the node stays "
                                    "unconfigured and commands nothing")
            self._diagnose()
            return TransitionCallbackReturn.FAILURE
        self.arm = arm
        self.arm_error = ""
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        """Enable velocity mode; the task starts on the next control cycle."""
        from aslip_ros.control.arm import ArmError
        try:
            self.arm.enable_velocity_mode()
        except ArmError as exc:
            self.arm_error = str(exc)
            self.get_logger().error(f"cannot enable velocity mode: {exc}")
            return TransitionCallbackReturn.FAILURE
        with self._lock:
            self.task = None
            self._started = False
            self.active = True
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

    def _make_arm(self):
        if self.p["arm"] == "sim":
            return TopicArm(self)
        from aslip_ros.hw.xarm import XArmAdapter, XArmConfig
        cfg = XArmConfig(ip=self.p["xarm_ip"], max_speed_m_s=self.p["xarm_max_speed_m_s"],
                         connect_timeout_s=self.p["xarm_connect_timeout_s"],
                         workspace_min_m=tuple(self.p["xarm_workspace_min_m"]),
                         workspace_max_m=tuple(self.p["xarm_workspace_max_m"]))
        adapter = XArmAdapter(cfg)
        adapter.poll_pose = True
        return adapter

    def _halt(self, why: str) -> None:
        from aslip_ros.control.command import apply_command
        with self._lock:
            task, arm = self.task, self.arm
            if task is not None:
                task.shutdown()
                try:
                    apply_command(arm, task.step())
                except Exception as exc:  # noqa: BLE001 - still try the plain stop below
                    self.get_logger().error(f"stop command failed: {exc}")
            if arm is not None:
                try:
                    arm.stop()
                except Exception as exc:  # noqa: BLE001
                    self.get_logger().error(f"arm stop failed ({why}): {exc}")

    def _release(self) -> None:
        with self._lock:
            arm, self.arm = self.arm, None
            self.active = False
        if arm is not None:
            try:
                arm.close()
            except Exception as exc:  # noqa: BLE001
                self.get_logger().error(f"arm close failed: {exc}")

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
        try:
            slip = convert.slip_from_msg(msg)
        except ValueError as exc:
            self.rejected_slip += 1
            self.get_logger().warning(f"SlipVector rejected: {exc}", throttle_duration_sec=1.0)
            return
        self.slip_count += 1
        now = time.monotonic()
        fresh = self.last_slip_t is not None and \
            now - self.last_slip_t <= self.p["slip_timeout_s"]
        self.steady_slip = self.steady_slip + 1 if fresh else 1
        self.last_slip_t = now
        with self._lock:
            if self.task is not None:
                self.feed_slip(slip, time.monotonic())
                self._task_fed = True

    def _on_tcp(self, msg: PoseStamped) -> None:
        try:
            stamp_ns, _, pose = convert.pose_from_msg(msg)
        except ValueError:
            return
        with self._lock:
            if isinstance(self.arm, TopicArm):
                self.arm.set_pose(pose)
            if self.task is not None:
                self.feed_pose(pose, time.monotonic(), stamp_ns)
                self._pose_fed = True

    def _control(self) -> None:
        from aslip_ros.control.arm import ArmError
        from aslip_ros.control.command import apply_command
        with self._lock:
            if not self.active or self.arm is None:
                return
            now = time.monotonic()
            if self.task is None:
                self.task = self.make_task()
                if self.task is None:
                    return
                self._started = False
                self._task_fed = False
                self._pose_fed = False
            try:
                if getattr(self.arm, "poll_pose", False):
                    pose = self.arm.tcp_pose()
                    self.task.on_tcp_pose(pose, now)
                    self._pose_fed = True
                    self.pub_tcp.publish(convert.pose_to_msg(
                        pose, self.get_clock().now().nanoseconds, "link_base"))
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
                apply_command(self.arm, self.task.step())
            except ArmError as exc:
                self.arm_error = str(exc)
                self.get_logger().error(f"arm error, stopping: {exc}")
                self.task.fault(str(exc))
                try:
                    apply_command(self.arm, self.task.step())
                    self.arm.stop()
                except Exception as exc2:  # noqa: BLE001 - the arm may be gone entirely
                    self.get_logger().error(f"stop after error failed: {exc2}")
            self.after_step(now)

    def _diagnose(self) -> None:
        state = getattr(self, "_state_machine", None)
        label = state.current_state[1] if state is not None else "?"
        values = {"lifecycle": label, "arm": self.p["arm"], "slip_received": self.slip_count,
                  "slip_rejected": self.rejected_slip}
        if self.p["arm"] == "xarm":
            values["xarm_ip"] = self.p["xarm_ip"]
        with self._lock:
            if self.task is not None:
                values["task_state"] = self.task.state.value
            values.update(self.status())
        if self.arm_error:
            level, message = c.Diagnostics.ERROR, f"arm error: {self.arm_error}"
        elif not self.active:
            level, message = c.Diagnostics.WARN, "not active"
        else:
            level, message = c.Diagnostics.OK, values.get("task_state", "waiting for inputs")
        self.diag.publish(level, message, values)
