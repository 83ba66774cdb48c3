"""Data collection: audio + motion capture + ground-truth slip + TF, recorded to a bag.

Simulation (default; the launch ends when `duration_s` of scene time is recorded):
    ros2 launch aslip_ros data_collection.launch.py scenario:=external_induced object:=chips_can
Hardware (docs/hardware-quickstart.md; the cell file names the device, channels, mocap
topics, grasp planes and arm limits; the launch ends after `duration_s`, 0 = at Ctrl-C):
    ros2 launch aslip_ros data_collection.launch.py sim:=false cell:=my_cell.yaml \
        object:=chips_can bag:=bags/ext_001
    ros2 launch aslip_ros data_collection.launch.py sim:=false cell:=my_cell.yaml \
        induced:=robot object:=probe bag:=bags/robot_001    # the arm sweeps the grasp

`recorder:=ros2bag` records with `ros2 bag record` (mcap), `recorder:=aslip` with the
package's own `bag_recorder` node (no rosbag2 needed), `auto` (default) picks ros2bag when it
is installed. Either records the audio, the pose topics the graph uses (remapped ones
included), the TCP, the ground truth, TF and the metadata, which on hardware carries the
cell's grasp-plane calibrations and the pose topic names (`aslip export` reads both). A
recorder that stops while the launch runs shuts the whole launch down with the reason: a
collection that records nothing must not look like one that works.

A failed hardware trial fails the launch (exit status 1, whichever the recorder), with one
ERROR line naming the stream, and the recorder closes its bag whole on the way out:
`stream_watch` (nodes/stream_watch.py) exits 1 when the audio or a pose stream never
arrives or stops mid-trial; audio_capture exits 1 when its source cannot be opened or
fails (`exit_on_error`); robot_sweeps exits 1 when it cannot reach its arm. `ros2 launch`
exits 0 after a Shutdown action, so each of these exits ends the launch through `fail`.
"""

import os
import re
import shutil

from ament_index_python.packages import PackageNotFoundError, get_package_prefix
from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, ExecuteProcess, LogInfo, OpaqueFunction,
                            RegisterEventHandler, Shutdown, TimerAction)
from launch.event_handlers import OnProcessExit, OnProcessIO
from launch_ros.actions import Node

from aslip_ros.cell import CellError
from aslip_ros.topics import AUDIO, METADATA, TF_STATIC
from aslip_ros.nodes.bag_recorder import record_topics
from aslip_ros.nodes.topic_audio import driver_topics
from aslip_ros.launch_support.common import (arg, arm_params, bridge_params,
                                             capture_params, cell_arguments, fail, flag,
                                             load_checked_cell, mocap_topics, node_param,
                                             rigid_bodies_source,
                                             recording_metadata, required, share_dir)

RECORDERS = ("auto", "ros2bag", "aslip")
INDUCED = ("external", "robot")
#: A node's readiness line (``common.ready``: ``ready`` or ``ready: ...``), whatever the
#: console format (RCUTILS_CONSOLE_OUTPUT_FORMAT) around the message.
READY_LINE = re.compile(rb"(?m)(?:^|\W)ready(?::|\s*$)")
#: Seconds between the end of a finite scene run and the end of the launch.
END_GRACE_S = 1.0


def ros2bag_found() -> bool:
    """Whether `ros2 bag` (rosbag2) is installed."""
    try:
        get_package_prefix("ros2bag")
    except PackageNotFoundError:
        return False
    return shutil.which("ros2") is not None


def _recorder_choice(context) -> str:
    """The recorder ``recorder:=`` picks ('auto': ros2bag where installed)."""
    choice = arg(context, "recorder")
    if choice == "auto":
        return "ros2bag" if ros2bag_found() else "aslip"
    return choice


def _recorder(context, topics: list, poses: list, duration_s: float,
              rigid: tuple = (), latched: tuple = ()) -> list:
    """The recorder; with ``duration_s`` > 0 (hardware, aslip recorder) it ends the
    collection once the audio spans that long, and the ``latched`` topics that the cell's
    nodes publish are in (however late their publisher is discovered)."""
    choice = arg(context, "recorder")
    bag = arg(context, "bag")
    if choice not in RECORDERS:
        return fail(f"recorder:={choice} is none of {', '.join(RECORDERS)}")
    choice = _recorder_choice(context)
    if choice == "ros2bag":
        if not ros2bag_found():
            return fail("recorder:=ros2bag but rosbag2 (`ros2 bag`) is not installed; "
                        "use recorder:=aslip")
        rec = ExecuteProcess(cmd=["ros2", "bag", "record", "-s", "mcap", "-o", bag] + topics,
                             name="ros2_bag_record", output="screen")
    else:
        pose_topics = [t for t in poses if t not in rigid] or [""]
        rec = Node(package="aslip_ros", executable="bag_recorder", name="bag_recorder",
                   output="screen", parameters=[{"output": bag, "topics": list(topics),
                                                 "pose_topics": pose_topics,
                                                 "rigid_bodies_topics": list(rigid) or [""],
                                                 "duration_s": duration_s,
                                                 "duration_topics": [AUDIO] + list(poses),
                                                 "latched_due": list(latched) or [""]}])

    def stopped(event, ctx):
        if ctx.is_shutdown:
            return None
        if event.returncode == 0 and duration_s > 0 and choice == "aslip":
            return _ended("bag_recorder", f"recorded {duration_s:g} s")(event, ctx)
        return fail(f"the recorder ({choice}) exited with code {event.returncode} while "
                    f"the launch was running: nothing more is recorded to {bag}")

    return [LogInfo(msg=f"recording {', '.join(topics)} with {choice} to {bag}"), rec,
            RegisterEventHandler(OnProcessExit(target_action=rec, on_exit=stopped))]


