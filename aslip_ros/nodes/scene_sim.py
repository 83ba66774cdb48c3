"""``scene_sim``: the simulated scene as a node, so closed loops run through real topics.

Steps :class:`aslip_ros.scene.World` in real time (one block per ``block_s``) and publishes
what the real cell would: ``/aslip/audio``, ``/aslip/mocap/finger``, ``/aslip/mocap/object``,
``/aslip/robot/tcp_pose`` and the latched ``/aslip/metadata``. It executes the controllers'
``/aslip/arm/cmd_vel`` (TwistStamped, ``link_base``) on the scene's simulated arm: each
command holds for ``command_timeout_s`` and the arm stops by itself when no newer one comes,
like the xArm's ``duration``.

TF: ``world`` -> ``link_base`` (static identity: they coincide in the scene) and, while
anyone listens on ``/tf``, the finger, object and TCP poses of each block as
``aslip_finger``, ``aslip_object`` and ``aslip_tcp`` (aslip_ros/frames.py).

Lockstep (``lockstep``): the scene stops pacing itself against the wall clock. A driver in
the same process (the closed-loop demo, ``benchmarks.demo_episode``) steps one block with
:meth:`SceneSim.lockstep_block` once the graph has handled the one before, and publishes the
simulated time on ``/clock`` with :meth:`SceneSim.lockstep_clock` when the block's estimate
is due (the block's end plus the compute time charged for it); lockstep controllers step
once per tick. A command that arrives then takes effect ``command_delay_s`` after that tick,
inside the next block (which is stepped in pieces at each command), so the graph's latency
is in the trial although nothing depends on the host's speed.

For evaluation (the closed-loop demo) it can write the world's true trajectory, the wall
contact and the slip onset to ``trajectory_out`` (``.npz``) when the run ends.
"""

from __future__ import annotations

import collections
import json
import threading
import time
from pathlib import Path
from typing import Optional

import numpy as np
from geometry_msgs.msg import PoseStamped, TwistStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import String

from aslip_ros import frames, topics
from aslip_ros.arm import ArmError
from aslip_ros.hw import sources
from aslip_ros.hw.sources import world_metadata
from aslip_ros.msg import AudioFrame
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import ConfigError, ready, run_node
from aslip_ros.runtime.qos import CLOCK_QOS, LATCHED_QOS, RELIABLE_QOS, SENSOR_QOS
from aslip_ros.nodes import convert
from aslip_ros.nodes.scene_params import scene_params


def build_world(values: dict, prefix: str = ""):
    """A :class:`aslip_ros.scene.World` from scene parameter values; unusable ones are a
    :class:`~aslip_ros.runtime.process.ConfigError` (the node refuses to start)."""
    try:
        return sources.build_world(values, prefix)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc


def merge_chunks(pieces: list):
    """One chunk of consecutive pieces of the scene's stream (a block stepped in parts)."""
    first = pieces[0]
    w = [p.w_rel for p in pieces]
    return type(first)(first.first_sample_index, first.t0,
                       np.concatenate([p.audio for p in pieces]),
                       [m for p in pieces for m in p.mocap], [s for p in pieces for s in p.tcp],
                       np.concatenate([p.v_rel for p in pieces]),
                       None if any(x is None for x in w) else np.concatenate(w))


class PacedScene:
    """Steps a world block by block against the wall clock; ROS stamps from a start time.

    ``due_blocks(now)`` says how many blocks the wall clock asks for; callers step them.
    Falling further behind than ``max_catch_up`` blocks skips time instead of bursting
    (counted in ``skipped_blocks``), so a stalled machine does not flood subscribers.
    """

    def __init__(self, world, block_frames: int, start_ns: int, max_catch_up: int = 10,
                 clock=time.monotonic) -> None:
        self.world = world
        self.block_frames = int(block_frames)
        self.start_ns = int(start_ns)
        self._clock = clock
        self._t0 = clock()
        self._blocks = 0
        self._skip = 0
        self.max_catch_up = int(max_catch_up)
        self.skipped_blocks = 0

    @property
    def block_s(self) -> float:
        """Block length [s]."""
        return self.block_frames / self.world.fs

    def due_blocks(self) -> int:
        """Blocks to step now to keep up with the wall clock."""
        due = int((self._clock() - self._t0) / self.block_s) - self._blocks - self._skip
        if due > self.max_catch_up:
            self.skipped_blocks += due - self.max_catch_up
            self._skip += due - self.max_catch_up
            due = self.max_catch_up
        return max(0, due)

    def step(self):
        """Advance one block; returns the scene chunk."""
        self._blocks += 1
        return self.world.step(self.block_frames)

    def step_frames(self, n: int):
        """Advance ``n`` frames (a piece of a lockstep block); returns the scene chunk."""
        return self.world.step(n)

    def stamp_ns(self, t_s: float) -> int:
        """ROS stamp of scene time ``t_s``."""
        return self.start_ns + int(round(t_s * 1e9))


