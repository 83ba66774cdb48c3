"""What the launch tests share: the launch description, an isolated domain, a topic probe.

Each test file in this folder is a launch_testing test (run it with ``launch_test FILE`` or
through pytest, where the launch_testing plugin collects it). Without launch_testing this
module still imports, and ``MISSING`` says why the launch tests cannot run; conftest.py
then skips them with that reason.

The launched graph runs on a ROS domain reserved for it (``domain_coordinator``) with
localhost discovery, so launch tests run beside the rest of the suite and other ROS users.
The probe reads the graph's topics on that domain through its own rclpy context.
"""

from __future__ import annotations

import json
import math
import threading
import time

try:
    import launch
    import launch_ros  # noqa: F401 - the launch files need it
    import launch_testing.actions
    import launch_testing.util
    from launch.launch_description_sources import PythonLaunchDescriptionSource
except ImportError as exc:
    MISSING = (f"{exc.name} is not importable: source a ROS 2 Jazzy install or "
               "build/ros2-launch/env.sh")
else:
    MISSING = None

#: ``input_timeout_s`` of the closed-loop launch tests [s]: what they test is the loop, and
#: a busy machine's stall must not latch the controllers' stale-input stop before it shows.
LOADED_INPUT_TIMEOUT_S = "1.0"

#: The domain reservations live as long as the test process.
_RESERVED = []


def scratch_dir(prefix: str) -> str:
    """A new temporary directory, removed when this process exits. Every process that imports
    a launch test makes one (pytest's collection too), not only the one whose last test
    could remove it."""
    import atexit
    import shutil
    import tempfile
    path = tempfile.mkdtemp(prefix=prefix)
    atexit.register(shutil.rmtree, path, True)
    return path


def reserve_domain() -> int:
    """A ROS_DOMAIN_ID no other user of domain_coordinator gets while this process runs."""
    from domain_coordinator import domain_id
    cm = domain_id()
    did = cm.__enter__()
    _RESERVED.append(cm)
    return int(did)


def description(launch_file: str, args: dict, keep_alive: bool = False):
    """``generate_test_description`` result: ``launch_file`` of the installed package,
    with ``args``, on a domain of its own; the tests get that ``domain``.

    ``keep_alive``: for a launch whose processes all end by themselves. Without a process
    that outlives them, a quick run (an export of a few seconds) can end the launch before
    the active tests have started waiting, which launch_testing reports as a failure
    ("Processes under test stopped before tests completed")."""
    import os

    from ament_index_python.packages import get_package_share_directory
    from launch.actions import GroupAction, IncludeLaunchDescription, SetEnvironmentVariable
    path = os.path.join(get_package_share_directory("aslip_ros"), "launch", launch_file)
    did = reserve_domain()
    # Scoped: the variables reach the launched processes, not the test process's environ.
    group = GroupAction(scoped=True, forwarding=True, actions=[
        SetEnvironmentVariable("ROS_DOMAIN_ID", str(did)),
        SetEnvironmentVariable("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST"),
        SetEnvironmentVariable("PYTHONUNBUFFERED", "1"),
        IncludeLaunchDescription(PythonLaunchDescriptionSource(path),
                                 launch_arguments=[(k, str(v)) for k, v in args.items()]),
    ])
    extra = [launch_testing.util.KeepAliveProc()] if keep_alive else []
    return (launch.LaunchDescription([group, *extra, launch_testing.actions.ReadyToTest()]),
            {"domain": did})


