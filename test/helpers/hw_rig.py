"""Stand-in hardware rig for the hardware rehearsal tests: the simulated scene behind the
real interfaces (a test helper; run it as a process).

Runs an :class:`aslip_ros.scene.World` in real time and speaks what the real cell speaks:

- **Audio interface** (piezo contact mics): the world's audio, float32 little-endian
  interleaved, written paced to real time into the FIFO ``--fifo``, which is the ``infile``
  of an ALSA ``file`` PCM over a ``null`` slave (config: :func:`alsa_config`). The null
  slave is unpaced, so PortAudio's reads block on the FIFO: the rig's writes pace the
  capture. Measured (alsa-lib 1.2.8, PortAudio 19.6): exact samples, contiguous indices,
  ~100 blocks/s of 480 frames. Rules found experimentally:

  * every write is ``--block-frames`` frames and the capture's block (``audio_capture``
    ``block_s * sample_rate``) must divide it: the file plugin does ONE ``read()`` per
    PortAudio block and a short read is not retried: the missing part of the block is
    left stale, silently (no overflow, no index gap). Default 480 = ``block_s`` 0.01.
  * the FIFO must exist before PortAudio initialises (it opens every configured PCM while
    enumerating: the open blocks until the rig is running; a missing file hides the
    device). The rig creates it.
  * the rig opens the FIFO non-blocking and only writes whole blocks when the pipe has room
    (pipe grown to 1 MiB); without a reader the blocks are dropped, like an ADC nobody
    records. A reader that closes (PortAudio's enumeration probe, a stopped stream) gives
    EPIPE: the rig reconnects to the next reader.
  * when the rig exits (EOF on the FIFO) the capture does NOT stop: the file plugin reads 0
    bytes and the null slave runs unpaced: PortAudio delivers stale blocks at ~30,000/s.
    Stop ``audio_capture`` BEFORE the rig.

- **Motion capture driver**: finger and object rigid bodies as ``geometry_msgs/PoseStamped``
  on ``--finger-topic`` / ``--object-topic`` (sensor-data QoS: best effort, depth 5),
  ``frame_id`` ``--frame-id`` (``mocap``), at the world's mocap rate (120 Hz), with its
  latency (8.3 ms: published that long after the instant it stamps) and noise; each stamped
  with the wall-clock time the sample represents: ``wall0 + t``, where audio frame ``i``
  represents ``wall0 + i / fs``. Audio blocks are written when their FIRST frame is due
  (``--audio-lead-blocks 1``): PortAudio reports no input latency for the null PCM
  (``currentTime == inputBufferAdcTime``), so ``audio_capture`` stamps a block at its
  arrival; written at its last frame (``0``) every audio stamp would be one block (10 ms)
  late against the poses. Measured with 1: audio stamps ~1 ms after the truth.

- **xArm controller**: JSON lines over TCP on 127.0.0.1:``--xarm-port`` (0 = any free
  port), spoken by the fake SDK ``test/helpers/fake_xarm_sdk`` (``XArmAPI``). Every call is
  one JSON line in ``--calls-log`` (``t`` wall time, ``scene_t``, ``call``, ``args``,
  ``kwargs``, ``ret``). Velocity commands (mm/s) are checked against ``--max-speed`` [m/s]
  and the box ``--workspace-min/--workspace-max`` [m] (the end point ``p + v * duration``,
  1 mm tolerance) and ``duration > 0``; a violation is a ``{"violation": {...}}`` line and
  the command is refused (code 12 parameter error, -6 Cartesian limit). Accepted commands
  drive the world's simulated arm (``arm.send_velocity``; first-order lag, stops after
  ``duration``); ``set_state(4)`` stops it. ``robot_induced`` runs with the scene's
  ``commanded_arm``: the probe stands in the world and the arm moves as commanded (by
  robot_sweeps), not by the scene's own sweeps. ``get_position`` answers the world's
  TCP in mm and rad (fixed-axis x-y-z roll/pitch/yaw, as the driver reads them).

Other outputs: one JSON line on stdout when ready (``{"ready": true, "xarm_port": P, ...}``)
and, with ``--status PATH``, JSON-line events (``start`` with ``wall0``, ``audio_connected``
with the world sample index that the reader's first block starts at, ``audio_disconnected``,
``stall`` with the wall and CPU seconds of the loop's gap and the load average, ``exit``
with counters). Nothing on ``/aslip/*``: a real cell has no scene.

Exits on SIGINT/SIGTERM, after ``--duration-s`` of scene time, and when its parent process
goes (the parent pid is polled every block; ``PR_SET_PDEATHSIG`` is not used because it
fires when the spawning *thread* ends, e.g. a launch service's worker thread).

Does not model: a sound card's clock (the rig's clock is the host's: no drift, no ADC
timestamps: PortAudio reports none for the null PCM, so ``audio_capture`` stamps the block
as received minus one block length), input overflow flags, the xArm's dynamics beyond the
scene's first-order lag, joint limits, controller errors/warnings (always ``[0, 0]``),
collisions, the mocap driver's own frames/TF, or a network between the machines.
"""

