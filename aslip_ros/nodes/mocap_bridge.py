"""``mocap_bridge``: finger and object poses -> ground-truth slip on ``/aslip/slip_truth``.

Subscribes to two ``geometry_msgs/PoseStamped`` topics from any motion-capture driver
(vrpn_mocap, ...) or the scene, or with ``pose_source: rigid_bodies`` to one
``mocap4r2_msgs/RigidBodies`` topic (mocap4r2's OptiTrack, Vicon and Qualisys drivers), the
finger and object picked out of it by ``finger_body`` / ``object_body`` (name or numeric
ID, :mod:`aslip_ros.rigid_bodies`; a body missing from a message is named in a warning and
the diagnostics, with the bodies present). It keeps the last ``buffer_s`` of each,
and publishes the mean slip over the window ``[t - window_s, t]`` ending at the newest
instant both streams cover -- the planar velocity and, not gated by ``slipping``, the
angular velocity about the pad normal (``angular_velocity``; its sigma -1) -- computed by
:func:`aslip_ros.data.labels.mocap_window_velocity`, the same function the training export
labels windows with. The export reads each window's ends from poses smoothed over 150 ms
both ways in time; the bridge reads the raw poses at the ends, as a window ending "now"
has no later poses to smooth with (its truth carries the motion capture's noise: about
2 mm/s at 0.15 mm, docs/results.md, "Window labels from smoothed poses").

The grasp plane's pose in the finger's rigid body comes from ``calibration``:
``param`` (``grasp_plane_in_finger``), ``metadata`` (the key of the same name on
``/aslip/metadata``, identity until it arrives) or ``measure`` (the object's mean position
relative to the finger over the first ``calibration_s``, with the parameter's orientation:
the object is held centred between the pads at start).

Stale poses (no new pose on either topic for ``stale_timeout_s``) or a pose gap inside the
window give no output, a diagnostic and a throttled warning.

TF (``publish_tf``): the calibration in use, as the static transform ``finger_frame`` ->
``frame_id`` (re-sent when metadata or the measurement changes it), and ``frame_id`` ->
``aslip_gripper`` (identity: the audio frame), so the slip arrows join the frames the
scene or the motion-capture driver publishes (aslip_ros/frames.py); and, where no driver
publishes the rigid bodies on TF (``publish_pose_tf``), every accepted pose on ``/tf``
(aslip_ros/nodes/mocap_tf.py), so rviz can place them on a real cell.
"""

from __future__ import annotations

import collections
import json
import threading
import time
from typing import Optional

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from aslip_ros import frames, poses, rigid_bodies
from aslip_ros.msg import SlipVector
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import ConfigError, ready, run_node
from aslip_ros.runtime.qos import LATCHED_QOS, MARKER_QOS, RELIABLE_QOS, SENSOR_QOS
from aslip_ros.nodes import convert
from aslip_ros.slip import DEFAULT_THRESHOLD

IDENTITY = [float(x) for x in poses.IDENTITY_POSE]


def bridge_params() -> list:
    """mocap_bridge's parameter specs."""
    from aslip_ros.data.labels import DEFAULT_EPSILON_M_S, DEFAULT_MAX_GAP_S, DEFAULT_WINDOW_S
    from aslip_ros.nodes.mocap_tf import mocap_tf_params
    return mocap_tf_params() + [
        c.Param("pose_source", rigid_bodies.POSE_STAMPED, "pose_stamped: finger_topic and "
                "object_topic; rigid_bodies: finger_body and object_body of a mocap4r2 "
                "RigidBodies on rigid_bodies_topic", c.one_of(*rigid_bodies.POSE_SOURCES),
                read_only=True),
        c.Param("rigid_bodies_topic", c.RIGID_BODIES_TOPIC,
                "rigid_bodies: the mocap4r2 RigidBodies topic", c.non_empty, read_only=True),
        c.Param("finger_body", "", "rigid_bodies: the finger's rigid_body_name or numeric ID "
                "(OptiTrack: the Motive ID, e.g. 3)", read_only=True),
        c.Param("object_body", "", "rigid_bodies: the object's rigid_body_name or numeric ID",
                read_only=True),
        c.Param("finger_topic", c.FINGER_TOPIC, "finger rigid-body PoseStamped topic",
                c.non_empty, read_only=True),
        c.Param("object_topic", c.OBJECT_TOPIC, "object rigid-body PoseStamped topic",
                c.non_empty, read_only=True),
        c.Param("window_s", DEFAULT_WINDOW_S, "slip is averaged over this window [s]",
                c.in_range(0.005, 2.0)),
        c.Param("rate_hz", 100.0, "evaluation rate [Hz]", c.in_range(1.0, 1000.0),
                read_only=True),
        c.Param("epsilon_m_s", DEFAULT_EPSILON_M_S,
                "speeds above this count as slipping [m/s]", c.non_negative),
        c.Param("max_gap_s", DEFAULT_MAX_GAP_S,
                "longest pose dropout bridged by interpolation [s]", c.positive),
        c.Param("stale_timeout_s", 0.1, "no pose for this long = stale [s]", c.positive),
        c.Param("calibration", "param", "grasp-plane calibration: param, metadata, measure",
                c.one_of("param", "metadata", "measure"), read_only=True),
        c.Param("grasp_plane_in_finger", list(IDENTITY),
                "grasp-plane pose in the finger body (x y z qx qy qz qw) [m]", c.pose7,
                read_only=True),
        c.Param("calibration_s", 0.5, "measure: averaging time at start [s]", c.positive,
                read_only=True),
        c.Param("frame_id", convert.GRASP_FRAME, "frame of the published slip",
                c.non_empty, read_only=True),
        c.Param("marker", True, "also publish a ground-truth rviz marker", read_only=True),
        c.Param("publish_tf", True, "publish the calibration on /tf_static", read_only=True),
        c.Param("finger_frame", frames.FINGER,
                "TF frame of the finger rigid body (parent of frame_id on /tf_static)",
                c.non_empty, read_only=True),
    ]


