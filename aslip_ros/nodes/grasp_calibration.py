"""The per-grasp calibration, started by a controller at each grasp and reported to the user.

A piezo pad couples to the object differently at every grasp, so a checkpoint with a
per-grasp calibration (docs/model.md) must start it again when a new grasp begins. On the
scene the audio stream starts with the grasp; on a real cell the audio runs across grasps,
and only the controller knows when a task (a grasp) begins. At the start of each task the
controller calls ``slip_inference``'s ``~/recalibrate`` (std_srvs/Trigger), tells the user to
hold the object still, and says when ``/aslip/calibration`` reports the new grasp converged
(or that the checkpoint has no calibration), and warns when it reports the grasp's estimate
untrusted (the calibration's self-check, docs/model.md). Nothing here moves or holds the
arm.
"""

from __future__ import annotations

import json
import time
from typing import Optional

from std_msgs.msg import String
from std_srvs.srv import Trigger

from aslip_ros import topics
from aslip_ros.runtime.qos import LATCHED_QOS

#: How long a task start waits for the service to be discovered before it gives up [s].
SERVICE_WAIT_S = 5.0

#: Where slip_inference offers its ``~/recalibrate`` under the package's launch files.
DEFAULT_SERVICE = "/slip_inference/recalibrate"


class GraspCalibration:
    """Starts the calibration at :meth:`begin` and follows ``/aslip/calibration``."""

    def __init__(self, node, service: str = DEFAULT_SERVICE, clock=time.monotonic) -> None:
        self.node = node
        self.clock = clock
        self.client = node.create_client(Trigger, service) if service else None
        node.create_subscription(String, topics.CALIBRATION, self._on_state, LATCHED_QOS)
        self.service = service
        self.calibrated: Optional[bool] = None     # None until slip_inference has said
        self.grasp = 0                             # slip_inference's newest grasp number
        self._begun_t: Optional[float] = None
        self._begun_grasp = 0
        self.converged_after_s: Optional[float] = None
        #: The self-check's verdict on the current task's grasp (None: not known yet).
        self.trusted: Optional[bool] = None
        self.requests = 0
        self.replies = 0                           # answered or failed calls
        self._pending = False
        if self.client is not None:
            node.create_timer(0.1, self._request)

    def begin(self) -> None:
        """A task starts with an object in the grasp: calibrate for this grasp."""
        self._begun_t, self._begun_grasp = self.clock(), self.grasp
        self.converged_after_s = None
        self.trusted = None
        self._pending = self.client is not None and self.calibrated is not False
        self._request()

    def _request(self) -> None:
        """Call the service once it is discovered (within :data:`SERVICE_WAIT_S`)."""
        if not self._pending:
            return
        log = self.node.get_logger()
        if not self.client.service_is_ready():
            if self.clock() - self._begun_t > SERVICE_WAIT_S:
                self._pending = False
                log.warning(f"{self.service} is not available: the per-grasp calibration "
                            "was not restarted for this grasp")
            return
        self._pending = False
        self.requests += 1
        self.client.call_async(Trigger.Request()).add_done_callback(self._on_reply)
        log.info("per-grasp calibration started: hold the grasped object still until "
                 "'calibration converged' is logged")

    def _on_reply(self, future) -> None:
        self.replies += 1
        try:
            reply = future.result()
        except Exception as exc:  # noqa: BLE001 - a failed call is reported, never raised
            self.node.get_logger().warning(f"{self.service} failed: {exc}")
            return
        if not reply.success:
            self.node.get_logger().info(f"{self.service}: {reply.message}")

    def _on_state(self, msg: String) -> None:
        try:
            state = json.loads(msg.data)
            calibrated, grasp = bool(state["calibrated"]), int(state["grasp"])
            converged = bool(state["converged"])
        except (ValueError, KeyError, TypeError) as exc:
            self.node.get_logger().warning(f"unreadable {topics.CALIBRATION}: {exc}")
            return
        self.calibrated, self.grasp = calibrated, grasp
        if converged and self._begun_t is not None and grasp > self._begun_grasp and \
                self.converged_after_s is None:
            self.converged_after_s = self.clock() - self._begun_t
            self.node.get_logger().info(f"calibration converged {self.converged_after_s:.2f} s "
                                        "after the grasp began")
        trusted = state.get("trusted")          # absent from an older slip_inference
        if converged and self._begun_t is not None and grasp > self._begun_grasp and \
                isinstance(trusted, bool) and trusted != self.trusted:
            self.trusted = trusted
            if not trusted:
                self.node.get_logger().warning(
                    "calibration not trusted: the background does not reach the "
                    "microphones alike (docs/model.md); slip directions may be biased")

    def values(self) -> dict:
        """Diagnostics values: ``calibration`` none / calibrating / converged / unknown."""
        if self.calibrated is None:
            state = "unknown"
        elif not self.calibrated:
            state = "none"
        else:
            state = "calibrating" if self.converged_after_s is None else "converged"
        out = {"calibration": state}
        if self.converged_after_s is not None:
            out["calibration_converged_after_s"] = round(self.converged_after_s, 3)
        if self.trusted is not None:
            out["calibration_trusted"] = self.trusted
        return out
