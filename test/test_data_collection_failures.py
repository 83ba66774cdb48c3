"""A failed recording fails (#34): ``ros2 launch aslip_ros data_collection.launch.py`` on a
hardware trial ends with exit status 1 within seconds, one ERROR line naming the stream,
and the recorder's bag closed whole; a complete trial still ends with 0 and its bag.

Each case runs ``ros2 launch`` for real (sim:=false, a cell file), on both recorder routes:
``recorder:=aslip`` (bag_recorder) and ``recorder:=auto`` picking ``ros2 bag record``, which
is no wheel: test/helpers/fake_ros2bag stands in for it (bag_recorder behind the same
command line). What the cell talks to: a WAV replay as the audio interface
(``audio_capture source:=wav``), test/helpers/driver_standin.py as the motion-capture driver
and, where audio must stop mid-trial, the audio interface (it can leave a stream out or
stop one once the graph reads it), sounddevice with a device that does not
exist, the real xarm SDK at a TEST-NET address. Every verdict waits on the launch's exit.
The seconds from the failure to the launch's exit are printed (``-s`` shows them).

The watch's own logic (thresholds, which stream failed first): test_data_stream_watch.py.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import HELPERS

pytestmark = [pytest.mark.ros, pytest.mark.slow]

try:
    import launch  # noqa: F401
    import launch_ros  # noqa: F401
except ImportError as exc:
    LAUNCH_MISSING = f"{exc.name} is not importable (source build/ros2-launch/env.sh)"
else:
    LAUNCH_MISSING = None

FINGER, OBJECT = "/standin/aslip_finger/pose", "/standin/aslip_object/pose"
AUDIO = "/aslip/audio"
#: The stand-in audio interface's stream (test/helpers/driver_standin.py --audio).
STANDIN_AUDIO = "/standin/audio"
STANDIN_CHANNELS = ("m0", "m1", "m2", "m3")
FAKE_ROS2BAG = HELPERS / "fake_ros2bag"
#: The longest a test waits for the launch to end: a trial that hangs fails here.
LAUNCH_TIMEOUT_S = 90.0
#: A failed trial's duration: long enough that only the failure can end it in time.
FAILED_TRIAL_S = "30"
#: A failed trial ends "at once" when the launch is over this much sooner than its duration
#: would end it: the verdict, the nodes' shutdowns (each may take its 4 s grace on a loaded
#: machine) and this test waking all fit, and a trial that ran to its end does not.
ENDED_AT_ONCE_S = float(FAILED_TRIAL_S) / 2
#: The cases of a stream that stops: a first message may come this late (a loaded machine
#: can take seconds to start a stream), so that only the stop can end the trial.
SLOW_START = {"start_timeout_s": 30.0}
#: A trial that must complete: neither a slow start nor a host too busy to run the capture
#: for a second (2026-11-29, CI: the audio stopped arriving for 1.0 s after 176 blocks while
#: every test process shared two cores, and the complete trial failed) may fail it here.
#: The thresholds themselves are tested with events below and in test_data_stream_watch.py.
BUSY_HOST = {**SLOW_START, "stall_timeout_s": 10.0}
#: rcutils' console line: [LEVEL] [stamp] [node]: message.
LOG_LINE = re.compile(r"\[(INFO|WARN|ERROR)\] \[(\d+\.\d+)\] \[([\w.]+)\]: (.*)")
ROUTES = ("aslip", "ros2bag")


def _wav(path: Path, seconds: float) -> None:
    from scipy.io import wavfile
    rate = 16000
    rng = np.random.default_rng(0)
    wavfile.write(path, rate, (0.01 * rng.standard_normal((int(rate * seconds), 4)))
                  .astype(np.float32))


def _cell(tmp_path: Path, audio: dict, arm: dict | None = None,
          watch: dict | None = None) -> Path:
    lines = ["audio_capture:"] + [f"  {k}: {v}" for k, v in audio.items()]
    lines += ["mocap_bridge:", f"  finger_topic: {FINGER}", f"  object_topic: {OBJECT}",
              "  grasp_plane_in_finger: [0, 0, 0, 0, 0, 0, 1]"]
    if arm:
        lines += ["arm:"] + [f"  {k}: {v}" for k, v in arm.items()]
    if watch:
        lines += ["stream_watch:"] + [f"  {k}: {v}" for k, v in watch.items()]
    path = tmp_path / "cell.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _wav_audio(tmp_path: Path, seconds: float = 6.0, loop: bool = True) -> dict:
    wav = tmp_path / "mics.wav"
    _wav(wav, seconds)
    return {"source": "wav", "wav_path": str(wav), "loop": "true" if loop else "false"}


class Trial:
    """``ros2 launch aslip_ros data_collection.launch.py sim:=false`` on ``route``, with the
    driver stand-in (``standin`` args; None = no driver at all)."""

    def __init__(self, ros_env: dict, tmp_path: Path, route: str, cell: Path,
                 standin: list | None, *args: str) -> None:
        ros2 = shutil.which("ros2", path=ros_env.get("PATH"))
        if LAUNCH_MISSING is not None or ros2 is None:
            pytest.skip(LAUNCH_MISSING or "`ros2` is not on PATH")
        env = dict(ros_env)
        if route == "ros2bag":
            env["PATH"] = f"{FAKE_ROS2BAG / 'bin'}{os.pathsep}{env['PATH']}"
            env["AMENT_PREFIX_PATH"] = f"{FAKE_ROS2BAG}{os.pathsep}{env['AMENT_PREFIX_PATH']}"
        self.bag = tmp_path / "bag"
        self.log = tmp_path / "launch.log"
        self.standin = None
        self.standin_out = tmp_path / "standin.log"
        if standin is not None:
            self.standin = subprocess.Popen(
                [sys.executable, str(HELPERS / "driver_standin.py"), *standin], env=ros_env,
                stdout=open(self.standin_out, "w"), stderr=subprocess.STDOUT)
        recorder = "aslip" if route == "aslip" else "auto"
        self.proc = subprocess.Popen(
            [ros2, "launch", "aslip_ros", "data_collection.launch.py", "sim:=false",
             f"cell:={cell}", f"bag:={self.bag}", f"recorder:={recorder}", *args],
            env=env, stdout=open(self.log, "w"), stderr=subprocess.STDOUT,
            start_new_session=True)
        self.code = None
        self.ended_at = None

    def wait(self) -> int:
        """The launch's exit status, once it has ended by itself."""
        try:
            self.code = self.proc.wait(timeout=LAUNCH_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"the launch did not end within {LAUNCH_TIMEOUT_S:g} s:\n"
                                 + self.text[-4000:]) from None
        self.ended_at = time.time()
        return self.code

    @property
    def text(self) -> str:
        return self.log.read_text()

    def lines(self, node: str, needle: str) -> list:
        """(stamp, message) of ``node``'s log lines that contain ``needle``."""
        found = (LOG_LINE.search(line) for line in self.text.splitlines())
        return [(float(m.group(2)), m.group(4)) for m in found
                if m and m.group(3) == node and needle in m.group(4)]

    def since(self, t: float, what: str) -> float:
        took = self.ended_at - t
        print(f"\n{what}: the launch ended {took:.2f} s later (exit {self.code})", flush=True)
        return took

    def close(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)
        if self.standin is not None and self.standin.poll() is None:
            self.standin.send_signal(signal.SIGINT)
            try:
                self.standin.wait(10)
            except subprocess.TimeoutExpired:
                self.standin.kill()

    def nodes_left(self) -> list:
        pids = [int(p) for p in re.findall(r"process started with pid \[(\d+)\]", self.text)]
        end = time.monotonic() + 15.0
        while time.monotonic() < end:
            left = [p for p in pids if _alive(p)]
            if not left:
                return []
            time.sleep(0.2)
        return [p for p in pids if _alive(p)]

    def assert_audio_contiguous(self) -> None:
        from aslip_ros.data.bags import BagReader
        with BagReader(self.bag) as reader:
            blocks = [(int(m.msg.first_sample_index), int(m.msg.data.size) // max(
                1, len(m.msg.channel_names))) for m in reader.messages([AUDIO])]
        jumps = [(a, n, b) for (a, n), (b, _) in zip(blocks, blocks[1:]) if b != a + n]
        assert blocks and not jumps, (len(blocks), jumps[:5])

    def bag_counts(self) -> dict:
        from aslip_ros.data.bags import BagReader
        assert self.bag.is_dir(), f"no bag at {self.bag}:\n{self.text[-3000:]}"
        with BagReader(self.bag) as reader:
            return dict(reader.info.counts)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except (ProcessLookupError, OSError):
        return False