from __future__ import annotations

import argparse
import errno
import fcntl
import json
import math
import os
import signal
import socket
import socketserver
import stat
import struct
import sys
import termios
import threading
import time
import traceback
from collections import deque
from pathlib import Path

import numpy as np

#: ALSA configuration for a capture device reading the FIFO (``ALSA_CONFIG_PATH`` replaces
#: alsa.conf, so nothing else loads; PortAudio aborts without a default PCM).
ALSA_CONFIG = """\
pcm.!default {{ type null }}
pcm.{name} {{
    type file
    slave.pcm {{ type null }}
    file "/dev/null"
    infile "{fifo}"
    format "raw"
}}
"""

FIRMWARE = (2, 3, 0)
MODE_VELOCITY, STATE_MOTION, STATE_STOP = 5, 0, 4
CODE_PARAM, CODE_CARTESIAN_LIMIT, CODE_NOT_READY = 12, -6, 9
F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)
F_GETPIPE_SZ = getattr(fcntl, "F_GETPIPE_SZ", 1032)


def alsa_config(fifo: str, name: str = "aslip_rig") -> str:
    """The ALSA configuration text for a PCM ``name`` capturing from ``fifo``."""
    return ALSA_CONFIG.format(name=name, fifo=fifo)


class JsonLines:
    """Append-only JSON-lines file, line-buffered, thread-safe."""

    def __init__(self, path: str | None) -> None:
        self._f = open(path, "a", buffering=1) if path else None
        self._lock = threading.Lock()

    def write(self, doc: dict) -> None:
        if self._f is None:
            return
        line = json.dumps(doc, default=float)
        with self._lock:
            self._f.write(line + "\n")

    def close(self) -> None:
        if self._f is not None:
            with self._lock:
                self._f.close()


class FifoSink:
    """Writes whole audio blocks into the FIFO when a reader is there (never blocks)."""

    def __init__(self, path: str, events: JsonLines) -> None:
        self.path = path
        self.events = events
        self.fd: int | None = None
        self.capacity = 0
        self.blocks_written = 0
        self.blocks_unconnected = 0
        self.blocks_overflowed = 0
        self.connections = 0
        p = Path(path)
        if p.exists() and not stat.S_ISFIFO(p.stat().st_mode):
            raise SystemExit(f"hw_rig: {path} exists and is not a FIFO")
        if not p.exists():
            os.mkfifo(path)

    def _open(self, world_index: int) -> bool:
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK)
        except OSError as exc:
            if exc.errno in (errno.ENXIO, errno.EINTR):
                return False          # no reader yet
            raise
        try:
            fcntl.fcntl(fd, F_SETPIPE_SZ, 1 << 20)
        except OSError:
            pass
        self.capacity = fcntl.fcntl(fd, F_GETPIPE_SZ)
        self.fd = fd
        self.connections += 1
        self.events.write({"event": "audio_connected", "world_index": world_index,
                           "wall": time.time(), "pipe_bytes": self.capacity})
        return True

    def _drop_connection(self, world_index: int) -> None:
        os.close(self.fd)
        self.fd = None
        self.events.write({"event": "audio_disconnected", "world_index": world_index,
                           "wall": time.time()})

    def write(self, data: bytes, world_index: int) -> None:
        if self.fd is None and not self._open(world_index):
            self.blocks_unconnected += 1
            return
        queued = struct.unpack("i", fcntl.ioctl(self.fd, termios.FIONREAD, b"\0\0\0\0"))[0]
        if self.capacity - queued < len(data):
            self.blocks_overflowed += 1       # reader > ~1 MiB behind: a device would overflow
            return
        try:
            n = os.write(self.fd, data)
        except BrokenPipeError:
            self._drop_connection(world_index)
            self.blocks_unconnected += 1
            return
        except BlockingIOError:
            self.blocks_overflowed += 1
            return
        if n != len(data):                    # cannot happen with room checked; never split
            raise RuntimeError(f"partial FIFO write {n} of {len(data)} bytes")
        self.blocks_written += 1

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def _pose_mm_rad(pose7: np.ndarray) -> list:
    from scipy.spatial.transform import Rotation
    rpy = Rotation.from_quat(pose7[3:7]).as_euler("xyz")
    return [float(v) for v in (pose7[:3] * 1000.0)] + [float(a) for a in rpy]