class Probe:
    """Subscribes to graph topics on ``domain`` and keeps what arrives, with receipt times.

    ``topics`` maps a name to ``(topic, type, qos)``; ``received[name]`` is a list of
    ``(monotonic time, message)``. Spins on a daemon thread until ``close()``.
    """

    def __init__(self, domain: int, topics: dict) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self._ctx = Context()
        rclpy.init(context=self._ctx, domain_id=domain)
        self.node = rclpy.create_node("aslip_launch_probe", context=self._ctx)
        self.received = {name: [] for name in topics}
        #: System-clock receipt times [ns], parallel to ``received`` (ROS stamps' clock).
        self.received_wall = {name: [] for name in topics}
        self._lock = threading.Lock()
        from rclpy.qos import QoSProfile
        for name, (topic, msg_type, qos) in topics.items():
            # 1000 deep: the probe's own queue must never be what drops a message.
            deep = QoSProfile(history=qos.history, depth=max(1000, qos.depth),
                              reliability=qos.reliability, durability=qos.durability)
            self.node.create_subscription(msg_type, topic, self._keeper(name), deep)
        self._ex = SingleThreadedExecutor(context=self._ctx)
        self._ex.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _keeper(self, name: str):
        def keep(msg) -> None:
            with self._lock:
                self.received[name].append((time.monotonic(), msg))
                self.received_wall[name].append(time.time_ns())
        return keep

    def _spin(self) -> None:
        import rclpy
        while rclpy.ok(context=self._ctx):
            try:
                self._ex.spin_once(timeout_sec=0.1)
            except Exception:  # noqa: BLE001 - the context went down under us
                return

    def messages(self, name: str) -> list:
        """A copy of what arrived on ``name`` so far."""
        with self._lock:
            return list(self.received[name])

    def wait_for(self, predicate, timeout: float, what: str):
        """Poll ``predicate()`` until it returns something truthy; fail after ``timeout``."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            value = predicate()
            if value:
                return value
            time.sleep(0.1)
        raise AssertionError(f"no {what} within {timeout:g} s")

    def close(self) -> None:
        """Stop spinning and release the context."""
        import rclpy
        rclpy.try_shutdown(context=self._ctx)
        self._thread.join(timeout=5.0)


def closed_loop_topics() -> dict:
    """Arm commands, slip estimates, controller diagnostics and the slip-stop result."""
    from geometry_msgs.msg import TwistStamped
    from std_msgs.msg import String

    from aslip_ros.msg import SlipVector
    from aslip_ros.nodes import common as c
    from aslip_ros.runtime.qos import LATCHED_QOS, RELIABLE_QOS
    from aslip_ros.nodes.slip_stop import RESULT_TOPIC
    return {"cmd": (c.CMD_VEL_TOPIC, TwistStamped, RELIABLE_QOS),
            "slip": (c.SLIP_TOPIC, SlipVector, RELIABLE_QOS),
            "diag": (c.DIAG_JSON_TOPIC, String, RELIABLE_QOS),
            "result": (RESULT_TOPIC, String, LATCHED_QOS)}


def speed(twist_msg) -> float:
    """Commanded TCP speed [m/s] of a TwistStamped."""
    v = twist_msg.twist.linear
    return math.sqrt(v.x * v.x + v.y * v.y + v.z * v.z)


def moving_commands(probe: Probe) -> list:
    """Arm commands with a non-zero velocity, as ``(time, msg)``."""
    return [(t, m) for t, m in probe.messages("cmd") if speed(m) > 0.0]


def assert_arm_commanded(probe: Probe, at_least: int = 20) -> list:
    """The controller drove the arm: ``at_least`` moving commands in ``link_base``.

    Returns them. This is what fails when the controller never commands the arm.
    """
    moving = moving_commands(probe)
    if len(moving) < at_least:
        raise AssertionError(f"the controller sent {len(moving)} moving arm commands "
                             f"(of {len(probe.messages('cmd'))} on the topic); expected "
                             f">= {at_least}")
    frames = {m.header.frame_id for _, m in moving}
    if frames != {"link_base"}:
        raise AssertionError(f"arm commands in frames {frames}, expected link_base")
    return moving


def controller_status(probe: Probe, node: str, since: float = float("-inf")) -> list:
    """The controller's diagnostics values, oldest first (from /aslip/diagnostics), of the
    reports received after ``since`` (the probe's monotonic receipt time)."""
    out = []
    for t, m in probe.messages("diag"):
        if t <= since:
            continue
        doc = json.loads(m.data)
        if doc.get("name") == f"aslip: {node}":
            out.append(dict(doc.get("values", {}), level=doc.get("level"),
                            message=doc.get("message")))
    return out


def change_state(probe: Probe, node: str, *transitions: str, timeout: float = 30.0) -> None:
    """Take lifecycle ``node`` through ``transitions`` (e.g. ``"deactivate", "activate"``),
    each awaited on its ``change_state`` service; fail where one is refused."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    client = probe.node.create_client(ChangeState, f"/{node}/change_state")
    try:
        probe.wait_for(lambda: client.service_is_ready(), timeout, f"/{node}/change_state")
        for label in transitions:
            req = ChangeState.Request()
            req.transition.id = getattr(Transition, f"TRANSITION_{label.upper()}")
            future = client.call_async(req)
            probe.wait_for(future.done, timeout, f"{node}'s answer to {label}")
            if not future.result().success:
                raise AssertionError(f"{node} refused the lifecycle transition {label}")
    finally:
        probe.node.destroy_client(client)


def final_slip_stop_result(probe: Probe):
    """The final slip-stop result document, or None yet."""
    for _, m in reversed(probe.messages("result")):
        doc = json.loads(m.data)
        if doc.get("final"):
            return doc
    return None


def assert_no_motion_after_stop(probe: Probe) -> None:
    """No moving arm command was published after the controller stopped.

    Judged on the publisher's own stamps (the controller's clock when it sent each
    command), against the system-clock moment the first slip-stop result (published right
    after the stop) was received here. Receipt order cannot judge it: under load the
    probe's executor took a backlog of earlier commands after the result (CI saw "210
    moving arm commands after the stop", all sent before it)."""
    with probe._lock:
        results = list(probe.received_wall["result"])
    if not results:
        raise AssertionError("no slip-stop result received")
    t_stop_ns = results[0]
    late = [speed(m) for _, m in moving_commands(probe)
            if m.header.stamp.sec * 10**9 + m.header.stamp.nanosec > t_stop_ns]
    if late:
        raise AssertionError(f"{len(late)} moving arm commands sent after the stop "
                             f"(up to {max(late):.4f} m/s)")