@pytest.fixture
def trial(ros_env, tmp_path):
    made = []

    def start(route, cell, standin, *args):
        made.append(Trial(ros_env, tmp_path, route, cell, standin, *args))
        return made[-1]
    yield start
    for t in made:
        t.close()


def _failed(t: Trial) -> None:
    """Exit status 1 saying the trial failed, every node gone, and the bag readable: the
    recorder closed it whole on the way out (what it holds depends on how soon the trial
    failed; the cases below check the streams that had arrived)."""
    assert t.wait() == 1, t.text[-4000:]
    assert t.nodes_left() == [], t.text[-3000:]
    assert "the trial failed" in t.text, t.text[-3000:]
    assert "bag written to" in t.text, t.text[-3000:]
    t.bag_counts()


@pytest.mark.parametrize("route", ROUTES)
def test_a_pose_stream_that_never_arrives_fails_the_trial(trial, tmp_path, route):
    """The driver publishes the finger only: the object's topic is named, exit 1."""
    cell = _cell(tmp_path, _wav_audio(tmp_path))
    t = trial(route, cell, [FINGER], f"duration_s:={FAILED_TRIAL_S}")
    _failed(t)
    (stamp, line), = t.lines("stream_watch", "the trial failed")
    assert line.startswith(f"{OBJECT}: no message in the first"), line
    t.since(stamp, f"[{route}] {OBJECT} never arrived, the watch's verdict")
    assert t.bag_counts().get(AUDIO, 0) > 0