class Controller:
    """The fake xArm controller's state and calls (thread-safe with the world lock)."""

    def __init__(self, rig: "Rig", log: JsonLines, max_speed: float | None,
                 lo: np.ndarray | None, hi: np.ndarray | None) -> None:
        self.rig = rig
        self.log = log
        self.max_speed = max_speed
        self.lo, self.hi = lo, hi
        self.mode = 0
        self.state = STATE_STOP
        self.enabled = False
        self.violations = 0
        self.executed = 0
        self.tol_m = 1e-3

    def handle(self, op: str, args: list, kwargs: dict, conn: int) -> object:
        rig = self.rig
        extra: dict = {}
        with rig.lock:
            scene_t = rig.world.t
            if op == "connect":
                ret = {"version_number": list(FIRMWARE), "mode": self.mode,
                       "state": self.state}
            elif op == "motion_enable":
                self.enabled = bool(kwargs.get("enable", True))
                ret = 0
            elif op == "set_mode":
                self.mode = int(args[0] if args else kwargs.get("mode", 0))
                ret = 0
            elif op == "set_state":
                self.state = int(args[0] if args else kwargs.get("state", 0))
                if self.state == STATE_STOP:
                    rig.world.arm.stop()
                ret = 0
            elif op == "vc_set_cartesian_velocity":
                ret, extra = self._velocity(args, kwargs)
            elif op == "get_position":
                ret = [0, _pose_mm_rad(rig.world.tcp_pose())]
            elif op == "get_err_warn_code":
                ret = [0, [0, 0]]
            elif op in ("clean_warn", "clean_error", "disconnect",
                        "register_report_location_callback",
                        "release_report_location_callback"):
                ret = 0
            else:
                ret = -4                       # command does not exist
        if op != "get_position" or rig.log_positions:
            self.log.write({"t": time.time(), "scene_t": scene_t, "conn": conn, "call": op,
                            "args": args, "kwargs": kwargs,
                            "ret": ret if not isinstance(ret, dict) else 0, **extra})
        if op == "connect":
            return ret
        return {"ret": ret, "mode": self.mode, "state": self.state}

    def _velocity(self, args: list, kwargs: dict) -> tuple:
        rig = self.rig
        speeds = np.asarray(args[0] if args else kwargs.get("speeds"), dtype=float)
        duration = float(kwargs.get("duration", -1))
        v = speeds[:3] / 1000.0
        problems = []
        if speeds.shape != (6,) or not np.all(np.isfinite(speeds)):
            problems.append({"kind": "malformed", "speeds": speeds.tolist()})
        else:
            if kwargs.get("is_tool_coord"):
                problems.append({"kind": "tool_coord", "detail": "only base frame modelled"})
            if np.any(speeds[3:] != 0.0):
                problems.append({"kind": "rotation", "rad_s": speeds[3:].tolist()})
            if not (math.isfinite(duration) and duration > 0.0):
                problems.append({"kind": "duration", "duration": duration})
            speed = float(np.linalg.norm(v))
            if self.max_speed is not None and speed > self.max_speed * (1 + 1e-9):
                problems.append({"kind": "speed", "speed_m_s": speed,
                                 "max_speed_m_s": self.max_speed})
            if self.lo is not None and speed > 0.0 and duration > 0.0:
                p = rig.world.tcp_pose()[:3]
                end = p + v * duration
                if np.any(end < self.lo - self.tol_m) or np.any(end > self.hi + self.tol_m):
                    problems.append({"kind": "workspace", "tcp_m": p.tolist(),
                                     "end_m": end.tolist(), "min_m": self.lo.tolist(),
                                     "max_m": self.hi.tolist()})
        if problems:
            self.violations += 1
            self.log.write({"t": time.time(), "scene_t": rig.world.t,
                            "violation": {"call": "vc_set_cartesian_velocity",
                                          "speeds": speeds.tolist(), "duration": duration,
                                          "problems": problems}})
            code = CODE_CARTESIAN_LIMIT if problems[0]["kind"] == "workspace" else CODE_PARAM
            return code, {"executed": False}
        if not (self.enabled and self.mode == MODE_VELOCITY and self.state == STATE_MOTION):
            return CODE_NOT_READY, {"executed": False}
        rig.world.arm.send_velocity(v, duration)
        self.executed += 1
        return 0, {"executed": True}


