"""The hardware rehearsal's stand-ins, tested themselves: test/helpers/hw_rig.py (scene
behind a FIFO-fed ALSA PCM, a fake mocap driver and a fake xArm controller) and the fake
xarm-python-sdk in test/helpers/fake_xarm_sdk.

What they stand in for and what they do not model: the docstrings of those files.
Verdicts wait on events (the rig's ready line, files, messages); timeouts only bound failure.
"""

from __future__ import annotations

import ctypes.util
import importlib.util
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import json_lines

ROOT = Path(__file__).resolve().parents[1]
HELPERS = ROOT / "test" / "helpers"
RIG = HELPERS / "hw_rig.py"
FAKE_SDK = HELPERS / "fake_xarm_sdk"
FS = 48000
BLOCK = 480
FINGER, OBJECT = "/vicon/aslip_finger/pose", "/vicon/aslip_object/pose"


def _load_rig_module():
    spec = importlib.util.spec_from_file_location("hw_rig_under_test", RIG)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _load_fake_wrapper():
    """The fake SDK's wrapper module under its own name (the real SDK may be installed)."""
    spec = importlib.util.spec_from_file_location("fake_xarm_wrapper",
                                                  FAKE_SDK / "xarm" / "wrapper.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _wait(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    value = predicate()
    assert value, f"timed out after {timeout} s waiting for {what}"
    return value


class RigProcess:
    """hw_rig.py as a child process; ``info`` is its ready line."""

    def __init__(self, tmp: Path, env: dict, layout="4mic", channels=4,
                 scenario="external_induced", extra=()) -> None:
        self.fifo = tmp / "mics.fifo"
        self.calls = tmp / "calls.jsonl"
        self.status = tmp / "status.jsonl"
        self.args = dict(layout=layout, channels=channels, scenario=scenario)
        cmd = [sys.executable, "-P", str(RIG), "--fifo", str(self.fifo), "--layout", layout,
               "--channels", str(channels), "--scenario", scenario, "--seed", "3",
               "--object", "chips_can", "--finger-topic", FINGER, "--object-topic", OBJECT,
               "--xarm-port", "0", "--calls-log", str(self.calls), "--status",
               str(self.status), *extra]
        self.proc = subprocess.Popen(cmd, env=env, cwd=str(ROOT), stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self.info = self._ready(60.0)

    def _ready(self, timeout: float) -> dict:
        out: list = []
        reader = threading.Thread(target=lambda: out.append(self.proc.stdout.readline()),
                                  daemon=True)
        reader.start()
        reader.join(timeout)
        if not out or not out[0]:
            self.proc.kill()
            raise AssertionError(f"rig not ready: {self.proc.stderr.read()[-3000:]}")
        return json.loads(out[0])

    def events(self, name=None) -> list:
        return json_lines(self.status, name)

    def calls_log(self) -> list:
        return json_lines(self.calls)

    def stop(self, timeout: float = 20.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()


pytestmark = pytest.mark.ros


def _child_env(extra=None) -> dict:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.update(extra or {})
    return env


@pytest.fixture
def rig_env(ros_env):
    """The node processes' environment (isolated ROS domain): the rig is a ROS process."""
    return dict(ros_env)


@pytest.fixture
def start_rig(tmp_path, rig_env):
    rigs: list = []

    def start(**kwargs) -> RigProcess:
        d = tmp_path / f"rig{len(rigs)}"
        d.mkdir()
        rig = RigProcess(d, rig_env, **kwargs)
        rigs.append(rig)
        return rig
    yield start
    for rig in rigs:
        rig.stop()


# -- audio: FIFO-paced ALSA capture through PortAudio -----------------------------------------

CAPTURE = textwrap.dedent("""\
    import json, sys, time
    import numpy as np
    from aslip_ros.hw.audio import SoundDeviceCapture
    device, channels, n, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    cap = SoundDeviceCapture(device, channels=channels, sample_rate=48000, block_frames=480,
                             queue_blocks=256)
    cap.start()
    blocks, arrival = [], []
    for _ in range(n):
        b = cap.read(5.0)
        if b is None:
            break
        blocks.append(b)
        arrival.append(time.monotonic())
    cap.stop()          # before the rig goes: its EOF would make the null PCM run unpaced
    st = cap.stats()
    np.save(out, np.concatenate([b.data for b in blocks]) if blocks else np.zeros((0, channels)))
    print(json.dumps(dict(
        index=[b.first_sample_index for b in blocks],
        lost=[b.frames_lost_before for b in blocks],
        overflow=[b.overflow for b in blocks],
        host_time=[b.host_time for b in blocks], arrival=arrival,
        stats=st.__dict__)))
    """)


def _world_audio(layout: str, n_frames: int) -> np.ndarray:
    """The rig's world audio from sample 0 (the same deterministic world, no arm commands)."""
    from aslip_ros.hw.sources import build_world
    w = build_world(dict(scenario="external_induced", seed=3, object="chips_can",
                         layout=layout, pad="textured", condition="robot_stationary",
                         sample_rate=float(FS), wall_distance_m=0.0, drag_speed_m_s=0.04))
    out = [w.step(BLOCK).audio for _ in range(-(-n_frames // BLOCK))]
    return np.concatenate(out)


@pytest.mark.skipif(ctypes.util.find_library("portaudio") is None,
                    reason="libportaudio2 not installed (make setup)")
@pytest.mark.parametrize("layout,channels", [("2mic_corners", 2), ("4mic", 4)])
def test_fifo_paced_alsa_capture_delivers_the_rigs_samples_in_real_time(
        start_rig, tmp_path, layout, channels):
    rig = start_rig(layout=layout, channels=channels)
    conf = tmp_path / "asound.conf"
    conf.write_text(rig.info["alsa_config"])
    script = tmp_path / "capture.py"
    script.write_text(CAPTURE)
    n = 500                                   # 5 s
    proc = subprocess.run([sys.executable, str(script), "aslip_rig", str(channels), str(n),
                           str(tmp_path / "audio.npy")],
                          env=_child_env({"ALSA_CONFIG_PATH": str(conf)}), cwd=str(ROOT),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    got = np.load(tmp_path / "audio.npy")
    st = out["stats"]
    # Every block, contiguous, none dropped or flagged.
    assert len(out["index"]) == n
    assert out["index"] == [i * BLOCK for i in range(n)]
    assert sum(out["lost"]) == 0 and not any(out["overflow"])
    assert st["blocks_dropped"] == 0 and st["input_overflows"] == 0
    assert st["callback_errors"] == 0
    # Exactly the rig's samples: find where in the world the capture began (the last
    # connection's world index, give or take the blocks PortAudio's enumeration probe saw).
    connects = [e["world_index"] for e in rig.events("audio_connected")]
    assert connects
    ref = _world_audio(layout, max(connects) + (n + 20) * BLOCK)
    assert ref.shape[1] == channels
    starts = [k for k in range(max(0, min(connects) - 10 * BLOCK),
                               max(connects) + 10 * BLOCK + 1, BLOCK)
              if np.array_equal(ref[k:k + BLOCK], got[:BLOCK])]
    assert len(starts) == 1, f"first block found at {starts} (connections {connects})"
    k0 = starts[0]
    assert np.array_equal(got, ref[k0:k0 + n * BLOCK])
    # Paced by the rig: ~100 blocks/s (mean over 5 s; the first blocks may have been queued).
    arrival = np.array(out["arrival"][10:])
    rate = (len(arrival) - 1) / (arrival[-1] - arrival[0])
    assert 95.0 < rate < 105.0, rate
    # Audio stamps against the time the rig says the samples represent.
    true = rig.info["wall0"] + (k0 + np.arange(n) * BLOCK) / FS
    lag = np.array(out["host_time"]) - true
    print(f"\n{layout}: {rate:.2f} blocks/s; host_time - true: median "
          f"{1e3 * np.median(lag):.2f} ms, p95 {1e3 * np.percentile(lag, 95):.2f} ms")
    # The rig writes a block when its first frame is due; the capture stamps its arrival:
    # within a block of it, not a block late (a stamp of the block's end, or of the next
    # block's start, would be 10 ms late). Beside busy loops the arrival itself is late by a
    # few ms of scheduling (seen: median 6.7 ms with -n 2 and two hogs), which only ever adds:
    # the earliest tenth of the stamps says where the stamp is taken, whatever the load.
    assert -0.002 < float(np.median(lag))
    assert float(np.percentile(lag, 10)) < 0.75 * BLOCK / FS


# -- the fake xArm: the real adapter over the fake SDK ------------------------------------------

ADAPTER = textwrap.dedent("""\
    import json, sys, time
    import numpy as np
    import xarm
    from aslip_ros.hw.xarm import XArmAdapter, XArmConfig
    assert 'fake_xarm_sdk' in xarm.__file__, xarm.__file__
    arm = XArmAdapter(XArmConfig(ip='192.168.1.223', max_acc_m_s2=1000.0, mode_settle_s=0.05))
    arm.connect()
    arm.enable_velocity_mode()
    p0 = arm.tcp_pose()
    t = time.monotonic()
    arm.send_velocity(np.array([0.05, 0.0, -0.02]), 0.2)
    time.sleep(0.5)                    # the command's 0.2 s and the arm's lag run out
    p1 = arm.tcp_pose()
    streaming = arm.set_pose_listener(None)
    arm.close()
    print(json.dumps(dict(p0=p0.tolist(), p1=p1.tolist(), streaming=streaming,
                          sent=arm.commands_sent)))
    """)


def test_real_xarm_adapter_drives_the_rig_through_the_fake_sdk(start_rig, tmp_path):
    rig = start_rig(scenario="wall_push", extra=(
        "--max-speed", "0.1", "--workspace-min", "0.15", "-0.45", "0.02",
        "--workspace-max", "0.70", "0.45", "0.60"))
    script = tmp_path / "adapter.py"
    script.write_text(ADAPTER)
    env = _child_env({"ASLIP_FAKE_XARM_PORT": str(rig.info["xarm_port"])})
    env["PYTHONPATH"] = os.pathsep.join([str(FAKE_SDK), env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-P", str(script)], env=env, cwd=str(ROOT),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["streaming"] is True and out["sent"] == 1
    calls = rig.calls_log()
    names = [c["call"] for c in calls if "call" in c]
    assert names[:6] == ["connect", "get_err_warn_code", "register_report_location_callback",
                         "motion_enable", "set_mode", "set_state"]
    assert [c["args"] for c in calls if c.get("call") == "set_mode"] == [[5]]
    vel = [c for c in calls if c.get("call") == "vc_set_cartesian_velocity"]
    assert vel[0]["args"][0] == pytest.approx([50.0, 0.0, -20.0, 0.0, 0.0, 0.0])
    assert vel[0]["kwargs"]["duration"] == pytest.approx(0.2)
    assert vel[0]["ret"] == 0 and vel[0]["executed"] is True
    assert names[-3:] == ["set_state", "release_report_location_callback", "disconnect"]
    assert not [c for c in calls if "violation" in c]
    # The first-order lag conserves displacement: the TCP moved by v * duration.
    moved = np.array(out["p1"][:3]) - np.array(out["p0"][:3])
    assert moved == pytest.approx([0.01, 0.0, -0.004], abs=5e-4)


def test_raw_commands_over_the_limits_are_refused_and_logged(start_rig):
    rig = start_rig(scenario="wall_push", extra=(
        "--max-speed", "0.1", "--workspace-min", "0.15", "-0.45", "0.02",
        "--workspace-max", "0.70", "0.45", "0.60"))
    wrapper = _load_fake_wrapper()
    os.environ["ASLIP_FAKE_XARM_PORT"] = str(rig.info["xarm_port"])
    try:
        api = wrapper.XArmAPI("192.168.1.223", is_radian=True, do_not_open=True,
                              report_type="real")
        api.connect()
    finally:
        del os.environ["ASLIP_FAKE_XARM_PORT"]
    assert api.connected and tuple(api.version_number) >= (1, 8, 0)
    assert api.motion_enable(enable=True) == 0 and api.set_mode(5) == 0
    assert api.set_state(0) == 0 and api.mode == 5 and api.state == 0
    code, pos = api.get_position(is_radian=True)
    assert code == 0 and pos[:3] == pytest.approx([400.0, 0.0, 300.0], abs=1e-6)
    # 0.5 m/s against 0.1 m/s: refused.
    too_fast = api.vc_set_cartesian_velocity([500.0, 0, 0, 0, 0, 0], is_radian=True,
                                             is_tool_coord=False, duration=0.1)
    # 0.05 m/s for 10 s towards +z ends 0.5 m higher: outside the box.
    outside = api.vc_set_cartesian_velocity([0, 0, 50.0, 0, 0, 0], is_radian=True,
                                            is_tool_coord=False, duration=10.0)
    forever = api.vc_set_cartesian_velocity([10.0, 0, 0, 0, 0, 0], duration=-1)
    ok = api.vc_set_cartesian_velocity([10.0, 0, 0, 0, 0, 0], duration=0.05)
    api.disconnect()
    assert too_fast != 0 and outside != 0 and forever != 0 and ok == 0
    logged = rig.calls_log()
    kinds = [[p["kind"] for p in c["violation"]["problems"]] for c in logged
             if "violation" in c]
    assert kinds == [["speed"], ["workspace"], ["duration"]]
    vel = [c for c in logged if c.get("call") == "vc_set_cartesian_velocity"]
    assert [c["executed"] for c in vel] == [False, False, False, True]
    speed = next(c["violation"] for c in logged if "violation" in c)
    assert speed["problems"][0]["speed_m_s"] == pytest.approx(0.5)
    assert speed["problems"][0]["max_speed_m_s"] == pytest.approx(0.1)


def test_robot_induced_executes_the_commands_against_a_still_probe(start_rig):
    """A cell's robot-induced recording: the arm moves as commanded (the scene's own sweeps
    are off), the limits still hold."""
    rig = start_rig(scenario="robot_induced", extra=("--max-speed", "0.1"))
    wrapper = _load_fake_wrapper()
    os.environ["ASLIP_FAKE_XARM_PORT"] = str(rig.info["xarm_port"])
    try:
        api = wrapper.XArmAPI("10.0.0.2", is_radian=True, do_not_open=True)
        api.connect()
    finally:
        del os.environ["ASLIP_FAKE_XARM_PORT"]
    api.motion_enable(True), api.set_mode(5), api.set_state(0)
    assert api.vc_set_cartesian_velocity([20.0, 0, 0, 0, 0, 0], duration=0.1) == 0
    assert api.vc_set_cartesian_velocity([200.0, 0, 0, 0, 0, 0], duration=0.1) != 0
    api.disconnect()
    vel = [c for c in rig.calls_log() if c.get("call") == "vc_set_cartesian_velocity"]
    assert [(c["ret"] == 0, c["executed"]) for c in vel] == [(True, True), (False, False)]


def test_fake_sdk_unconnected_returns_codes_like_the_sdk(monkeypatch):
    monkeypatch.delenv("ASLIP_FAKE_XARM_PORT", raising=False)
    wrapper = _load_fake_wrapper()
    api = wrapper.XArmAPI("10.0.0.3", is_radian=True, do_not_open=True)
    api.connect()
    assert not api.connected
    assert api.set_mode(5) == -1 and api.get_position() == (-1, None)


# -- the fake mocap driver -----------------------------------------------------------------------

def test_poses_arrive_on_the_given_topics_at_the_mocap_rate(start_rig, rclpy_context):
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import qos_profile_sensor_data

    from node_support import Bus, header_ns
    bus = Bus(rclpy_context)
    try:
        bus.listen(PoseStamped, FINGER, qos_profile_sensor_data)
        bus.listen(PoseStamped, OBJECT, qos_profile_sensor_data)
        rig = start_rig()
        _wait(lambda: all(len(bus.messages(t)) >= 360 for t in (FINGER, OBJECT)), 60.0,
              "3 s of poses on both topics")
        for topic in (FINGER, OBJECT):
            got = bus.stamped(topic)[-300:]
            stamps = np.array([header_ns(m) for _, m in got]) / 1e9
            assert {m.header.frame_id for _, m in got} == {"mocap"}
            assert np.all(np.diff(stamps) > 0)
            rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
            assert rate == pytest.approx(120.0, rel=0.03)
            # Published after the instant they represent (the driver's latency), not much.
            arrival_wall = np.array([time.time() - (time.monotonic() - t) for t, _ in got])
            delay = arrival_wall - stamps
            print(f"\n{topic}: {rate:.1f} Hz; arrival - stamp median "
                  f"{1e3 * np.median(delay):.1f} ms")
            assert 0.008 < float(np.median(delay)) < 0.05     # 8.3 ms driver latency
        # The only topics it publishes are the ones it was given (no /aslip/*, no scene).
        names = _wait(lambda: bus.node.get_publisher_names_and_types_by_node(
            "fake_mocap_driver", "/"), 20.0, "the rig's node in the graph")
        published = {n for n, _ in names} - {"/parameter_events"}   # every rclpy node's
        assert published == {FINGER, OBJECT}
        assert rig.proc.poll() is None
    finally:
        bus.close()


# -- lifetime ----------------------------------------------------------------------------------

def test_rig_exits_on_sigterm_and_after_its_duration(start_rig):
    rig = start_rig()
    assert rig.stop() == 0
    assert rig.events("exit")
    short = start_rig(extra=("--duration-s", "0.5"))
    assert short.proc.wait(30) == 0
    assert short.events("exit")[0]["scene_t"] == pytest.approx(0.5, abs=0.011)


def test_a_rig_the_host_does_not_run_reports_a_stall(start_rig):
    """The rehearsal tells a stalled stand-in from a failing node by this event: a rig held
    still (SIGSTOP, as a host that does not schedule it) for 0.5 s, 50 blocks, says so once
    it runs again, and skips the time rather than bursting it."""
    rig = start_rig()
    rig.proc.send_signal(signal.SIGSTOP)
    try:
        time.sleep(0.5)          # the stall itself: any longer only adds skipped blocks
    finally:
        rig.proc.send_signal(signal.SIGCONT)
    # The event of the hold: its loop stood at least as long and it used no CPU meanwhile
    # (held, not busy). A loaded host may add stalls of its own: slow progress, short gaps.
    try:
        held = _wait(lambda: [e for e in rig.events("stall") if e["gap_s"] >= 0.5], 20.0,
                     "a stall event with the hold's gap")
    except AssertionError as exc:
        raise AssertionError(f"{exc}; the rig's stall events: {rig.events('stall')}") from None
    assert held[0]["skipped_blocks"] >= 50 - 20 - 1, held
    assert held[0]["cpu_s_in_gap"] < held[0]["gap_s"] / 2, held
    assert rig.stop() == 0


PARENT = textwrap.dedent("""\
    import subprocess, sys
    rig = subprocess.Popen(sys.argv[1:], stdout=subprocess.PIPE, text=True)
    rig.stdout.readline()            # ready
    print(rig.pid, flush=True)       # and go, leaving the rig behind
    """)


def test_rig_does_not_outlive_its_parent(tmp_path, rig_env):
    cmd = [sys.executable, "-P", str(RIG), "--fifo", str(tmp_path / "f.fifo"), "--channels",
           "4", "--finger-topic", FINGER, "--object-topic", OBJECT, "--xarm-port", "0",
           "--calls-log", str(tmp_path / "c.jsonl")]
    parent = subprocess.run([sys.executable, "-c", PARENT, *cmd], env=rig_env,
                            capture_output=True, text=True, timeout=60, cwd=str(ROOT))
    pid = int(parent.stdout.strip())

    def gone() -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.split(") ")[1].startswith("Z")
    _wait(gone, 20.0, f"rig {pid} to exit after its parent")


def test_alsa_config_names_the_fifo():
    mod = _load_rig_module()
    text = mod.alsa_config("/tmp/x.fifo", "mics")
    assert 'infile "/tmp/x.fifo"' in text and "pcm.mics" in text and "type null" in text


def test_a_rig_that_does_not_stop_after_its_signal_says_where_and_exits(tmp_path):
    """The rig's exit watch: a run that has not returned ``EXIT_GRACE_S`` after the stop
    signal appends every thread's stack to the status file (``exit_forced``) and exits 3,
    so a test's teardown never waits out a hung stand-in (CI once waited 20 s on one)."""
    status = tmp_path / "status.jsonl"
    code = textwrap.dedent(f"""
        import importlib.util, threading, time
        spec = importlib.util.spec_from_file_location("rig", {str(RIG)!r})
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        mod.EXIT_GRACE_S = 0.2
        threading.Thread(target=mod._exit_watch, args=(threading.Event(), {str(status)!r}),
                         daemon=True).start()
        time.sleep(120)                       # a run that never returns
    """)
    script = tmp_path / "hung_rig.py"
    script.write_text(code)
    done = subprocess.run([sys.executable, "-P", str(script)], env=_child_env(), cwd=str(ROOT),
                          capture_output=True, text=True, timeout=100)
    assert done.returncode == 3, done.stderr
    doc = json.loads(status.read_text().splitlines()[-1])
    assert doc["event"] == "exit_forced" and doc["grace_s"] == 0.2
    assert "time.sleep(120)" in doc["stacks"]["MainThread"]
