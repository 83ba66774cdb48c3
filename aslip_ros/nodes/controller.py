"""What ``slip_stop`` and ``slip_track`` share: the slip input and the start of a task.

The task logic lives in :mod:`aslip_ros.control` (pure, clock-injectable); the arm, its
lifecycle and its safety are :class:`~aslip_ros.nodes.arm_node.ArmNode`'s (the arm chosen
by name from :mod:`aslip_ros.nodes.arms`: ``sim``, the scene's arm over topics; ``xarm``;
``module.path:factory``, docs/design.md "Extending"). This module adds the SlipVector input
and when a task may start. Each task start is a new grasp: the per-grasp calibration of
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

Lifecycle and safety are the arm node's (:mod:`.arm_node`): ``activate`` starts the task;
stale slip input stops the arm as stale TCP input does, and no velocity command follows a
stop until the next activation.
"""

from __future__ import annotations

import json
from typing import Optional

from std_msgs.msg import String

from aslip_ros import topics
from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S
from aslip_ros.msg import SlipVector
from aslip_ros.nodes import common as c
from aslip_ros.nodes import convert
from aslip_ros.nodes.arm_node import ArmNode, arm_params, rearm
from aslip_ros.nodes.grasp_calibration import DEFAULT_SERVICE, GraspCalibration
from aslip_ros.runtime.qos import LATCHED_QOS, RELIABLE_QOS


def controller_params() -> list:
    """The arm's parameters (:func:`~aslip_ros.nodes.arm_node.arm_params`) and the slip
    input's (shared by both controllers)."""
    return arm_params() + [
        c.Param("slip_timeout_s", DEFAULT_TIMEOUT_S, "stop when no SlipVector for this long "
                "[s] (raise only on a busy computer)", c.in_range(1e-3, 1.0)),
        c.Param("slip_topic", c.SLIP_TOPIC, "SlipVector input topic", c.non_empty,
                read_only=True),
        c.Param("start_after_messages", 10,
                "start moving only after this many consecutive SlipVectors, each within "
                "slip_timeout_s of the previous one (a steady stream, not the first one)",
                c.int_range(1, 1000),
                read_only=True),
        c.Param("recalibrate_service", DEFAULT_SERVICE, "called at each task start (a new "
                "grasp) to restart the per-grasp calibration; '' = never", read_only=True),
        c.Param("lockstep", False, f"step once per {topics.CLOCK} tick (scene_sim's lockstep "
                "mode; set use_sim_time too) instead of on a steady-clock timer",
                read_only=True),
    ]


class ControllerNode(ArmNode):
    """A controller on :class:`~aslip_ros.nodes.arm_node.ArmNode` (threads, lifecycle and
    safety there): subclasses provide ``task_params``, ``task_config``, ``make_task``,
    ``feed_slip`` and optionally ``after_step``.
    """

    task_name = "controller"

    def __init__(self, name: str, **kwargs) -> None:
        self.rejected_slip = 0
        self.slip_count = 0
        self.last_slip_t: Optional[float] = None
        self.steady_slip = 0    # consecutive SlipVectors, each within slip_timeout_s
        self._task_fed = False
        self._started = False
        self.meta: Optional[dict] = None
        super().__init__(name, controller_params() + self.task_params(), self.cross_check,
                         **kwargs)

    def create_inputs(self) -> None:
        """The slip and metadata inputs, the slip deadline and the grasp calibration."""
        self.calibration = GraspCalibration(self, self.p["recalibrate_service"],
                                            clock=self.now_s)
        self.create_subscription(SlipVector, self.p["slip_topic"], self._on_slip,
                                 RELIABLE_QOS)
        self.create_subscription(String, c.METADATA_TOPIC, self._on_metadata, LATCHED_QOS)
        self._slip_deadline = self.deadline(self.p["slip_timeout_s"])

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

    def reset_task(self) -> None:
        """At activation: the task is built anew on the next control cycle."""
        self.task = None
        self._started = False

    def stop_inputs(self) -> dict:
        """The newest valid slip estimate and pose before a stop."""
        return {"slip": self.last_slip_t, "pose": self.last_pose_t}

    def start_task(self, now: float) -> bool:
        """Start the task; False to retry on the next cycle."""
        self.task.start()
        return True

    def after_step(self, now: float) -> None:
        """Called after each control cycle (results, end of task), with ``_lock`` held."""

    def status(self) -> dict:
        """Task values for the diagnostics."""
        return {}

    # -- inputs ------------------------------------------------------------------------------

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
        rearm(self._slip_deadline)
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

    def control_step(self) -> None:
        """Build and start the task when its inputs allow, then step it."""
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

    def diagnostic_values(self) -> dict:
        """Slip counts, the task's state and values, inputs, stop latency, calibration."""
        values = {"slip_received": self.slip_count, "slip_rejected": self.rejected_slip}
        if self.task is not None:
            values["task_state"] = self.task.state.value
        values.update(self.status())
        values.update(self.inputs.values())
        values.update(self.stop_latency())
        values.update(self.calibration.values())
        return values