class _Handler(socketserver.StreamRequestHandler):
    def handle(self) -> None:
        rig: Rig = self.server.rig
        conn = id(self) & 0xFFFF
        self.request.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for raw in self.rfile:
            try:
                req = json.loads(raw)
                op = req["op"]
            except (ValueError, KeyError, TypeError) as exc:
                self.wfile.write(json.dumps({"error": f"bad request: {exc}"}).encode() + b"\n")
                continue
            if op == "subscribe_reports":
                self.wfile.write(json.dumps({"id": req.get("id"), "ret": 0}).encode() + b"\n")
                self._stream_reports(rig)
                return
            try:
                ret = rig.controller.handle(op, req.get("args", []), req.get("kwargs", {}),
                                            conn)
                out = {"id": req.get("id"), "ret": ret}
            except Exception as exc:  # noqa: BLE001 - answer, never hang the client
                out = {"id": req.get("id"), "error": repr(exc)}
            self.wfile.write(json.dumps(out).encode() + b"\n")

    def _stream_reports(self, rig: "Rig") -> None:
        period = 1.0 / rig.world.scenario.tcp_rate_hz
        nxt = time.monotonic()
        while not rig.stopping.is_set():
            with rig.lock:
                pose = _pose_mm_rad(rig.world.tcp_pose())
            try:
                self.wfile.write(json.dumps({"report": {"cartesian": pose}}).encode()
                                 + b"\n")
            except OSError:
                return
            nxt += period
            time.sleep(max(0.0, nxt - time.monotonic()))


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True