def test_a_pose_stream_that_stops_mid_trial_fails_the_trial(trial, tmp_path):
    """The finger stream stops once the graph has read it for 1 s (ros2 bag route)."""
    cell = _cell(tmp_path, _wav_audio(tmp_path), watch=SLOW_START)
    t = trial("ros2bag", cell, [FINGER, OBJECT, "--stop", FINGER, "--stop-after-s", "1",
                                "--subscribers", "3"], f"duration_s:={FAILED_TRIAL_S}")
    _failed(t)
    (_, line), = t.lines("stream_watch", "the trial failed")
    assert line.startswith(f"{FINGER}: no message for"), line
    stopped = float(re.search(r"stopped \S+ at (\d+\.\d+)", t.standin_out.read_text())[1])
    assert t.since(stopped, f"[ros2bag] {FINGER} stopped") < ENDED_AT_ONCE_S
    assert t.bag_counts().get(FINGER, 0) > 0


def test_audio_that_stops_mid_trial_fails_the_trial(trial, tmp_path):
    """The audio interface stalls (aslip recorder): the stand-in's audio stream, bridged by
    ``audio_capture source:=topic``, stops 1 s after the recorder and the watch have both
    counted /aslip/audio messages in their diagnostics. Found beside two CPU hogs: a WAV
    replay of fixed length could end before the watch had subscribed, and the verdict was
    then, rightly, "never arrived". Found in CI: the two readers in the graph were not yet
    both matched, and the bag held no audio; the stop now waits on what each has received."""
    cell = _cell(tmp_path, {"source": "topic", "input_topic": STANDIN_AUDIO,
                            "sample_rate": 16000.0, "channel_names": list(STANDIN_CHANNELS),
                            "layout": "''"}, watch=SLOW_START)
    t = trial("aslip", cell, [FINGER, OBJECT, "--audio", STANDIN_AUDIO, "--stop",
                              STANDIN_AUDIO, "--readers-of", AUDIO, "--subscribers", "2",
                              "--heard-by", "2"],
              f"duration_s:={FAILED_TRIAL_S}")
    _failed(t)
    (_, line), = t.lines("stream_watch", "the trial failed")
    assert line.startswith(f"{AUDIO}: no message for"), line
    stopped = float(re.search(r"stopped \S+ at (\d+\.\d+)", t.standin_out.read_text())[1])
    assert t.since(stopped, f"[aslip] {STANDIN_AUDIO} stopped") < ENDED_AT_ONCE_S
    assert t.bag_counts().get(AUDIO, 0) > 0