class SceneSim(Node):
    """The simulated world, its sensors and its arm, on topics."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("scene_sim", **kwargs)
        specs = scene_params() + [
            c.Param("block_s", 0.01, "audio block length [s]", c.in_range(0.001, 0.1),
                    read_only=True),
            c.Param("duration_s", 0.0, "stop stepping after this much scene time [s]; 0 = "
                    "run until shut down", c.non_negative, read_only=True),
            c.Param("exit_when_done", False, "exit once duration_s is reached",
                    read_only=True),
            c.Param("command_timeout_s", 0.1,
                    "each arm command holds this long [s] unless renewed",
                    c.in_range(0.005, 1.0)),
            c.Param("trajectory_out", "", "write the true trajectory (.npz) here at the end",
                    read_only=True),
            c.Param("frame_id", convert.SENSOR_FRAME, "audio frame id", c.non_empty,
                    read_only=True),
            c.Param("lockstep", False, "step only when a driver in this process says the "
                    f"graph has handled the last block, publishing {topics.CLOCK} (module "
                    "docstring); false = real time", read_only=True),
            c.Param("start_with_subscriber", False, f"hold the scene's clock at 0 until "
                    f"{c.AUDIO_TOPIC} has a subscriber (a recorder, or the closed loop's "
                    "slip_inference), so no scene second is lost to a reader that starts "
                    "late", read_only=True),
        ]
        self.p = c.declare_params(self, specs, self._on_change)
        self.world = build_world(self.p)
        self.world.arm.connect()
        if self.world.scenario.kind != "robot_induced":
            self.world.arm.enable_velocity_mode()
        fs = self.world.fs
        self.block_frames = max(1, int(round(self.p["block_s"] * fs)))
        self.meta = world_metadata(self.world)
        self.names = list(self.meta["channel_names"])
        self.cmd_timeout = float(self.p["command_timeout_s"])
        self.done = False
        self.exit_code = 0
        self._lock = threading.Lock()
        self._written = False
        self._finished = False
        self.n_commands = 0
        self.n_rejected = 0

        self.pub_audio = self.create_publisher(AudioFrame, c.AUDIO_TOPIC, SENSOR_QOS)
        self.pub_finger = self.create_publisher(PoseStamped, c.FINGER_TOPIC, SENSOR_QOS)
        self.pub_object = self.create_publisher(PoseStamped, c.OBJECT_TOPIC, SENSOR_QOS)
        self.pub_tcp = self.create_publisher(PoseStamped, c.TCP_TOPIC, SENSOR_QOS)
        self.pub_meta = self.create_publisher(String, c.METADATA_TOPIC, LATCHED_QOS)
        self.diag = c.Diagnostics(self, "aslip: scene_sim", "scene")
        from aslip_ros.nodes import tf_frames
        self._tf_msg = tf_frames.transform_msg
        self.tf = tf_frames.DynamicFrames(self)
        self.tf_static = tf_frames.StaticFrames(self)
        self.tf_static.set(frames.WORLD, frames.BASE, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        self.create_subscription(TwistStamped, c.CMD_VEL_TOPIC, self._on_cmd, RELIABLE_QOS,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.pub_meta.publish(String(data=json.dumps(self.meta)))
        self._hold = bool(self.p["start_with_subscriber"])
        self.scene = PacedScene(self.world, self.block_frames,
                                self.get_clock().now().nanoseconds)
        self.lockstep = bool(self.p["lockstep"])
        #: Lockstep: commands waiting for their time, ``(scene time [s], velocity)``; the
        #: newest tick; the delay charged to each command after its tick [s].
        self._queued: collections.deque = collections.deque()
        self._tick_s = 0.0
        self.command_delay_s = 0.0
        self.tcp_published = 0
        if self.lockstep:
            self.pub_clock = self.create_publisher(ClockMsg, topics.CLOCK, CLOCK_QOS)
            self.lockstep_clock(0.0)
        else:
            # The stepping timer and the diagnostics timer never block each other.
            self.create_timer(self.scene.block_s / 2.0, self._tick,
                              callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(1.0, self._diagnose, callback_group=MutuallyExclusiveCallbackGroup())
        ready(self, f"scenario {self.world.scenario.kind}, {len(self.names)} channels at "
                    f"{fs:g} Hz, {self.block_frames}-frame blocks")

    def _on_change(self, changed: dict) -> None:
        if "command_timeout_s" in changed:
            self.cmd_timeout = float(changed["command_timeout_s"])

    def _on_cmd(self, msg: TwistStamped) -> None:
        try:
            v = convert.twist_from_msg(msg)
            if self.lockstep:
                self._queued.append((self._tick_s + self.command_delay_s, v))
            else:
                self._command(v)
            self.n_commands += 1
        except (ArmError, ValueError) as exc:
            self.n_rejected += 1
            self.get_logger().warning(f"arm command refused: {exc}", throttle_duration_sec=1.0)

    def _command(self, v: np.ndarray, hold_s: Optional[float] = None) -> None:
        """Hand one velocity (zero: a stop) to the simulated arm, to hold ``hold_s``
        (default ``command_timeout_s``)."""
        with self._lock:
            if float(np.linalg.norm(v)) == 0.0:
                self.world.arm.stop()
            else:
                self.world.arm.send_velocity(v, self.cmd_timeout if hold_s is None
                                             else hold_s)

    # -- lockstep ------------------------------------------------------------------------------

    def lockstep_clock(self, t_s: float) -> float:
        """Publish scene time ``t_s`` on ``/clock`` (never backwards); returns the tick."""
        self._tick_s = max(self._tick_s, float(t_s))
        self.pub_clock.publish(ClockMsg(clock=convert.ns_to_stamp(
            self.scene.stamp_ns(self._tick_s))))
        return self._tick_s

    def lockstep_block(self) -> bool:
        """Step and publish one block, each queued command taking effect at its time
        (the block is stepped in pieces there); False once ``duration_s`` is reached."""
        limit = self.p["duration_s"]
        if self._finished:
            return False
        if limit > 0.0 and self.world.t >= limit:
            self._finish()
            return False
        fs, left, pieces = self.world.fs, self.block_frames, []
        while left > 0:
            while self._queued and self._queued[0][0] <= self.world.t + 0.5 / fs:
                self._apply_queued(self._queued.popleft()[1])
            self._renew_held(self.world.t + left / fs)
            n = left
            if self._queued:
                n = min(left, max(1, int(round((self._queued[0][0] - self.world.t) * fs))))
            pieces.append(self.scene.step_frames(n))
            left -= n
        self._publish(pieces[0] if len(pieces) == 1 else merge_chunks(pieces))
        return True

    def _renew_held(self, end_s: float) -> None:
        """Queued commands before ``end_s`` that only renew what the arm already does
        (same velocity, not yet expired) take effect now, with the deadline they would have
        had: the motion is the same, and the block is stepped in fewer pieces."""
        arm = self.world.arm
        while self._queued and self._queued[0][0] < end_s and \
                arm.holds(self._queued[0][1], self._queued[0][0]):
            t, v = self._queued.popleft()
            self._apply_queued(v, self.cmd_timeout + (t - self.world.t))

    def _apply_queued(self, v: np.ndarray, hold_s: Optional[float] = None) -> None:
        try:
            self._command(v, hold_s)
        except (ArmError, ValueError) as exc:
            self.n_rejected += 1
            self.get_logger().warning(f"arm command refused: {exc}", throttle_duration_sec=1.0)

    def _tick(self) -> None:
        if self._finished or self._waiting_for_subscriber():
            return
        limit = self.p["duration_s"]
        for _ in range(self.scene.due_blocks()):
            if limit > 0.0 and self.world.t >= limit:
                self._finish()
                return
            with self._lock:
                chunk = self.scene.step()
            self._publish(chunk)

    def _waiting_for_subscriber(self) -> bool:
        """With ``start_with_subscriber``: True until the audio topic is subscribed; the
        scene's clock (and its stamps) start when it is."""
        if not self._hold:
            return False
        if self.pub_audio.get_subscription_count() == 0:
            self.get_logger().info(f"waiting for a subscriber on {c.AUDIO_TOPIC} before "
                                   "the scene starts", throttle_duration_sec=5.0)
            return True
        self._hold = False
        self.scene = PacedScene(self.world, self.block_frames,
                                self.get_clock().now().nanoseconds)
        self.get_logger().info(f"{c.AUDIO_TOPIC} is subscribed: the scene starts")
        return False

    def _publish(self, chunk) -> None:
        st = self.scene.stamp_ns
        self.pub_audio.publish(convert.audio_to_msg(
            chunk.first_sample_index, st(chunk.t0), self.world.fs, self.names, chunk.audio,
            self.meta.get("layout", ""), self.p["frame_id"]))
        # The poses go out only to whoever listens (a recorder, mocap_bridge), as the TF
        # frames below: an unmatched publisher would only serialize them for no one.
        if self.pub_finger.get_subscription_count() or \
                self.pub_object.get_subscription_count():
            for m in chunk.mocap:
                self.pub_finger.publish(convert.pose_to_msg(m.finger_pose, st(m.t),
                                                            frames.WORLD))
                self.pub_object.publish(convert.pose_to_msg(m.object_pose, st(m.t),
                                                            frames.WORLD))
        for t, pose in chunk.tcp:
            self.pub_tcp.publish(convert.pose_to_msg(pose, st(t), frames.BASE))
        self.tcp_published += len(chunk.tcp)
        if self.tf.wanted:
            tf = self._tf_msg
            self.tf.publish(
                [tf(frames.WORLD, body, pose, st(m.t)) for m in chunk.mocap
                 for body, pose in ((frames.FINGER, m.finger_pose),
                                    (frames.OBJECT, m.object_pose))]
                + [tf(frames.BASE, frames.TCP, pose, st(t)) for t, pose in chunk.tcp])

    def _diagnose(self) -> None:
        w = self.world
        values = {"scene_time_s": w.t, "arm_commands": self.n_commands,
                  "arm_commands_refused": self.n_rejected,
                  "skipped_blocks": self.scene.skipped_blocks,
                  "tcp_x": w.tcp_pose()[0], "tcp_y": w.tcp_pose()[1], "tcp_z": w.tcp_pose()[2]}
        if w.wall_contact_time is not None:
            values["wall_contact_time_s"] = w.wall_contact_time
        level = c.Diagnostics.WARN if self.scene.skipped_blocks else c.Diagnostics.OK
        msg = "done" if self._finished else "running"
        if self.scene.skipped_blocks:
            msg += f"; fell behind real time ({self.scene.skipped_blocks} blocks skipped)"
        self.diag.publish(level, msg, values)

    def _finish(self) -> None:
        self._finished = True
        self.get_logger().info(f"scene time {self.world.t:.2f} s reached; world stopped")
        self._write_trajectory()
        # Without exit_when_done the node stays up (metadata, diagnostics), world frozen.
        self.done = bool(self.p["exit_when_done"])

    def _write_trajectory(self) -> None:
        out = self.p["trajectory_out"]
        if not out or self._written or not self.world.record:
            return
        self._written = True
        w = self.world
        traj = w.trajectory()
        extra = {"wall_contact_time": np.nan if w.wall_contact_time is None
                 else w.wall_contact_time,
                 "slip_onset_time": np.nan if w.slip_onset_time is None else w.slip_onset_time,
                 "wall_contact_tcp_position": (np.full(3, np.nan)
                                               if w.wall_contact_tcp_position is None
                                               else w.wall_contact_tcp_position),
                 "start_ns": self.scene.start_ns}
        path = Path(out)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, metadata=json.dumps(self.meta), **traj, **extra)
        tmp.replace(path)
        self.get_logger().info(f"trajectory written to {path}")

    def before_shutdown(self) -> None:
        """Write the trajectory when stopped before ``duration_s``."""
        self._write_trajectory()


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros scene_sim``."""
    return run_node(SceneSim, args)


if __name__ == "__main__":
    raise SystemExit(main())