#: The task's reasons to end (aslip_ros.control.slip_stop.StopReason values).
def slip_stop_reasons() -> set:
    from aslip_ros.control.slip_stop import StopReason
    return {r.value for r in StopReason}


def slip_stop_success_reasons() -> set:
    from aslip_ros.control.slip_stop import SUCCESS_REASONS
    return {r.value for r in SUCCESS_REASONS}


def rviz_missing() -> bool:
    """True where rviz2 is not installed (the launch files then run without it)."""
    from aslip_ros.launch_support.common import rviz_found
    return not rviz_found()


def post_shutdown_test():
    """``launch_testing.post_shutdown_test()``, or a no-op where launch_testing is missing."""
    if MISSING is not None:
        return lambda cls: cls
    return launch_testing.post_shutdown_test()


#: Exit codes of a clean end: 0, or death by the launch's SIGINT.
CLEAN_EXIT_CODES = (0, -2)


def assert_clean_exit(proc_info, proc_output=None, tail_lines: int = 40) -> None:
    """Every process exited 0 (or died of the launch's SIGINT), none was killed.

    The failure names every process that did not, with its code and, given
    ``proc_output``, the last ``tail_lines`` lines it wrote: a failure seen once under
    load must say which node and why."""
    bad = [(str(info.process_name), info.returncode) for info in proc_info
           if info.returncode not in CLEAN_EXIT_CODES]
    if not bad:
        return
    parts = []
    for name, code in bad:
        parts.append(f"{name} exited with code {code}")
        if proc_output is not None:
            try:
                text = b"".join(io.text for io in proc_output[name]).decode(errors="replace")
            except KeyError:
                text = ""
            tail = text.splitlines()[-tail_lines:]
            parts.append("  last output:\n    " + "\n    ".join(tail or ["(none)"]))
    raise AssertionError("not every process exited cleanly: " + "; ".join(
        f"{n} ({c})" for n, c in bad) + "\n" + "\n".join(parts))


def final_result_time(probe: Probe):
    """Receipt time of the first final slip-stop result, or None."""
    for t, m in probe.messages("result"):
        if json.loads(m.data).get("final"):
            return t
    return None


def assert_rviz_started_where_installed(proc_info) -> None:
    """With ``rviz:=true``: an rviz2 process where rviz2 is installed, none elsewhere."""
    names = [str(n) for n in proc_info.process_names()]
    started = any(n.startswith("rviz2") for n in names)
    if started == rviz_missing():
        raise AssertionError(f"rviz2 {'missing' if rviz_missing() else 'installed'} but "
                             f"the launched processes were {names}")