@pytest.mark.parametrize("route", ROUTES)
def test_an_audio_device_that_cannot_be_opened_fails_the_trial(trial, tmp_path, route):
    """sounddevice with a device that does not exist: audio_capture exits 1 at once."""
    cell = _cell(tmp_path, {"source": "device", "device": "no_such_aslip_device"})
    t = trial(route, cell, [FINGER, OBJECT], f"duration_s:={FAILED_TRIAL_S}")
    _failed(t)
    assert re.search(rf"ERROR: {AUDIO}: audio_capture exited with code 1", t.text), \
        t.text[-3000:]
    (failed, _), = t.lines("audio_capture", "cannot open audio source")
    assert t.since(failed, f"[{route}] the audio device could not be opened") < ENDED_AT_ONCE_S


def test_an_unreachable_arm_fails_the_trial(trial, tmp_path):
    """induced:=robot with the xArm at a TEST-NET address (the real SDK, a 1 s connect
    deadline): robot_sweeps exits 1 at once instead of waiting for an arm."""
    cell = _cell(tmp_path, _wav_audio(tmp_path),
                 {"xarm_ip": "192.0.2.1", "xarm_connect_timeout_s": 1.0})
    t = trial("aslip", cell, [FINGER, OBJECT], "induced:=robot",
              f"duration_s:={FAILED_TRIAL_S}")
    _failed(t)
    assert "ERROR: robot_sweeps exited with code 1: the arm did not sweep" in t.text, \
        t.text[-3000:]
    (failed, line), = t.lines("robot_sweeps", "the sweeps cannot start")
    assert "192.0.2.1" in line, line
    assert t.since(failed, "[aslip] the arm was unreachable") < ENDED_AT_ONCE_S


@pytest.mark.parametrize("route", ROUTES)
def test_a_complete_trial_ends_with_exit_0_and_a_complete_bag(trial, tmp_path, route):
    cell = _cell(tmp_path, _wav_audio(tmp_path), watch=BUSY_HOST)
    t = trial(route, cell, [FINGER, OBJECT], "duration_s:=3")
    assert t.wait() == 0, t.text[-4000:]
    assert "collection finished" in t.text
    assert "the trial failed" not in t.text
    assert t.nodes_left() == [], t.text[-3000:]
    counts = t.bag_counts()
    for topic in (AUDIO, FINGER, OBJECT, "/aslip/metadata", "/tf_static"):
        assert counts.get(topic, 0) > 0, (topic, counts)
    # The audio is whole: every block follows the one before it, sample for sample (a lost
    # block shows as a jump in first_sample_index). How many blocks 3 s of wall time holds
    # depends on the host's load (the streams' start-up), so the count is only a floor: at
    # least half of the 3 s of 10 ms blocks, and of the 120 Hz poses.
    t.assert_audio_contiguous()
    assert counts[AUDIO] >= 150 and counts[OBJECT] >= 180, counts
