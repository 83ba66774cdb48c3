"""``robot_sweeps``: the node in this process with an arm that streams its own TCP (the
xArm's way), and as the installed executable with the test arm ``fake_arm:make_arm``
(test/helpers/fake_arm.py, polled like an arm without a stream)."""

from __future__ import annotations

import json
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import ROOT
from node_support import Bus, NodeProcess

pytestmark = pytest.mark.ros

START = np.array([0.4, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0])
#: Tests that are not about the watchdog tolerate a stalled test process (a loaded machine).
POSE_TIMEOUT_S = 0.5


# ------------------------------------------------------------------ an arm in this process

class StreamArm:
    """A point TCP moving at the commanded velocity until the command expires; it pushes its
    pose to the node's listener from a thread of its own, as the xArm SDK's report stream
    does, while ``streaming`` is set."""

    def __init__(self) -> None:
        self.pose = START.copy()
        self.v = np.zeros(3)
        self.until = 0.0
        self.t = time.monotonic()
        self.calls: list = []
        self.lock = threading.Lock()
        self.listener = None
        self.streaming = threading.Event()
        self.streaming.set()
        self.moving = threading.Event()      # set after 20 non-zero velocity commands
        self.stopped = threading.Event()
        self.closed = threading.Event()
        self.fail_after: int | None = None   # raise ArmError on this velocity command
        self.thread = threading.Thread(target=self._stream, daemon=True)

    def _advance(self) -> None:
        now = time.monotonic()
        self.pose[:3] += self.v * max(0.0, min(now, self.until) - self.t)
        self.t = now

    def connect(self) -> None:
        self.calls.append(("connect", None))
        self.thread.start()

    def enable_velocity_mode(self) -> None:
        self.calls.append(("enable", None))

    def send_velocity(self, v, duration_s) -> None:
        from aslip_ros.arm import ArmError
        with self.lock:
            self._advance()
            n = sum(1 for name, _ in self.calls if name == "velocity")
            if self.fail_after is not None and n >= self.fail_after:
                raise ArmError("test arm: refused")
            self.v = np.asarray(v, dtype=float).copy()
            self.until = self.t + float(duration_s)
            self.calls.append(("velocity", (self.v.copy(), float(duration_s))))
            if sum(1 for name, x in self.calls
                   if name == "velocity" and np.linalg.norm(x[0]) > 0) >= 20:
                self.moving.set()

    def stop(self) -> None:
        with self.lock:
            self._advance()
            self.v = np.zeros(3)
            self.calls.append(("stop", None))
        self.stopped.set()

    def tcp_pose(self) -> np.ndarray:
        with self.lock:
            self._advance()
            return self.pose.copy()

    def set_pose_listener(self, callback) -> bool:
        self.listener = callback
        return True

    def close(self) -> None:
        self.stop()
        self.calls.append(("close", None))
        self.closed.set()

    def _stream(self) -> None:
        while not self.closed.is_set():
            listener = self.listener
            if self.streaming.is_set() and listener is not None:
                listener(self.tcp_pose(), time.monotonic(), time.time_ns())
            self.closed.wait(0.01)       # the device's report period

    def names(self) -> list:
        return [name for name, _ in self.calls]


MADE: list = []


def make_arm(node, params):
    """The factory ``arm:=test_nodes_robot_sweeps:make_arm`` names."""
    MADE.append(StreamArm())
    return MADE[-1]


class InProcess:
    """The node on the test's context, spun on a thread of its own."""

    def __init__(self, context, **params) -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter

        from aslip_ros.nodes.robot_sweeps import RobotSweeps
        MADE.clear()
        values = dict(arm=f"{__name__}:make_arm", pose_timeout_s=POSE_TIMEOUT_S)
        values.update(params)
        self.node = RobotSweeps(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in values.items()])
        self.arm: StreamArm | None = MADE[-1] if MADE else None     # None: not configured
        self.ex = SingleThreadedExecutor(context=context)
        self.ex.add_node(self.node)
        self.halt = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self.halt.is_set():
            self.ex.spin_once(timeout_sec=0.02)

    def close(self) -> None:
        self.node.before_shutdown()
        self.halt.set()
        self.thread.join(5)
        self.ex.shutdown()
        self.node.destroy_node()


def _nothing_after_the_first_stop(names: list) -> None:
    first = names.index("stop")
    assert "velocity" not in names[first:], names[first - 3:first + 5]