def _ended(who: str, done: str, failed: str = ""):
    """``on_exit`` of the node whose end is the end of the collection (``who``); a nonzero
    exit fails the launch (``failed`` says what that means)."""
    def ended(event, ctx):
        if ctx.is_shutdown:
            return None
        if event.returncode != 0:
            return fail(f"{who} exited with code {event.returncode}{failed}")
        why = f"{done}: collection finished"
        # The recorder still receives what was in flight when the node ended; then the
        # launch ends. (A launch test can also finish its checks before the launch is gone.)
        return [LogInfo(msg=why),
                TimerAction(period=END_GRACE_S, actions=[Shutdown(reason=why)])]
    return ended


def _stream_lost(stream: str, who: str, why: str):
    """``on_exit`` of the node ``who`` without which ``stream`` gets nothing: the trial
    failed."""
    def lost(event, ctx):
        if ctx.is_shutdown:
            return None
        return fail(f"{stream}: {who} exited with code {event.returncode} ({why}): the "
                    "trial failed")
    return lost


def _stream_watch(cell, poses, duration_s: float, latched: tuple = ()) -> list:
    """stream_watch over the audio and both pose streams of a hardware trial; its exit
    (code 1: a stream never arrived or stopped, its ERROR line names it) fails the launch,
    whichever the recorder. With ``duration_s`` > 0 (``ros2 bag record``, which has no
    duration) it ends the trial: exit 0 that long after every stream is in and the
    ``latched`` topics have reached it. Its thresholds
    are its parameters' defaults (data/stream_watch.py) or the cell's ``stream_watch``
    section's (a lab whose motion capture drops a body for longer)."""
    streams = list(dict.fromkeys([AUDIO, *poses]))    # one topic may carry both bodies
    params = dict(cell.params("stream_watch"), topics=streams, duration_s=duration_s,
                  latched_due=list(latched) if duration_s > 0 and latched else [""])
    watch = Node(package="aslip_ros", executable="stream_watch", name="stream_watch",
                 parameters=[params], output="screen")
    done = _ended("stream_watch", f"every stream recorded {duration_s:g} s",
                  ": a stream of the trial failed (named in its ERROR line above)")

    def ended(event, ctx):
        if ctx.is_shutdown:
            return None
        if event.returncode == 0 and duration_s <= 0:
            return fail("stream_watch exited while the trial ran")
        return done(event, ctx)
    return [watch, RegisterEventHandler(OnProcessExit(target_action=watch, on_exit=ended))]


def _once_ready(node, actions: list) -> list:
    """``actions`` once ``node`` has logged its readiness line (``common.ready``: after its
    autostart). The stream watch's deadlines count from its own start: started with the
    launch, they would include audio_capture's start-up, measured at 8 s on a loaded
    2-core machine (the pose streams of a running driver come within a second)."""
    started = []

    def seen(event):
        if started or not READY_LINE.search(event.text):
            return None
        started.append(True)
        return actions
    return [RegisterEventHandler(OnProcessIO(target_action=node, on_stdout=seen,
                                             on_stderr=seen))]


def _duration(context) -> float:
    text = arg(context, "duration_s")
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"duration_s:={text} is not a number of seconds") from None
    if not value >= 0.0:
        raise ValueError(f"duration_s:={text} must be >= 0 (0 = until Ctrl-C)")
    return value


def _graph(context) -> list:
    try:
        return _nodes(context)
    except (CellError, ValueError) as exc:
        return fail(str(exc))


