"""``slip_track``: move the gripper with the object while it slips in the grasp.

The control law is :class:`aslip_ros.control.slip_track.SlipTrack`: the commanded gripper
velocity is the estimated OBJECT velocity, the TCP velocity measured over
``velocity_window_s`` plus ``gain`` times the predicted slip (deadband, low-pass, magnitude
saturation), plus, where set, ``position_gain_1_s`` times the integrated slip (off by
default: it fails its ablation), rotated from the grasp plane into ``link_base`` with
the newest TCP pose and the ``grasp_plane_in_tcp`` calibration. When slip ends it keeps the
last object velocity for ``hold_s``, decays it to zero with ``decay_s`` and waits for the
next slip (or, with ``stop_on_slip_end``, ends the task).
``duration_s`` > 0 ends the task after that long (with ``exit_when_done`` the node exits).
"""

from __future__ import annotations

from typing import Optional

from aslip_ros.control.slip_track import SlipTrack, SlipTrackConfig, TrackState
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import run_node
from aslip_ros.nodes.controller import ControllerNode


class SlipTrackNode(ControllerNode):
    """Slip-tracking controller."""

    task_name = "slip_track"

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        self._t_start: Optional[float] = None
        super().__init__("slip_track", **kwargs)

    def task_params(self) -> list:
        """Control-law parameters (SI), their defaults the core's :class:`SlipTrackConfig`."""
        return [
            c.from_config(SlipTrackConfig, "gain",
                          "fraction of the predicted slip corrected (0, 2)", c.positive),
            c.from_config(SlipTrackConfig, "deadband_m_s",
                          "slip speeds below this are ignored [m/s]", c.non_negative),
            c.from_config(SlipTrackConfig, "max_speed_m_s", "commanded speed limit [m/s]",
                          c.positive),
            c.from_config(SlipTrackConfig, "lowpass_tau_s",
                          "command low-pass time constant [s]; 0 = off", c.non_negative),
            c.from_config(SlipTrackConfig, "hold_s",
                          "keep the object velocity this long after slip ends [s]",
                          c.non_negative),
            c.from_config(SlipTrackConfig, "decay_s",
                          "then decay it to zero with this time constant [s]",
                          c.non_negative),
            c.from_config(SlipTrackConfig, "velocity_window_s",
                          "TCP velocity measured over this span (the model's window) [s]",
                          c.positive),
            c.from_config(SlipTrackConfig, "position_gain_1_s",
                          "integrated-slip position gain [1/s]; 0 = off", c.non_negative),
            c.from_config(SlipTrackConfig, "position_leak_s",
                          "leak of the integrated slip [s]; 0 = none", c.non_negative),
            c.from_config(SlipTrackConfig, "max_offset_m", "clip of the integrated slip [m]",
                          c.non_negative),
            c.from_config(SlipTrackConfig, "stop_on_slip_end", "end the task when slip ends"),
            c.Param("duration_s", 0.0, "end the task after this long [s]; 0 = never",
                    c.non_negative, read_only=True),
        ]

    def task_config(self, values: dict) -> SlipTrackConfig:
        """The core's config: every parameter named like one of its fields (the law's and
        the shared timeouts, command duration and grasp plane)."""
        return SlipTrackConfig(**c.config_kwargs(SlipTrackConfig, values))

    def make_task(self):
        """A fresh SlipTrack controller."""
        self._t_start = None
        return SlipTrack(self.task_config(self.p), clock=self.now_s)

    def start_task(self, now: float) -> bool:
        """Start tracking."""
        self.task.start(now=now)
        self._t_start = now
        self.get_logger().info("slip tracking started")
        return True

    def feed_slip(self, slip, now: float) -> None:
        """Grasp-plane slip vector and decision."""
        self.task.on_slip((slip.vx, slip.vz), slip.slipping, now)

    def feed_pose(self, pose, now: float, stamp_ns: int) -> None:
        """TCP pose with its stamp: the arm velocity is measured on the sensor's clock."""
        self.task.on_tcp_pose(pose, now, stamp=stamp_ns * 1e-9 if stamp_ns > 0 else None)

    def after_step(self, now: float) -> None:
        """End the task after ``duration_s``; exit when asked to once stopped."""
        if self._t_start is None:
            return
        limit = self.p["duration_s"]
        if limit > 0.0 and now - self._t_start >= limit and \
                self.task.state is not TrackState.STOPPED:
            self.get_logger().info(f"tracking ran {limit:g} s; stopping")
            self.task.shutdown(now)
            self.post(self.task.step(now))
        if self.task.state is TrackState.STOPPED and self.p["exit_when_done"]:
            self.done = True

    def status(self) -> dict:
        """Commanded velocity and stop reason."""
        if self.task is None:
            return {}
        v = self.task.last_velocity
        out = {"cmd_vx": v[0], "cmd_vy": v[1], "cmd_vz": v[2]}
        if self.task.reason:
            out["stop_reason"] = self.task.reason
        if self._t_start is not None:
            out["tracking_s"] = self.now_s() - self._t_start
        return out


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros slip_track``."""
    return run_node(SlipTrackNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