def test_a_stale_pose_stream_stops_the_arm_for_good(rclpy_context):
    from aslip_ros.control.sweeps import SweepEnd
    # Not shorter than the suite's: a stall of the fake arm's report thread on a loaded
    # machine must not end the run before it has moved.
    run = InProcess(rclpy_context, pose_timeout_s=POSE_TIMEOUT_S, duration_s=0.0)
    try:
        assert run.arm.moving.wait(20), run.arm.names()
        assert run.node.active
        run.arm.streaming.clear()                       # the report stream falls silent
        assert run.arm.stopped.wait(5), "no stop after the pose stream went stale"
        assert run.node.task.end_reason is SweepEnd.STALE_POSE
        names = run.arm.names()
        _nothing_after_the_first_stop(names)
        assert run.node.worker.latched
        run.arm.streaming.set()                         # poses again: the run stays over
        n = len(run.arm.names())
        assert run.arm.closed.wait(0.5) is False        # half a second of fresh poses
        assert "velocity" not in run.arm.names()[n:]
    finally:
        run.close()
    names = run.arm.names()
    _nothing_after_the_first_stop(names)
    assert names[-1] == "close"


def test_an_arm_error_stops_the_arm(rclpy_context):
    from aslip_ros.control.sweeps import SweepEnd
    run = InProcess(rclpy_context, duration_s=0.0)
    try:
        run.arm.fail_after = 30
        assert run.arm.stopped.wait(30), run.arm.names()
        # The worker reports the error on its thread, then the task faults.
        deadline = time.monotonic() + 5
        while run.node.task.end_reason is None and time.monotonic() < deadline:
            run.halt.wait(0.02)
        assert run.node.task.end_reason is SweepEnd.ERROR
        assert "refused" in run.node.arm_error
    finally:
        run.close()
    _nothing_after_the_first_stop(run.arm.names())


def test_deactivate_stops_and_activate_sweeps_again(rclpy_context):
    from aslip_ros.control.sweeps import SweepState
    run = InProcess(rclpy_context, duration_s=0.0)
    try:
        assert run.arm.moving.wait(20), run.arm.names()
        run.node.trigger_deactivate()
        assert run.arm.stopped.is_set() and not run.node.active
        _nothing_after_the_first_stop(run.arm.names())
        assert run.node.task.state is SweepState.STOPPED
        n = len(run.arm.calls)
        run.node.trigger_activate()
        assert run.node.active and run.node.task.state is not SweepState.STOPPED
        later = lambda: [x for name, x in run.arm.calls[n:]  # noqa: E731
                         if name == "velocity" and np.linalg.norm(x[0]) > 0]
        deadline = time.monotonic() + 20
        while len(later()) < 5 and time.monotonic() < deadline:
            run.halt.wait(0.02)
        assert len(later()) >= 5, "no sweeps after re-activation"
    finally:
        run.close()


def test_a_finite_run_returns_to_the_start_and_is_done(rclpy_context):
    from aslip_ros.control.sweeps import SweepEnd
    run = InProcess(rclpy_context, duration_s=2.0, exit_when_done=True, seed=3)
    try:
        assert run.arm.stopped.wait(20), run.arm.names()
        deadline = time.monotonic() + 5
        while not run.node.done and time.monotonic() < deadline:
            run.halt.wait(0.02)
        assert run.node.done and run.node.exit_code == 0
        assert run.node.task.end_reason is SweepEnd.DONE
        assert any(np.linalg.norm(x[0]) > 0 for name, x in run.arm.calls if name == "velocity")
        tol = run.node.p["return_tolerance_m"]
        assert np.linalg.norm(run.arm.tcp_pose()[:3] - START[:3]) <= tol + 1e-4
    finally:
        run.close()
    _nothing_after_the_first_stop(run.arm.names())


def test_parameters_declare_their_ranges_and_are_checked(rclpy_context):
    from rclpy.parameter import Parameter

    from aslip_ros.runtime.process import ConfigError
    run = InProcess(rclpy_context, autostart=False)
    try:
        d = {x.name: x for x in run.node.describe_parameters(
            ["sweep_radius_m", "seed", "duration_s", "arm"])}
        assert [(r.from_value, r.to_value) for r in d["sweep_radius_m"].floating_point_range] \
            == [(0.001, 0.1)]
        assert [(r.from_value, r.to_value) for r in d["seed"].integer_range] == \
            [(0, 2 ** 31 - 1)]
        assert "not sim" in d["arm"].description
        res = run.node.set_parameters([Parameter("sweep_radius_m", value=0.5)])
        assert not res[0].successful
        res = run.node.set_parameters([Parameter("return_tolerance_m", value=0.005),
                                       Parameter("sweep_radius_m", value=0.004)])
        # Set one by one: the tolerance fits the old radius, the radius is then too small.
        assert res[0].successful
        assert not res[1].successful and "return_tolerance_m" in res[1].reason
        assert run.arm is None and not MADE   # autostart false: not even built
    finally:
        run.close()
    from aslip_ros.nodes.robot_sweeps import RobotSweeps
    with pytest.raises(ConfigError, match="robot_induced"):
        RobotSweeps(context=rclpy_context, parameter_overrides=[Parameter("arm", value="sim")])