def scene_status(probe: Probe, after: float = 0.0, first: bool = False):
    """Values of a scene_sim diagnostics report received after ``after`` (monotonic): the
    newest, or with ``first`` the oldest; None when there is none yet."""
    msgs = [m for t, m in probe.messages("diag") if t > after]
    for m in (msgs if first else reversed(msgs)):
        doc = json.loads(m.data)
        if doc.get("name") == "aslip: scene_sim" and "tcp_x" in doc.get("values", {}):
            return doc["values"]
    return None


def tcp(status: dict) -> list:
    """TCP position [m] of a scene_sim diagnostics report."""
    return [float(status["tcp_x"]), float(status["tcp_y"]), float(status["tcp_z"])]


def rviz_config():
    """``(fixed frame, [display topics])`` of the installed config/aslip.rviz."""
    import os

    import yaml
    from ament_index_python.packages import get_package_share_directory
    path = os.path.join(get_package_share_directory("aslip_ros"), "config", "aslip.rviz")
    with open(path) as f:
        doc = yaml.safe_load(f)
    manager = doc["Visualization Manager"]
    topics = [d["Topic"]["Value"] for d in manager["Displays"]
              if isinstance(d.get("Topic"), dict) and d["Topic"].get("Value")]
    return manager["Global Options"]["Fixed Frame"], topics


def rviz_topics(displays) -> dict:
    """Probe subscriptions for rviz's display topics (named by topic) and TF."""
    from geometry_msgs.msg import PoseStamped
    from tf2_msgs.msg import TFMessage
    from visualization_msgs.msg import MarkerArray

    from aslip_ros.runtime.qos import MARKER_QOS, SENSOR_QOS
    from aslip_ros.runtime.qos import TF_QOS, TF_STATIC_LISTENER_QOS
    out = {}
    for topic in displays:
        msg_type = MarkerArray if "marker" in topic else PoseStamped
        qos = MARKER_QOS if msg_type is MarkerArray else SENSOR_QOS
        out[topic] = (topic, msg_type, qos)
    out["/tf"] = ("/tf", TFMessage, TF_QOS)
    out["/tf_static"] = ("/tf_static", TFMessage, TF_STATIC_LISTENER_QOS)
    return out


def header_frames(messages) -> set:
    """The frame ids of stamped messages or of the markers of MarkerArrays."""
    frames = set()
    for _, m in messages:
        if hasattr(m, "markers"):
            frames.update(k.header.frame_id for k in m.markers)
        else:
            frames.add(m.header.frame_id)
    return frames


def tf_edges(probe: Probe) -> set:
    """``(parent, child)`` of every transform received on /tf and /tf_static."""
    return {(t.header.frame_id, t.child_frame_id)
            for name in ("/tf", "/tf_static") for _, m in probe.messages(name)
            for t in m.transforms}


def tf_connected(edges: set, a: str, b: str) -> bool:
    """Whether TF ``edges`` join frames ``a`` and ``b`` (in either direction)."""
    if a == b:
        return True
    seen, todo = {a}, [a]
    while todo:
        f = todo.pop()
        for p, ch in edges:
            for nxt in ((ch,) if p == f else ()) + ((p,) if ch == f else ()):
                if nxt == b:
                    return True
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
    return False


def skip_unlaunched(config, items) -> None:
    """Skip launch tests that pytest collected as plain modules (called by test/conftest.py).

    Without the launch_testing plugin (launch_testing missing, or `-p no:launch_testing`)
    pytest would run these files' test classes with nothing launched. They are skipped with
    a one-line reason instead; ASLIP_REQUIRE_LAUNCH=1 (CI with the launch stack) makes that
    an error, so no launch test is skipped there.
    """
    import os
    from pathlib import Path

    import pytest
    here = Path(__file__).resolve().parent
    mine = [i for i in items if here in Path(str(i.path)).resolve().parents
            and type(i).__name__ not in ("LaunchTestItem", "LaunchROSTestItem")]
    if not mine:
        return
    if MISSING is not None:
        reason = MISSING
    elif not config.pluginmanager.has_plugin("launch_testing"):
        reason = "the launch_testing pytest plugin is not loaded"
    else:
        reason = "not a launch test (generate_test_description lacks @pytest.mark.launch_test)"
    if os.environ.get("ASLIP_REQUIRE_LAUNCH") == "1":
        raise pytest.UsageError(f"launch tests required but not runnable: {reason}")
    for item in mine:
        item.add_marker(pytest.mark.skip(reason=reason))
