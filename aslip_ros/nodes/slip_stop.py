"""``slip_stop``: the paper's wall-push task, stopping the arm when slip is detected.

The task logic is :class:`aslip_ros.control.slip_stop.SlipStop`: start with the object in
contact with the wall, retract ``retract_distance_m``, settle, re-approach at
``approach_speed_m_s`` along ``direction`` (``link_base``), stop after ``debounce_count``
consecutive slipping estimates; with ``stop_on_rotation`` an estimate whose
``|angular_velocity|`` (SlipVector, rad/s about the pad normal) reaches
``rotation_threshold_rad_s`` counts as slipping (reason ``rotation``). The result (stop
reason, success, stopping distance past the contact pose) is published latched as JSON on
``/aslip/slip_stop/result`` when the arm stops and again, final, once it has come to rest
(``settle_result_s`` later).

``direction`` ``[0, 0, 0]`` (default) takes the push direction from the scene's metadata
(``task.push_direction`` on ``/aslip/metadata``); on hardware give it explicitly.
"""

from __future__ import annotations

import json
import math
from typing import Optional

import numpy as np
from std_msgs.msg import String

from aslip_ros import topics
from aslip_ros.control.slip_stop import SlipStop, SlipStopConfig
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import run_node
from aslip_ros.runtime.qos import LATCHED_QOS
from aslip_ros.nodes.controller import ControllerNode

RESULT_TOPIC = topics.SLIP_STOP_RESULT


def _direction_check(v) -> Optional[str]:
    vals = [float(x) for x in v]
    if len(vals) != 3 or not all(math.isfinite(x) for x in vals):
        return f"must be 3 finite numbers, got {vals}"
    return None


class SlipStopNode(ControllerNode):
    """Wall-push slip-stop controller."""

    task_name = "slip_stop"

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        self._result_pub = None
        self._stopped_at: Optional[float] = None
        self._final_sent = False
        super().__init__("slip_stop", **kwargs)
        self._result_pub = self.create_publisher(String, RESULT_TOPIC, LATCHED_QOS)

    def task_params(self) -> list:
        """Wall-push parameters (SI, ``link_base``), their defaults the core's
        :class:`SlipStopConfig` (``direction`` excepted: the node's 0 0 0 means "from the
        scene", the core needs a direction)."""
        return [
            c.Param("direction", [0.0, 0.0, 0.0],
                    "approach direction towards the wall in link_base; 0 0 0 = from the "
                    "scene metadata", c.Rule(_direction_check, "3 finite numbers"),
                    read_only=True),
            c.from_config(SlipStopConfig, "approach_speed_m_s", "re-approach speed [m/s]",
                          c.positive),
            c.from_config(SlipStopConfig, "retract_distance_m",
                          "back-off distance [m] (paper: 0.1)", c.positive),
            c.from_config(SlipStopConfig, "retract_speed_m_s", "back-off speed [m/s]",
                          c.positive),
            c.from_config(SlipStopConfig, "settle_s",
                          "pause between retract and approach [s]", c.non_negative),
            c.from_config(SlipStopConfig, "max_approach_distance_m",
                          "approach travel limit [m]", c.positive),
            c.from_config(SlipStopConfig, "debounce_count",
                          "consecutive slip estimates needed to stop", c.int_range(1, 100)),
            c.from_config(SlipStopConfig, "time_margin", "phase time limit factor (>= 1)",
                          c.at_least(1.0)),
            c.from_config(SlipStopConfig, "stop_on_rotation",
                          "an estimate rotating at rotation_threshold_rad_s or faster counts "
                          "as slipping; false = act on planar slip only"),
            c.from_config(SlipStopConfig, "rotation_threshold_rad_s",
                          "|angular_velocity| that counts as slip [rad/s]",
                          c.in_range(0.01, 100.0)),
            c.Param("settle_result_s", 0.5, "final result this long after the stop [s]",
                    c.non_negative, read_only=True),
        ]

    def task_config(self, values: dict, direction=None) -> SlipStopConfig:
        """The core's config from the parameters named like its fields; ``direction`` the
        push direction in use (None: the core's default, for the parameter checks)."""
        kwargs = c.config_kwargs(SlipStopConfig, values)
        kwargs["direction"] = tuple(direction) if direction is not None else \
            SlipStopConfig.direction
        return SlipStopConfig(**kwargs)

    def _direction(self):
        d = np.asarray(self.p["direction"], dtype=float)
        if np.linalg.norm(d) > 0:
            return d
        task = (self.meta or {}).get("task", {})
        if "push_direction" in task:
            return np.asarray(task["push_direction"], dtype=float)
        return None

    def make_task(self):
        """The SlipStop core once the direction is known."""
        d = self._direction()
        if d is None:
            self.get_logger().info("waiting for the push direction on /aslip/metadata",
                                   throttle_duration_sec=2.0)
            return None
        self._stopped_at = None
        self._final_sent = False
        self.get_logger().info(f"wall push along {np.round(d, 4).tolist()} (link_base)")
        return SlipStop(self.task_config(self.p, d), clock=self.now_s)

    def start_task(self, now: float) -> bool:
        """Start from the current (contact) TCP pose."""
        self.task.start(now=now)
        self.get_logger().info("slip-stop trial started: retracting")
        return True

    def feed_slip(self, slip, now: float) -> None:
        """The planar slip decision and the angular velocity about the pad normal (0.0 from
        a decoder or a message without one) are what the wall-push task uses."""
        self.task.on_slip(slip.slipping, now, getattr(slip, "angular_velocity", 0.0))

    def after_step(self, now: float) -> None:
        """Publish the result at the stop and, final, once the arm has settled."""
        result = self.task.result()
        if result is None:
            return
        if self._stopped_at is None:
            self._stopped_at = now
            self._publish_result(result, final=False)
            self.get_logger().info(f"stopped: {result.reason.value}, stopping distance "
                                   f"{result.stopping_distance_m * 1e3:.1f} mm")
        elif not self._final_sent and now - self._stopped_at >= self.p["settle_result_s"]:
            self._final_sent = True
            self._publish_result(result, final=True)
            if self.p["exit_when_done"]:
                self.done = True

    def _publish_result(self, result, final: bool) -> None:
        doc = {"reason": result.reason.value, "success": result.success,
               "stopping_distance_m": result.stopping_distance_m,
               "command_distance_m": result.command_distance_m,
               "approach_travel_m": result.approach_travel_m,
               "approach_time_s": result.approach_time_s, "detail": result.detail,
               "final": final}
        if final:
            # How long after the newest valid slip estimate and pose the stop went out.
            doc.update(self.stop_latency())
        doc = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
               for k, v in doc.items()}
        if self._result_pub is not None:
            self._result_pub.publish(String(data=json.dumps(doc)))

    def status(self) -> dict:
        """Travel past the contact pose for the diagnostics."""
        if self.task is None:
            return {}
        travel = self.task.travel()
        out = {"task_rejected_inputs": self.task.rejected_inputs}
        if math.isfinite(travel):
            out["travel_m"] = travel
        return out


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros slip_stop``."""
    return run_node(SlipStopNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