def _nodes(context) -> list:
    cfg = os.path.join(share_dir(), "config")
    sim = flag(context, "sim")
    cell = load_checked_cell(arg(context, "cell"))
    duration = _duration(context)
    induced = arg(context, "induced")
    if induced not in INDUCED:
        raise ValueError(f"induced:={induced} is none of {', '.join(INDUCED)}")
    bridge = Node(package="aslip_ros", executable="mocap_bridge", name="mocap_bridge",
                  output="screen", on_exit=required,
                  parameters=[os.path.join(cfg, "mocap_bridge.yaml"),
                              bridge_params(context, cell, sim)])
    actions = [bridge]
    if sim:
        scenario = arg(context, "scenario")
        scene = Node(package="aslip_ros", executable="scene_sim", name="scene_sim",
                     output="screen",
                     parameters=[os.path.join(cfg, "scene_sim.yaml"),
                                 {"scenario": scenario, "object": arg(context, "object"),
                                  "seed": int(arg(context, "seed")), "duration_s": duration,
                                  "exit_when_done": duration > 0,
                                  # a recorder that starts late must not lose the start
                                  "start_with_subscriber": flag(context, "record"),
                                  "condition": "robot_moving" if scenario == "robot_induced"
                                  else "robot_stationary"}])
        actions += [scene,
                    RegisterEventHandler(OnProcessExit(
                        target_action=scene,
                        on_exit=_ended("scene_sim", "the scene ran its duration_s")))]
    else:
        robot = induced == "robot"
        condition = arg(context, "condition") or ("robot_moving" if robot
                                                  else "robot_stationary")
        meta = recording_metadata(context, cell, object=arg(context, "object"),
                                  induced=induced, condition=condition)
        audio = dict(capture_params(context, cell, meta), exit_on_error=True)
        capture = Node(package="aslip_ros", executable="audio_capture",
                       name="audio_capture", output="screen",
                       on_exit=_stream_lost(AUDIO, "audio_capture",
                                            "its audio source failed, see above"),
                       parameters=[os.path.join(cfg, "audio_capture.yaml"), audio])
        actions.append(capture)
        if robot:
            # The sweeps end the recording: their duration, then back to the start.
            sweeps = arm_params(context, cell, "robot_sweeps", sim=False)
            # exit_when_done also for duration_s:=0: an arm it cannot reach, or a fault,
            # ends the process (code 1), and with it the trial.
            sweeps.update(duration_s=duration, exit_when_done=True,
                          seed=int(arg(context, "seed")))
            node = Node(package="aslip_ros", executable="robot_sweeps", name="robot_sweeps",
                        output="screen",
                        parameters=[os.path.join(cfg, "robot_sweeps.yaml"), sweeps])
            actions += [node, RegisterEventHandler(OnProcessExit(
                target_action=node, on_exit=_ended(
                    "robot_sweeps", "the sweeps are done",
                    ": the arm did not sweep to the end (its error above); the trial failed")))]
    # On hardware an external trial ends duration_s after every stream is in: the aslip
    # recorder counts it, and for ros2 bag the stream watch; no recorder: from the launch.
    record = flag(context, "record")
    external = not sim and induced == "external"
    recorded = external and record and _recorder_choice(context) == "aslip"
    watched = external and record and not recorded
    if external and duration > 0 and not record:
        why = f"ran for duration_s:={duration:g}: collection finished"
        actions.append(TimerAction(period=duration, actions=[
            LogInfo(msg=why), Shutdown(reason=why)]))
    if flag(context, "record"):
        poses = mocap_topics(context, cell)
        # On hardware audio_capture latches the metadata and mocap_bridge, unless told
        # not to, the calibration on /tf_static: a timed trial does not end without them.
        latched = () if sim else (METADATA,) + (
            (TF_STATIC,) if node_param(cell, "mocap_bridge", "publish_tf") else ())
        if not sim:
            watch = _stream_watch(cell, poses, duration if watched else 0.0, latched)
            actions += _once_ready(capture, watch)
        # audio_common's own pair too, where the cell bridges it (aslip export reads it).
        driver = [] if sim else driver_topics(cell.params("audio_capture"))
        source = rigid_bodies_source(context, cell)     # mocap4r2: both on one topic
        actions += _recorder(context, record_topics(*poses) + driver, list(poses),
                             duration if recorded else 0.0,
                             (source["topic"],) if source else (), latched)
    return actions


def generate_launch_description():
    args = [
        DeclareLaunchArgument("sim", default_value="true", description="simulated scene"),
        DeclareLaunchArgument("scenario", default_value="external_induced",
                              description="sim: external_induced | robot_induced"),
        DeclareLaunchArgument("induced", default_value="external",
                              description="hw: external (someone moves the object) | robot "
                                          "(robot_sweeps moves the arm; a clamped probe)"),
        DeclareLaunchArgument("condition", default_value="",
                              description="hw: recorded as the trial's condition (default "
                                          "robot_stationary, robot_moving for induced:=robot)"),
        DeclareLaunchArgument("object", default_value="chips_can"),
        DeclareLaunchArgument("seed", default_value="0"),
        DeclareLaunchArgument("duration_s", default_value="30.0",
                              description="sim: scene time to record; hw: seconds from the "
                                          "launch; then the launch ends; 0 = until Ctrl-C"),
        DeclareLaunchArgument("bag", default_value="aslip_bag", description="output bag"),
        DeclareLaunchArgument("record", default_value="true"),
        DeclareLaunchArgument("recorder", default_value="auto",
                              description="auto | ros2bag | aslip (no rosbag2 needed)"),
    ] + cell_arguments()
    return LaunchDescription(args + [OpaqueFunction(function=_graph)])