class Rig:
    """The world, its paced stepping and the three interfaces."""

    def __init__(self, a: argparse.Namespace) -> None:
        from aslip_ros.hw.sources import build_world
        self.a = a
        self.world = build_world(dict(
            scenario=a.scenario, seed=a.seed, object=a.object, layout=a.layout, pad=a.pad,
            condition=a.condition, sample_rate=a.sample_rate,
            wall_distance_m=a.wall_distance_m, drag_speed_m_s=a.drag_speed_m_s))
        if self.world.scenario.kind == "robot_induced":
            # A cell's robot-induced recording: the probe stands in the world and the arm
            # moves as its driver (robot_sweeps) commands, not by the scene's own sweeps.
            from dataclasses import replace

            from aslip_ros.scene import World
            self.world = World(replace(self.world.scenario, commanded_arm=True))
        names = self.world.layout.channel_names
        if len(names) != a.channels:
            raise SystemExit(f"hw_rig: layout {a.layout} has {len(names)} channels "
                             f"({names}), --channels {a.channels}")
        self.world.arm.connect()
        self.world.arm.enable_velocity_mode()
        self.lock = threading.Lock()
        self.stopping = threading.Event()
        self.log_positions = not a.no_log_positions
        self.events = JsonLines(a.status)
        self.calls = JsonLines(a.calls_log)
        lo = np.array(a.workspace_min, float) if a.workspace_min else None
        hi = np.array(a.workspace_max, float) if a.workspace_max else None
        if (lo is None) != (hi is None):
            raise SystemExit("hw_rig: give both --workspace-min and --workspace-max")
        self.controller = Controller(self, self.calls, a.max_speed, lo, hi)
        self.block = a.block_frames or max(1, int(round(0.01 * self.world.fs)))
        self.sink = FifoSink(a.fifo, self.events)
        self.server = _Server(("127.0.0.1", a.xarm_port), _Handler)
        self.server.rig = self
        self.port = self.server.server_address[1]
        self._ros()
        self.skipped_blocks = 0
        self.mocap_published = 0

    def _ros(self) -> None:
        import rclpy
        from geometry_msgs.msg import PoseStamped
        from rclpy.context import Context
        from rclpy.qos import qos_profile_sensor_data
        from rclpy.signals import SignalHandlerOptions
        self.ctx = Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(self.a.node_name, context=self.ctx,
                                      start_parameter_services=False, enable_rosout=False)
        self._Pose = PoseStamped
        self.pub_finger = self.node.create_publisher(PoseStamped, self.a.finger_topic,
                                                     qos_profile_sensor_data)
        self.pub_object = self.node.create_publisher(PoseStamped, self.a.object_topic,
                                                     qos_profile_sensor_data)

    def _pose_msg(self, pose: np.ndarray, stamp_s: float):
        msg = self._Pose()
        ns = int(round(stamp_s * 1e9))
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
        msg.header.frame_id = self.a.frame_id
        p, q = msg.pose.position, msg.pose.orientation
        p.x, p.y, p.z = (float(x) for x in pose[:3])
        q.x, q.y, q.z, q.w = (float(x) for x in pose[3:7])
        return msg

    def run(self) -> int:
        threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.1},
                         name="xarm-server", daemon=True).start()
        fs, block = self.world.fs, self.block
        block_s = block / fs
        parent = os.getppid()
        t0 = time.monotonic()
        # The loop's clock for its gaps starts with its block clock, before the ready line:
        # a stall between the two counts as a gap of the first iteration.
        last, last_cpu = t0, time.process_time()
        self.wall0 = wall0 = time.time() - (time.monotonic() - t0)
        self.events.write({"event": "start", "wall0": wall0, "fs": fs, "block_frames": block,
                           "channels": self.a.channels, "layout": self.a.layout,
                           "scenario": self.world.scenario.kind, "pid": os.getpid()})
        from aslip_ros.hw.sources import world_metadata
        print(json.dumps({"ready": True, "xarm_port": self.port, "fifo": self.a.fifo,
                          "pid": os.getpid(), "wall0": wall0, "block_frames": block,
                          "task": world_metadata(self.world)["task"],
                          "alsa_config": alsa_config(self.a.fifo)}), flush=True)
        limit = self.a.duration_s
        lead = self.a.audio_lead_blocks
        latency = float(self.world.scenario.mocap_latency_s)
        pending: deque = deque()           # (monotonic due, stamp, mocap sample)
        k = 0                              # blocks stepped
        max_catch_up = 20
        while not self.stopping.is_set():
            if os.getppid() != parent:
                self.events.write({"event": "parent_gone"})
                break
            now, cpu = time.monotonic(), time.process_time()
            # Since the loop last came here: wall time, and this process's CPU time in it
            # (about none: the host did not run it; about as much: a busy thread held it).
            gap_s, gap_cpu_s = now - last, cpu - last_cpu
            last, last_cpu = now, cpu
            while pending and pending[0][0] <= now:
                _, stamp, m = pending.popleft()
                self.pub_finger.publish(self._pose_msg(m.finger_pose, stamp))
                self.pub_object.publish(self._pose_msg(m.object_pose, stamp))
                self.mocap_published += 1
            done = limit > 0 and self.world.t >= limit
            if done and not pending:
                break
            due_at = t0 + (k + 1 - lead) * block_s
            if done or due_at > now:
                nxt = due_at if not done else pending[0][0]
                if pending:
                    nxt = min(nxt, pending[0][0])
                self.stopping.wait(max(0.0, nxt - now))
                continue
            behind = int((now - due_at) / block_s)
            if behind > max_catch_up:      # stalled host: skip time, do not burst
                skip = behind - max_catch_up
                t0 += skip * block_s
                self.wall0 += skip * block_s
                self.skipped_blocks += skip
                self.events.write({"event": "stall", "skipped_blocks": skip,
                                   "world_index": self.world.sample_index,
                                   "gap_s": round(gap_s, 3),
                                   "cpu_s_in_gap": round(gap_cpu_s, 3),
                                   "loadavg": os.getloadavg()})
            with self.lock:
                chunk = self.world.step(block)
            k += 1
            self.sink.write(np.ascontiguousarray(chunk.audio, dtype="<f4").tobytes(),
                            chunk.first_sample_index)
            for m in chunk.mocap:
                # A driver publishes a frame its latency after the capture instant it
                # stamps (the world's delivery, here on the wall clock).
                pending.append((t0 + m.t + latency, self.wall0 + m.t, m))
        return self.close()

    def close(self) -> int:
        self.stopping.set()
        self.server.shutdown()
        self.server.server_close()
        self.sink.close()
        s = self.sink
        self.events.write({
            "event": "exit", "scene_t": self.world.t, "blocks_written": s.blocks_written,
            "blocks_unconnected": s.blocks_unconnected, "blocks_overflowed": s.blocks_overflowed,
            "audio_connections": s.connections, "skipped_blocks": self.skipped_blocks,
            "mocap_frames": self.mocap_published, "violations": self.controller.violations,
            "commands_executed": self.controller.executed})
        self.events.close()
        self.calls.close()
        import rclpy
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        return 0


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fifo", required=True, help="FIFO path (ALSA file PCM infile)")
    p.add_argument("--layout", default="4mic")
    p.add_argument("--channels", type=int, required=True)
    p.add_argument("--scenario", default="external_induced",
                   choices=("external_induced", "robot_induced", "wall_push", "drag"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--object", default="chips_can")
    p.add_argument("--pad", default="textured")
    p.add_argument("--condition", default="robot_stationary")
    p.add_argument("--sample-rate", type=float, default=48000.0)
    p.add_argument("--wall-distance-m", type=float, default=0.0)
    p.add_argument("--drag-speed-m-s", type=float, default=0.04)
    p.add_argument("--block-frames", type=int, default=0,
                   help="frames per FIFO write; a multiple of the capture's block "
                        "(default: 10 ms)")
    p.add_argument("--audio-lead-blocks", type=int, default=1, choices=(0, 1),
                   help="write each audio block when its first frame is due (1), not its "
                        "last (0): audio_capture stamps arrival minus nothing (PortAudio "
                        "reports no latency for the null PCM), so 1 makes its stamps match "
                        "the acquisition time")
    p.add_argument("--finger-topic", required=True)
    p.add_argument("--object-topic", required=True)
    p.add_argument("--frame-id", default="mocap")
    p.add_argument("--node-name", default="fake_mocap_driver")
    p.add_argument("--xarm-port", type=int, required=True, help="0 = any free port")
    p.add_argument("--calls-log", required=True)
    p.add_argument("--status", default=None, help="JSON-lines events file")
    p.add_argument("--duration-s", type=float, default=0.0, help="0 = until stopped")
    p.add_argument("--workspace-min", type=float, nargs=3, default=None)
    p.add_argument("--workspace-max", type=float, nargs=3, default=None)
    p.add_argument("--max-speed", type=float, default=None, help="[m/s]")
    p.add_argument("--no-log-positions", action="store_true",
                   help="do not log get_position calls (they can be many)")
    return p.parse_args(argv)


def main(argv=None) -> int:
    a = parse_args(argv)
    # The hardware this stands in for (an audio interface, a mocap PC, an arm controller)
    # does not share the test machine's CPU: the rig runs above ordinary work, as the nodes
    # do (nice -10 where allowed). At normal priority, beside two CPU hogs and two
    # rehearsals, it once sent no TCP report for 1 s (robot_sweeps stopped on stale pose).
    from aslip_ros.util import raise_cpu_priority
    raise_cpu_priority()
    rig = Rig(a)
    exited = threading.Event()

    def on_signal(signum, frame):
        if not rig.stopping.is_set():
            threading.Thread(target=_exit_watch, args=(exited, a.status), name="exit-watch",
                             daemon=True).start()
        rig.stopping.set()
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    rc = rig.run()
    exited.set()
    # Nothing is left to write: leave without the interpreter's finalisation (rclpy's and
    # DDS's exit hooks, foreign threads), which a stand-in has no reason to wait on.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)


#: After a stop signal the rig is gone within this [s] (a test's teardown waits 20 s).
EXIT_GRACE_S = 10.0


def _exit_watch(exited: threading.Event, status: str | None) -> None:
    """Once stopped by a signal: if ``run`` has not returned within ``EXIT_GRACE_S``, append
    where every thread is to the status file (event ``exit_forced``; no ``exit`` event is
    written, so a test that reads it fails) and exit with status 3."""
    if exited.wait(EXIT_GRACE_S):
        return
    frames = sys._current_frames()
    stacks = {t.name: "".join(traceback.format_stack(frames[t.ident]))
              for t in threading.enumerate() if t.ident in frames}
    try:
        if status:
            with open(status, "a") as f:     # not the rig's JsonLines: its lock may be held
                f.write(json.dumps({"event": "exit_forced", "grace_s": EXIT_GRACE_S,
                                    "stacks": stacks}) + "\n")
    finally:
        os._exit(3)


if __name__ == "__main__":
    sys.exit(main())