def test_the_shipped_yaml_holds_the_nodes_defaults():
    from aslip_ros.nodes.introspect import declared_by_name
    declared = declared_by_name("robot_sweeps")
    doc = yaml.safe_load((ROOT / "config" / "robot_sweeps.yaml").read_text())
    values = doc["robot_sweeps"]["ros__parameters"]
    # Every parameter but the arm's limits, which the file leaves to ArmLimits (written once).
    limits = {"arm_max_speed_m_s", "arm_max_acc_m_s2", "arm_workspace_min_m",
              "arm_workspace_max_m"}
    assert set(values) == set(declared) - limits and limits <= set(declared)
    for name, value in values.items():
        default = declared[name].default
        assert value == default and type(value) is type(default), name
    for gone in ("slip_timeout_s", "slip_topic", "start_after_messages"):
        assert gone not in declared


# ------------------------------------------------------------------ the executable

def _calls(path: Path) -> list:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.endswith("}")]


def test_the_executable_sweeps_within_limits_and_stops_on_sigint(rclpy_context, ros_env, tmp_path):
    from geometry_msgs.msg import PoseStamped

    from aslip_ros import frames
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import SENSOR_QOS
    from aslip_ros.nodes import convert
    log = tmp_path / "arm.jsonl"
    env = dict(ros_env, FAKE_ARM_LOG=str(log))
    bus = Bus(rclpy_context)
    bus.listen(PoseStamped, c.TCP_TOPIC, SENSOR_QOS)
    params = {"arm": "fake_arm:make_arm", "arm_max_speed_m_s": 0.05, "seed": 4,
              "duration_s": 0.0, "pose_timeout_s": POSE_TIMEOUT_S, "sweep_radius_m": 0.01}
    with NodeProcess("robot_sweeps", env, params) as node:
        node.wait_ready()
        assert node.wait_for("sweeping from", 30), node.output

        def moving() -> int:
            return sum(1 for k in _calls(log)
                       if k["call"] == "velocity" and np.linalg.norm(k["v"]) > 1e-3)
        assert bus.wait(lambda: moving() >= 50, 30), node.output
        assert bus.wait(lambda: len(bus.messages(c.TCP_TOPIC)) > 50, 10), node.output
        node.proc.send_signal(signal.SIGINT)
        assert node.proc.wait(10) == 0, node.output
    bus.close()
    calls = _calls(log)
    names = [k["call"] for k in calls]
    assert names[:2] == ["connect", "enable"], names[:5]
    velocity = [k for k in calls if k["call"] == "velocity"]
    assert max(np.linalg.norm(k["v"]) for k in velocity) <= 0.05 + 1e-9
    assert all(0 < k["duration"] <= 0.5 for k in velocity)
    # Identity grasp plane and TCP orientation: sweeps in base x and z only.
    assert all(k["v"][1] == 0.0 for k in velocity)
    first = names.index("stop")
    assert "velocity" not in names[first:] and names[-1] == "close", names[first:]
    # The published TCP: stamped, in link_base, never far from where it started.
    msgs = bus.messages(c.TCP_TOPIC)
    poses = np.array([convert.pose_from_msg(m)[2] for m in msgs])
    stamps = [convert.pose_from_msg(m)[0] for m in msgs]
    assert all(b >= a for a, b in zip(stamps, stamps[1:])) and stamps[0] > 0
    assert {m.header.frame_id for m in msgs} == {frames.BASE}
    offsets = np.linalg.norm(poses[:, :3] - START[:3], axis=1)
    assert offsets.max() <= 0.01 + 2e-3 and offsets.max() > 1e-3


def test_the_executable_refuses_the_simulated_arm(ros_env):
    proc = NodeProcess("robot_sweeps", ros_env, {"arm": "sim"})
    assert proc.proc.wait(30) == 2
    out = proc.stop()
    assert "refused to start" in out and "robot_induced" in out, out
    assert "Traceback" not in out


def test_the_executable_exits_when_the_sweeps_are_done(ros_env, tmp_path):
    """exit_when_done: after duration_s the arm returns to the start, stops, and the process
    ends by itself with code 0 (what ends a robot-induced recording)."""
    log = tmp_path / "arm.jsonl"
    env = dict(ros_env, FAKE_ARM_LOG=str(log))
    params = {"arm": "fake_arm:make_arm", "duration_s": 1.5, "exit_when_done": True,
              "pose_timeout_s": POSE_TIMEOUT_S, "seed": 1}
    node = NodeProcess("robot_sweeps", env, params)
    try:
        assert node.proc.wait(60) == 0, node.output
    finally:
        out = node.stop()
    assert "stopping the arm: done" in out, out
    calls = _calls(log)
    names = [k["call"] for k in calls]
    assert any(k["call"] == "velocity" and np.linalg.norm(k["v"]) > 0 for k in calls)
    first = names.index("stop")
    assert "velocity" not in names[first:] and names[-1] == "close", names[first:]