#: How often mocap_bridge says which pose streams it is still waiting for [s].
WAITING_LOG_S = 5.0


class MocapBridge(Node):
    """Ground-truth slip from motion capture."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("mocap_bridge", **kwargs)
        self.p = c.declare_params(self, bridge_params(), self.p_update,
                                  cross_check=_cross_check)
        from aslip_ros.data import labels
        self._labels = labels
        self._lock = threading.Lock()
        keep = 1024
        self.finger = collections.deque(maxlen=keep)
        self.obj = collections.deque(maxlen=keep)
        self._arrival = {"finger": None, "object": None}
        self.calib: Optional[np.ndarray] = None
        if self.p["calibration"] == "param":
            self.calib = labels.as_pose(self.p["grasp_plane_in_finger"])
        elif self.p["calibration"] == "metadata":
            self.calib = labels.as_pose(IDENTITY)
        self._measure: list = []
        self._measure_t0: Optional[float] = None
        self._last_end: Optional[int] = None
        self.published = 0
        self.rejected = 0
        self.stale_events = 0
        self.gap_windows = 0
        self.state = "waiting for poses"
        rb = self.p["pose_source"] == rigid_bodies.RIGID_BODIES
        self.bodies = {r: self.p[f"{r}_body"] for r in rigid_bodies.ROLES} if rb else {}
        self.body_tally = rigid_bodies.BodyTally(self.bodies)
        self.body_problem = ""
        #: Where each pose comes from, in the node's messages.
        self.sources = ({r: f"{self.p['rigid_bodies_topic']} body {b!r}"
                         for r, b in self.bodies.items()} if rb else
                        {r: self.p[f"{r}_topic"] for r in rigid_bodies.ROLES})

        self.pub = self.create_publisher(SlipVector, c.SLIP_TRUTH_TOPIC, RELIABLE_QOS)
        self.pub_marker = (self.create_publisher(MarkerArray, c.MARKER_TOPIC + "_truth",
                                                 MARKER_QOS) if self.p["marker"] else None)
        self.diag = c.Diagnostics(self, "aslip: mocap_bridge", "motion capture")
        self.tf_static = None
        if self.p["publish_tf"]:
            from aslip_ros.nodes import tf_frames
            self.tf_static = tf_frames.StaticFrames(self)
            self.tf_static.set(self.p["frame_id"], frames.GRIPPER, IDENTITY)
            if self.calib is not None:
                self._publish_calibration(self.calib)
        from aslip_ros.nodes.mocap_tf import MocapFrames
        self.mocap_tf = MocapFrames(self, self.p, self.tf_static)
        group = MutuallyExclusiveCallbackGroup()
        if rb:
            # Sensor QoS: best effort serves the drivers' reliable depth-1000 publisher too.
            self.create_subscription(_rigid_bodies_msg(), self.p["rigid_bodies_topic"],
                                     self._on_rigid_bodies, SENSOR_QOS, callback_group=group)
        else:
            self.create_subscription(PoseStamped, self.p["finger_topic"],
                                     lambda m: self._on_pose("finger", m), SENSOR_QOS,
                                     callback_group=group)
            self.create_subscription(PoseStamped, self.p["object_topic"],
                                     lambda m: self._on_pose("object", m), SENSOR_QOS,
                                     callback_group=group)
        if self.p["calibration"] == "metadata":
            self.create_subscription(String, c.METADATA_TOPIC, self._on_metadata,
                                     LATCHED_QOS)
        self.create_timer(1.0 / self.p["rate_hz"], self._evaluate,
                          callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(1.0, self._diagnose, callback_group=MutuallyExclusiveCallbackGroup())
        ready(self, f"finger {self.sources['finger']}, object {self.sources['object']}, "
                    f"calibration {self.p['calibration']}")

    def p_update(self, changed: dict) -> None:
        """Apply accepted run-time parameter changes."""
        with self._lock:
            self.p.update(changed)

    # -- input --------------------------------------------------------------------------------

    def _on_metadata(self, msg: String) -> None:
        try:
            meta = json.loads(msg.data)
            calib = self._labels.as_pose(meta.get("grasp_plane_in_finger", IDENTITY))
        except (ValueError, TypeError, AttributeError) as exc:
            self.get_logger().error(f"metadata has no usable grasp_plane_in_finger: {exc}")
            return
        with self._lock:
            self.calib = calib
        self._publish_calibration(calib)
        self.get_logger().info(f"grasp-plane calibration from metadata: {calib.tolist()}")

    def _publish_calibration(self, calib) -> None:
        if self.tf_static is not None:
            self.tf_static.set(self.p["finger_frame"], self.p["frame_id"], calib)

    def _on_pose(self, which: str, msg: PoseStamped) -> None:
        try:
            stamp_ns, frame_id, pose = convert.pose_from_msg(msg)
        except ValueError as exc:
            self.rejected += 1
            self.get_logger().warning(f"{which} pose rejected: {exc}", throttle_duration_sec=1.0)
            return
        self._take(which, stamp_ns, frame_id, pose)

    def _on_rigid_bodies(self, msg) -> None:
        sel = convert.select_bodies(msg, self.bodies)
        with self._lock:
            self.body_tally.add(sel)
            self.body_problem = missing = rigid_bodies.missing_text(
                self.bodies, sel.missing, sel.present,
                f"the RigidBodies on {self.p['rigid_bodies_topic']}")
        if missing:
            self.get_logger().warning(missing, throttle_duration_sec=1.0)
        for which, raw in sel.poses.items():
            try:
                pose = poses.as_pose(raw, f"rigid body {self.bodies[which]!r}")
            except ValueError as exc:
                self.rejected += 1
                self.get_logger().warning(f"{which} pose rejected: {exc}",
                                          throttle_duration_sec=1.0)
                continue
            self._take(which, sel.stamp_ns, sel.frame_id, pose)

    def _take(self, which: str, stamp_ns: int, frame_id: str, pose: np.ndarray) -> None:
        """One accepted pose of ``which`` (finger or object), whatever message it came in."""
        with self._lock:
            buf = self.finger if which == "finger" else self.obj
            if buf and stamp_ns <= buf[-1][0]:
                self.rejected += 1
                return
            buf.append((stamp_ns, pose))
            self._arrival[which] = time.monotonic()
            if self.calib is None:
                self._collect_calibration()
        why = self.mocap_tf.pose(which, stamp_ns, frame_id, pose)
        if why:
            self.get_logger().warning(f"not on TF: {why}", throttle_duration_sec=5.0)

    def _collect_calibration(self) -> None:
        if not self.finger or not self.obj:
            return
        now = time.monotonic()
        if self._measure_t0 is None:
            self._measure_t0 = now
        self._measure.append((self.finger[-1][1], self.obj[-1][1]))
        if now - self._measure_t0 >= self.p["calibration_s"] and len(self._measure) >= 3:
            f, o = (np.array(x) for x in zip(*self._measure))
            self.calib = self._labels.measure_grasp_plane(
                f, o, self.p["grasp_plane_in_finger"][3:])
            self._publish_calibration(self.calib)
            self.get_logger().info(f"grasp-plane calibration measured: {self.calib.tolist()}")

    # -- output -------------------------------------------------------------------------------

    def _evaluate(self) -> None:
        now = time.monotonic()
        with self._lock:
            arrivals = list(self._arrival.values())
            if any(a is None for a in arrivals):
                self.state = "waiting for poses"
                missing = [f"{self.sources[which]} ({which})"
                           for which, t in self._arrival.items() if t is None]
                seen = f" ({self.body_problem})" if self.body_problem else ""
                self.get_logger().info(f"waiting for poses on {' and '.join(missing)}{seen}",
                                       throttle_duration_sec=WAITING_LOG_S)
                return
            age = now - min(arrivals)
            if age > self.p["stale_timeout_s"]:
                if self.state != "stale":
                    self.stale_events += 1
                    self.state = "stale"
                self.get_logger().warning(f"motion capture stale: no pose for {age:.3f} s",
                                          throttle_duration_sec=1.0)
                return
            if self.calib is None:
                self.state = "calibrating"
                return
            t_end_ns = min(self.finger[-1][0], self.obj[-1][0])
            if t_end_ns == self._last_end:
                return
            f = np.array([p for _, p in self.finger])
            tf = np.array([t for t, _ in self.finger])
            o = np.array([p for _, p in self.obj])
            to = np.array([t for t, _ in self.obj])
            calib = self.calib.copy()
            window, eps, gap = self.p["window_s"], self.p["epsilon_m_s"], self.p["max_gap_s"]
        # Only the tail that covers the window (plus one earlier sample) is interpolated.
        span_ns = int((window + gap + 0.05) * 1e9)
        kf = max(0, int(np.searchsorted(tf, t_end_ns - span_ns)) - 1)
        ko = max(0, int(np.searchsorted(to, t_end_ns - span_ns)) - 1)
        f, tf, o, to = f[kf:], tf[kf:], o[ko:], to[ko:]
        # Times relative to the window end keep float64 resolution far below 1 us.
        L = self._labels
        ref = t_end_ns
        ft = L.PoseTrack((tf - ref) * 1e-9, f, "finger")
        ot = L.PoseTrack((to - ref) * 1e-9, o, "object")
        lab = L.mocap_window_velocity(ft, ot, [-window], [0.0], calib, gap)
        self._last_end = t_end_ns
        if not lab.valid[0]:
            self.gap_windows += 1
            self.state = L.REASONS.get(int(lab.reason[0]), "invalid")
            return
        vx, vz = float(lab.vx[0]), float(lab.vz[0])
        slipping = float(lab.speed[0]) > eps
        try:
            msg = convert.slip_to_msg(vx, vz, 1.0 if slipping else 0.0, slipping,
                                      DEFAULT_THRESHOLD, t_end_ns, window, "mocap_truth",
                                      self.p["frame_id"],
                                      angular_velocity=float(lab.angular[0]))
        except ValueError as exc:
            self.get_logger().warning(f"truth not published: {exc}", throttle_duration_sec=1.0)
            return
        self.state = "running"
        self.pub.publish(msg)
        self.published += 1
        if self.pub_marker is not None:
            self.pub_marker.publish(convert.slip_markers(msg, ns="aslip_slip_truth",
                                                         alpha=0.6))

    def _diagnose(self) -> None:
        values = {"published": self.published, "rejected_poses": self.rejected,
                  "stale_events": self.stale_events, "gap_windows": self.gap_windows,
                  "finger_poses": len(self.finger), "object_poses": len(self.obj),
                  "state": self.state}
        if self.bodies:
            with self._lock:
                values.update({"rigid_bodies_messages": self.body_tally.messages,
                               "bodies_present": ", ".join(self.body_tally.seen),
                               "missing_bodies": self.body_tally.text() or "none"})
        if self.calib is not None:
            values["grasp_plane_in_finger"] = json.dumps([round(x, 6) for x in self.calib])
        level = {"running": c.Diagnostics.OK, "stale": c.Diagnostics.STALE}.get(
            self.state, c.Diagnostics.WARN)
        self.diag.publish(level, self.state, values)


def _cross_check(values: dict) -> Optional[str]:
    return _frames_differ(values) or _bodies_named(values)


def _bodies_named(values: dict) -> Optional[str]:
    rb = values["pose_source"] == rigid_bodies.RIGID_BODIES
    named = [f"{r}_body" for r in rigid_bodies.ROLES if str(values[f"{r}_body"]).strip()]
    if rb and len(named) < 2:
        return ("pose_source rigid_bodies needs finger_body and object_body (each a "
                "rigid_body_name of the RigidBodies, or the body's numeric ID)")
    if not rb and named:
        return (f"{' and '.join(named)} only apply to pose_source rigid_bodies (pose_source "
                f"is {values['pose_source']})")
    if rb and rigid_bodies.body_key(values["finger_body"]) == \
            rigid_bodies.body_key(values["object_body"]):
        return f"finger_body and object_body are the same body ({values['finger_body']!r})"
    return None


def _rigid_bodies_msg():
    try:
        return convert.rigid_bodies_class()
    except ValueError as exc:
        raise ConfigError(f"pose_source rigid_bodies: {exc}") from None


def _frames_differ(values: dict) -> Optional[str]:
    if values["finger_frame"] == values["frame_id"]:
        return (f"finger_frame and frame_id must differ (both {values['frame_id']!r}): "
                "the calibration is the transform between them")
    return None


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros mocap_bridge``."""
    return run_node(MocapBridge, args)


if __name__ == "__main__":
    raise SystemExit(main())
