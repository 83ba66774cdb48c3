"""One closed-loop episode of the demo, with the real nodes composed in this process.

Per episode: a ROS_DOMAIN_ID of its own (``domain_coordinator``, discovery on localhost), a
fresh rclpy context on it, and the package's real node classes (``scene_sim``,
``slip_inference``, ``slip_stop`` or ``slip_track``) plus a small recorder on one
executor. The pivot-stop task (issue #21) runs ``slip_stop`` on the scene's pivot: a wall
push downwards (``push_dir_xz`` (0, -1)) whose surface meets the object ``pivot_lever_m``
off the grasp axis, so it turns between the pads instead of sliding. Every message still goes
through DDS topics exactly as between the separate executables (composing the nodes in one
process changes only that); only the process start-up (importing torch and rclpy costs
seconds) is shared between episodes.

Two modes (``Episode.mode``). ``lockstep`` (the default): ``scene_sim`` steps a block only
once the graph has handled the one before, and publishes simulated time on ``/clock``; the
nodes run on it (``use_sim_time``, the controller one step per tick), so the trial does not
depend on how fast or how busy the host is (:func:`_spin_lockstep`). The compute time of
each block is charged to simulated time (``Episode.charge``: the declared budget of
:data:`LOCKSTEP_BUDGET_S`, or the time measured on this host): the estimate of a block is
due its budget after the block's end, and the controller's command takes effect its own
budget after that. ``realtime``: the scene paces itself against the wall clock, as on a
cell; what it measures is the machine as much as the method.

Node parameters go in as ``parameter_overrides`` of each node's constructor (its
``**kwargs`` reach ``rclpy.node.Node``, as in a composed rclpy process), checked by the same
declarations as from a launch file. The scene's true trajectory
(``World.trajectory()``) and the wall contacts are read from the scene node at the end.
"""

from __future__ import annotations

import gc
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Optional

import numpy as np

from aslip_ros.control.slip_stop import SlipStopConfig
from aslip_ros.control.slip_track import SlipTrackConfig
from benchmarks import demo_metrics as dm
from aslip_ros.scene.layouts import DEFAULT_LAYOUT
from aslip_ros.scene.scenario import Scenario

TASKS = ("slip_stop", "slip_track", "pivot_stop")
MODES = ("lockstep", "realtime")
CHARGES = ("budget", "measured")
#: The compute time charged to simulated time per block in lockstep [s], per node: the
#: estimator's by model family, about the p99 of the live node on the reference machine
#: (``make latency``, results/latency/tail.json: streaming 2.5 ms, window CNN 4.8 ms end to
#: end, idle; a hybrid, which runs both, as the slower), and the controller's one step.
#: ``--charge measured`` charges what this host takes instead.
LOCKSTEP_BUDGET_S = {"aslip_stream": 0.003, "aslip_cnn": 0.005, "svm": 0.005,
                     "aslip_hybrid": 0.005, "controller": 0.0005}
#: Lockstep: the longest the graph may take over one block before the episode is given up
#: as stalled (wall clock; a guard against a lost message, never reached in a sound run).
LOCKSTEP_STALL_S = 20.0
#: Lockstep: the wall-clock guard of a whole episode. Scene time decides a lockstep trial,
#: so a host too slow or too busy for ``Episode.wall_s_limit`` (the real-time guard) must
#: not turn a trial into a failure: past this guard the episode is an error (reported,
#: counted), never a scored trial. Measured: beside a training job and the test suite on 2
#: cores, 3 of 400 lockstep episodes passed 30 s and were scored as failures.
LOCKSTEP_WALL_S = 600.0


@dataclass(frozen=True)
class StopSettings:
    """Slip-stop timing: the paper's 10 cm retract and re-approach, at demo speeds (faster
    than the node's defaults, :class:`~aslip_ros.control.slip_stop.SlipStopConfig`)."""

    retract_distance_m: float = SlipStopConfig.retract_distance_m
    retract_speed_m_s: float = 0.08
    settle_s: float = 0.3
    approach_speed_m_s: float = 0.03
    debounce_count: int = SlipStopConfig.debounce_count
    # A missed slip must be able to push past the object's length (a failure by the
    # paper's rule) before the controller's own travel limit ends the approach.
    overshoot_limit_m: float = 0.15
    settle_result_s: float = 0.3


@dataclass(frozen=True)
class PivotSettings:
    """Pivot-stop: the slip-stop state machine lowers the object, held by one end, onto a
    surface below that meets it ``pivot_lever_m`` off the grasp axis (the scene's
    ``wall_push(push_dir_xz=(0, -1), pivot_lever_m=...)``): it turns instead of sliding.
    Retract and settle as in slip-stop; the approach turns the object at about
    ``approach_speed_m_s / pivot_lever_m`` (0.8 rad/s: 1.6 times the 0.5 rad/s at which a
    window is labelled rotating and above the controller's 0.7 that stops on it; at
    slip-stop's 3 cm/s it would turn at 0.3 rad/s, below both). The travel limit lets an
    arm that ignores rotation push ``overshoot_limit_m`` past the surface contact (the
    object then turns by about 25 degrees) before it stops on its own."""

    pivot_lever_m: float = 0.1
    retract_distance_m: float = SlipStopConfig.retract_distance_m
    retract_speed_m_s: float = 0.08
    settle_s: float = 0.3
    approach_speed_m_s: float = 0.08
    debounce_count: int = SlipStopConfig.debounce_count
    rotation_threshold_rad_s: float = SlipStopConfig.rotation_threshold_rad_s
    overshoot_limit_m: float = 0.05
    settle_result_s: float = 0.3


@dataclass(frozen=True)
class TrackSettings:
    """Slip-track: drag duration and the controller's law (aslip_ros.control.slip_track).

    The law commands the estimated object velocity (TCP velocity over the model's 200 ms
    window + predicted slip) plus a small integrated-slip position term; see the module.
    Its defaults are the node's, :class:`~aslip_ros.control.slip_track.SlipTrackConfig`'s.
    """

    duration_s: float = 4.0
    drag_speed_m_s: float = 0.04
    # The agent holds the object still this long after the grasp (what grasp_calibration
    # asks of a user) before its first pull; the episode lasts hold + duration, and the
    # RMSE is taken over the duration after the hold. The scene's default.
    agent_hold_s: float = Scenario.drag_hold_s
    gain: float = SlipTrackConfig.gain
    deadband_m_s: float = SlipTrackConfig.deadband_m_s
    max_speed_m_s: float = SlipTrackConfig.max_speed_m_s
    lowpass_tau_s: float = SlipTrackConfig.lowpass_tau_s
    hold_s: float = SlipTrackConfig.hold_s
    decay_s: float = SlipTrackConfig.decay_s
    velocity_window_s: float = SlipTrackConfig.velocity_window_s
    position_gain_1_s: float = SlipTrackConfig.position_gain_1_s
    position_leak_s: float = SlipTrackConfig.position_leak_s
    max_offset_m: float = SlipTrackConfig.max_offset_m

    def law(self) -> dict:
        """The controller's parameters: the fields shared with SlipTrackConfig."""
        names = {f.name for f in fields(SlipTrackConfig)}
        return {k: v for k, v in asdict(self).items() if k in names}


def robot_noise_name(x: float) -> str:
    """The stressor name of the arm's noise at ``x`` times the scene's: ``robot<x>x``, ``x``
    as ``%g`` writes it (``robot0.5x``); one name a factor."""
    return f"robot{x:g}x"


@dataclass(frozen=True)
class Episode:
    """What to run: task, method label, checkpoint, object, seed."""

    task: str
    method: str
    checkpoint: str
    object: str
    trial: int
    seed: int
    stop: StopSettings = field(default_factory=StopSettings)
    track: TrackSettings = field(default_factory=TrackSettings)
    wall_s_limit: float = 30.0     # wall-clock guard per real-time episode [s]
    pivot: PivotSettings = field(default_factory=PivotSettings)
    #: pivot_stop: ``rotation_aware`` (stop_on_rotation) or ``ignores_rotation``.
    arm: str = dm.PIVOT_ARMS[0]
    mode: str = MODES[0]
    charge: str = CHARGES[0]
    #: A held-out scene variant (a name in ``aslip_ros.scene.variants.VARIANTS``; None:
    #: the default scene) and a factor on the arm's operating noise level, both handed to
    #: ``scene_sim`` as its ``variant`` and ``robot_noise_x`` parameters.
    variant: Optional[str] = None
    robot_noise_x: float = 1.0

    def __post_init__(self) -> None:
        from aslip_ros.scene.variants import VARIANTS
        if self.arm not in dm.PIVOT_ARMS:
            raise ValueError(f"arm must be one of {dm.PIVOT_ARMS}, got {self.arm!r}")
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.charge not in CHARGES:
            raise ValueError(f"charge must be one of {CHARGES}, got {self.charge!r}")
        if self.variant is not None and self.variant not in VARIANTS:
            raise ValueError(f"variant must be None or one of {list(VARIANTS)}, got "
                             f"{self.variant!r}")
        if not (math.isfinite(self.robot_noise_x) and self.robot_noise_x >= 0.0):
            raise ValueError(f"robot_noise_x must be finite and >= 0, got "
                             f"{self.robot_noise_x!r}")

    @property
    def stressor(self) -> str:
        """The scene's stressor in words: ``default``, the variant's name, ``robot<x>x``
        for louder robot noise, or both joined by ``+``."""
        parts = ([self.variant] if self.variant else []) + \
            ([robot_noise_name(self.robot_noise_x)] if self.robot_noise_x != 1.0 else [])
        return "+".join(parts) or "default"

    @property
    def key(self) -> str:
        """File-name key of the episode (pivot-stop episodes name their arm, an episode in
        a stressed scene its stressor)."""
        arm = f"-{self.arm}" if self.task == "pivot_stop" else ""
        stressor = "" if self.stressor == "default" else f"-{self.stressor}"
        return f"{self.task}-{self.method}{arm}-{self.object}-{self.trial:02d}{stressor}"


def overrides(params: dict) -> list:
    """``parameter_overrides`` for a node constructor from ``{name: value}`` (types kept)."""
    from rclpy.parameter import Parameter
    return [Parameter(k, value=v) for k, v in params.items()]


def node_params(ep: Episode, length_m: float) -> dict:
    """Parameters of every node of the episode (SI units)."""
    scene = {"seed": int(ep.seed), "object": ep.object, "layout": DEFAULT_LAYOUT}
    if ep.variant is not None:
        scene["variant"] = ep.variant
    if ep.robot_noise_x != 1.0:
        scene["robot_noise_x"] = float(ep.robot_noise_x)
    if ep.task == "slip_stop":
        s = ep.stop
        scene.update(scenario="wall_push", wall_distance_m=0.0)
        ctl = {"approach_speed_m_s": s.approach_speed_m_s,
               "retract_distance_m": s.retract_distance_m,
               "retract_speed_m_s": s.retract_speed_m_s, "settle_s": s.settle_s,
               "max_approach_distance_m": s.retract_distance_m + length_m
               + s.overshoot_limit_m,
               "debounce_count": int(s.debounce_count),
               "settle_result_s": s.settle_result_s}
    elif ep.task == "pivot_stop":
        scene.update(pivot_scene(ep.pivot))
        ctl = pivot_controller(ep.pivot, ep.arm)
    else:
        scene.update(scenario="drag", drag_speed_m_s=ep.track.drag_speed_m_s,
                     drag_hold_s=ep.track.agent_hold_s)
        ctl = ep.track.law()
    out = {"scene_sim": scene, "slip_inference": {"checkpoint": str(ep.checkpoint)},
           ep.task: ctl}
    if ep.mode == "lockstep":
        for name, params in out.items():
            params["use_sim_time"] = True
            if name != "slip_inference":
                params["lockstep"] = True
    return out


def pivot_scene(s: PivotSettings) -> dict:
    """scene_sim's parameters of the pivot: a wall push down onto a surface met off the
    grasp axis, starting in contact (scene_sim's ``pivot`` scenario)."""
    return {"scenario": "pivot", "wall_distance_m": 0.0,
            "pivot_lever_m": float(s.pivot_lever_m)}


def pivot_controller(s: PivotSettings, arm: str) -> dict:
    """slip_stop's parameters of one pivot arm: the same state machine, acting on the
    rotation estimate or ignoring it (planar slip and its travel limit only)."""
    return {"approach_speed_m_s": s.approach_speed_m_s,
            "retract_distance_m": s.retract_distance_m,
            "retract_speed_m_s": s.retract_speed_m_s, "settle_s": s.settle_s,
            "max_approach_distance_m": s.retract_distance_m + s.overshoot_limit_m,
            "debounce_count": int(s.debounce_count),
            "stop_on_rotation": arm == dm.PIVOT_ARMS[0],
            "rotation_threshold_rad_s": float(s.rotation_threshold_rad_s),
            "settle_result_s": s.settle_result_s}


class _Recorder:
    """Collects the predicted slip, the arm commands (stamp, speed) and the slip-stop result
    (a plain rclpy node)."""

    def __init__(self) -> None:
        from geometry_msgs.msg import TwistStamped
        from rclpy.node import Node
        from std_msgs.msg import String

        from aslip_ros.msg import SlipVector
        from aslip_ros.nodes import common as c
        from aslip_ros.runtime.qos import LATCHED_QOS
        from aslip_ros.nodes.slip_stop import RESULT_TOPIC
        self.node = Node("aslip_demo_recorder")
        self.slip: list[tuple] = []
        self.commands: list[tuple[int, float]] = []
        self.result: Optional[dict] = None
        self.node.create_subscription(SlipVector, c.SLIP_TOPIC, self._on_slip, 100)
        # Reliable, and deep enough to keep every command of an episode that falls behind.
        self.node.create_subscription(TwistStamped, c.CMD_VEL_TOPIC, self._on_cmd, 1000)
        self.node.create_subscription(String, RESULT_TOPIC, self._on_result, LATCHED_QOS)

    def _on_cmd(self, msg) -> None:
        lin = msg.twist.linear
        self.commands.append((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                              math.sqrt(lin.x * lin.x + lin.y * lin.y + lin.z * lin.z)))

    def _on_slip(self, msg) -> None:
        st = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.slip.append((st, msg.velocity.x, msg.velocity.z, msg.probability,
                          bool(msg.slipping), float(getattr(msg, "angular_velocity", 0.0))))

    def _on_result(self, msg) -> None:
        try:
            self.result = json.loads(msg.data)
        except ValueError:
            pass


_WARM: set = set()


def warm_up(checkpoint: str) -> None:
    """Run the model once outside any episode.

    The first forward pass in a process pays torch's lazy initialisation (a few hundred
    ms); inside an episode that would stall ``slip_inference`` long enough for the
    best-effort audio queue to overflow, which no warm node on a real cell would see.
    """
    if checkpoint in _WARM:
        return
    from aslip_ros.learn.checkpoint import load_checkpoint
    from aslip_ros.learn.models.registry import model_backend
    from aslip_ros.learn.inference.live import load_predictor
    ckpt = load_checkpoint(checkpoint)
    if model_backend(ckpt.model_type).streaming:   # slip_inference warms it up itself
        _WARM.add(checkpoint)
        return
    pred = load_predictor(ckpt, max_time_jump_s=0.05)
    window = np.zeros((int(pred.meta["window_samples"]), len(pred.meta["channel_names"])),
                      dtype=np.float32)
    for _ in range(3):
        pred.predict(window)
    _WARM.add(checkpoint)


class StallProbe:
    """The worker's own tail during one episode: how long the executor went between two
    callbacks (``spin_once`` returns; idle ones wait at most ``SPIN_TIMEOUT_S``) and every
    pause of Python's cyclic garbage collector, per generation."""

    def __init__(self) -> None:
        self.gaps: list[float] = []
        self.gc_pauses: list[tuple[int, float]] = []
        self._last: Optional[float] = None
        self._gc_t0 = 0.0

    def _on_gc(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._gc_t0 = time.perf_counter()
        else:
            self.gc_pauses.append((int(info.get("generation", -1)),
                                   time.perf_counter() - self._gc_t0))

    def __enter__(self) -> "StallProbe":
        gc.callbacks.append(self._on_gc)
        return self

    def __exit__(self, *exc) -> None:
        gc.callbacks.remove(self._on_gc)

    def tick(self) -> None:
        """After each ``spin_once``: the gap since the previous one."""
        now = time.perf_counter()
        if self._last is not None:
            self.gaps.append(now - self._last)
        self._last = now

    def summary(self) -> dict:
        """Gaps and pauses in ms: p50, p99, p99.9, max (the live bench's ``tail_stats``),
        and what exceeded 50 ms."""
        from benchmarks.node_bench import tail_stats
        g = np.asarray(self.gaps, dtype=float) * 1e3
        pauses = np.asarray([d for _, d in self.gc_pauses], dtype=float) * 1e3
        full = [d * 1e3 for gen, d in self.gc_pauses if gen == 2]
        return {"spin_gaps": int(g.size), **tail_stats(g, "spin_gap"),
                "spin_gaps_over_50ms": int(np.sum(g > 50.0)),
                "gc_pauses": int(pauses.size),
                "gc_pause_max_ms": float(pauses.max()) if pauses.size else 0.0,
                "gc_full_collections": len(full),
                "gc_full_max_ms": max(full) if full else 0.0}


#: The longest an idle ``spin_once`` waits in an episode [s].
SPIN_TIMEOUT_S = 0.02


def run_episode(ep: Episode, keep_trace: bool = True) -> dict:
    """Run one episode; returns its metrics (and, with ``keep_trace``, arrays for plots)."""
    import rclpy
    from domain_coordinator import domain_id
    from rclpy.signals import SignalHandlerOptions

    from aslip_ros.nodes.scene_sim import SceneSim
    from aslip_ros.nodes.slip_inference import SlipInference
    from aslip_ros.scene.layouts import get_object
    if ep.task in ("slip_stop", "pivot_stop"):
        from aslip_ros.nodes.slip_stop import SlipStopNode as Controller
    elif ep.task == "slip_track":
        from aslip_ros.nodes.slip_track import SlipTrackNode as Controller
    else:
        raise ValueError(f"unknown task {ep.task!r}; choose one of {TASKS}")

    warm_up(str(ep.checkpoint))
    length = get_object(ep.object).length_m
    t_wall0 = time.monotonic()
    params = node_params(ep, length)
    nodes = []
    executor = None
    with domain_id() as did:
        rclpy.init(domain_id=did, signal_handler_options=SignalHandlerOptions.NO)
        try:
            rec = _Recorder()
            nodes.append(rec.node)
            infer = SlipInference(parameter_overrides=overrides(params["slip_inference"]))
            nodes.append(infer)
            ctl = Controller(parameter_overrides=overrides(params[ep.task]))
            nodes.append(ctl)
            # The scene last: its clock starts now, and nothing should miss its start.
            sim = SceneSim(parameter_overrides=overrides(params["scene_sim"]))
            nodes.append(sim)
            executor = _make_executor()
            for n in nodes:
                executor.add_node(n)
            with StallProbe() as probe:
                if ep.mode == "lockstep":
                    outcome = _spin_lockstep(ep, executor, sim, infer, ctl, rec, t_wall0,
                                             probe)
                else:
                    outcome = _spin(ep, executor, sim, ctl, rec, t_wall0, probe)
            _drain_commands(ep, executor, probe, ctl, rec)
            # Input arrival gaps and stop latency, as the controller saw them.
            timing = dict(ctl.inputs.values(), **ctl.stop_latency())
            ctl.before_shutdown()
            out = _score(ep, sim, rec, length, outcome)
            out["calibration"] = calibration_outcome(infer.predictor, sim.world)
            out["controller_timing"] = timing
            out["worker_timing"] = probe.summary()
            if ep.task == "slip_track":
                out["controller_reason"] = ctl.task.reason if ctl.task else "not started"
        finally:
            if executor is not None:
                executor.shutdown(timeout_sec=2.0)
            for n in nodes:
                n.destroy_node()
            rclpy.try_shutdown()
    out["wall_s"] = round(time.monotonic() - t_wall0, 3)
    if not keep_trace:
        out.pop("trace", None)
    return out


def _make_executor():
    """The executor all nodes of an episode share (``ASLIP_DEMO_EXECUTOR`` picks it)."""
    kind = os.environ.get("ASLIP_DEMO_EXECUTOR", "events")
    if kind == "events":
        from rclpy.experimental.events_executor import EventsExecutor
        return EventsExecutor()
    if kind == "single":
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor()
    from rclpy.executors import MultiThreadedExecutor
    return MultiThreadedExecutor(num_threads=4)


def _spin(ep: Episode, executor, sim, ctl, rec, t_wall0: float, probe: StallProbe) -> str:
    """Spin until the trial is decided; returns why the episode ended."""
    while True:
        executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
        probe.tick()
        if time.monotonic() - t_wall0 > ep.wall_s_limit:
            return "wall_clock_limit"
        ended = _decided(ep, sim.world, rec)
        if ended:
            return ended


class LockstepStall(RuntimeError):
    """The graph did not handle a block within :data:`LOCKSTEP_STALL_S` (names what it
    waited for)."""


def _spin_until(executor, probe: StallProbe, done, what: str) -> None:
    """Spin the episode's executor until ``done()``; a stall past the guard raises."""
    t0 = time.monotonic()
    while not done():
        executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
        probe.tick()
        if time.monotonic() - t0 > LOCKSTEP_STALL_S:
            raise LockstepStall(f"lockstep: no {what} within {LOCKSTEP_STALL_S:g} s")


def _spin_lockstep(ep: Episode, executor, sim, infer, ctl, rec, t_wall0: float,
                   probe: StallProbe) -> str:
    """Lockstep (module docstring): per block, (1) the scene steps and publishes it; (2) the
    graph handles it: ``slip_inference`` has every frame and is idle, and the controller and
    the recorder have every estimate and pose; (3) ``/clock`` ticks at the block's end plus
    the estimator's charge, the controller takes one step, and the scene has its commands
    (and ``slip_inference`` any recalibration request), each to take effect the
    controller's charge after the tick. Nothing waits on a wall-clock period, so a slower
    or busier host only takes longer."""
    world, blocks = sim.world, 0
    budget = LOCKSTEP_BUDGET_S.get(infer.source, max(LOCKSTEP_BUDGET_S.values()))
    sim.command_delay_s = LOCKSTEP_BUDGET_S["controller"]
    cal = ctl.calibration
    while True:
        if not sim.lockstep_block():
            return "duration"
        blocks += 1
        # The model thread's end wakes no executor where it publishes nothing (a hybrid's
        # window part): wait on the thread itself, not a spin's timeout.
        _spin_until(executor, probe, lambda: infer.blocks_in >= blocks
                    and infer.wait_idle(SPIN_TIMEOUT_S)
                    and ctl.slip_count + ctl.rejected_slip >= infer.published
                    and len(rec.slip) >= infer.published
                    and ctl.pose_count >= sim.tcp_published, "estimate for the block")
        charge = budget if ep.charge == "budget" else infer.last_compute_s
        steps = ctl.control_steps
        sim.lockstep_clock(world.t + charge)
        arm = ctl.arm
        _spin_until(executor, probe, lambda: ctl.control_steps > steps
                    and sim.n_commands + sim.n_rejected >= getattr(arm, "published", 0)
                    and cal.requests <= cal.replies, "control step")
        if time.monotonic() - t_wall0 > LOCKSTEP_WALL_S:
            raise LockstepStall(f"lockstep: the episode took more than {LOCKSTEP_WALL_S:g} s "
                                "of wall time (a host this slow is an error, not a trial)")
        ended = _decided(ep, world, rec)
        if ended:
            return ended


def _drain_commands(ep: Episode, executor, probe: StallProbe, ctl, rec) -> None:
    """Every arm command the controller published reaches the recorder before the score:
    in lockstep as surely as the scene got them (a stall past the guard raises); in real
    time for at most a second (``stop_hold`` then reads what arrived)."""
    def done():
        return len(rec.commands) >= getattr(ctl.arm, "published", 0)
    if ep.mode == "lockstep":
        _spin_until(executor, probe, done, "arm commands at the recorder")
        return
    t0 = time.monotonic()
    while not done() and time.monotonic() - t0 < 1.0:
        executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
        probe.tick()


def _decided(ep: Episode, world, rec) -> Optional[str]:
    """Why the trial is decided, or None while it is not."""
    if ep.task == "slip_track":
        return "duration" if world.t >= ep.track.agent_hold_s + ep.track.duration_s \
            else None
    if rec.result is not None and rec.result.get("final"):
        return "controller_result"
    if ep.task == "pivot_stop":
        return None                # the controller's travel limit bounds the turn
    contact = world.wall_contact_tcp_position
    if contact is not None and \
            (world.tcp_pose()[:3] - contact) @ world.wall_normal() > world.object.length_m + 0.01:
        # Already past the object's length: the trial has failed whatever follows.
        return "pushed_past_length"
    return None


def _score(ep: Episode, sim, rec, length: float, ended: str) -> dict:
    world = sim.world
    traj = world.trajectory()
    start_ns = sim.scene.start_ns
    out = {"task": ep.task, "method": ep.method, "object": ep.object, "trial": ep.trial,
           "seed": ep.seed, "ended": ended, "scene_s": round(world.t, 3),
           "skipped_blocks": int(sim.scene.skipped_blocks), "n_slip_msgs": len(rec.slip)}
    if ep.stressor != "default":
        # What the scene node was given and built: its parameters and its robot noise level.
        out.update(stressor=ep.stressor, scene={
            "variant": sim.p["variant"], "robot_noise_x": sim.p["robot_noise_x"],
            "robot_level": world.scenario.acoustics.robot_level})
    cmd = np.array(rec.commands, dtype=float).reshape(-1, 2)
    cmd_t = (cmd[:, 0] - start_ns) / 1e9
    if ep.task in ("slip_stop", "pivot_stop"):
        out["stop_hold"] = dm.stop_hold(cmd_t, cmd[:, 1], world.t)
    if ep.task == "slip_stop":
        first = world.wall_contacts[0][1] if world.wall_contacts else None
        o = dm.stop_outcome(traj["t"], traj["tcp"], world.wall_normal(), world.wall_contacts,
                            length, initial_contact=first)
        out.update(o.to_dict())
        res = rec.result or {}
        out["controller_reason"] = res.get("reason")
        out["controller_distance_m"] = res.get("stopping_distance_m")
        out["onset_to_stop_s"] = dm.onset_to_stop_s(world.slip_onset_time,
                                                    world.arm.stop_times)
    elif ep.task == "pivot_stop":
        out.update(_score_pivot(ep, world, traj, rec))
    else:
        out["pose_rmse_m"] = dm.pose_rmse(traj["t"], traj["rel"],
                                          t_from_s=ep.track.agent_hold_s)
        rel = traj["rel"]
        out["max_excursion_m"] = float(np.max(np.linalg.norm(rel - rel[0], axis=1))) \
            if len(rel) else math.nan
    slip = np.array(rec.slip, dtype=float).reshape(-1, 6)
    out["lag_curve"] = dm.lag_curve(traj["t"], traj["v_rel"], (slip[:, 0] - start_ns) / 1e9,
                                    slip[:, 1:3])
    out["trace"] = {
        "t": traj["t"].astype(np.float32), "tcp": traj["tcp"].astype(np.float32),
        "object": traj["object"].astype(np.float32), "rel": traj["rel"].astype(np.float32),
        "v_rel": traj["v_rel"].astype(np.float32),
        "pred_t": ((slip[:, 0] - start_ns) / 1e9).astype(np.float32),
        "pred_v": slip[:, 1:3].astype(np.float32), "pred_p": slip[:, 3].astype(np.float32),
        "pred_w": slip[:, 5].astype(np.float32),
        "push_dir": world.wall_normal().astype(np.float32),
        # The arm commands: stamp (scene time [s], float64: stamps are compared) and speed.
        "cmd_t": cmd_t, "cmd_speed": cmd[:, 1].astype(np.float32)}
    for k in ("angle", "w_rel"):        # the scene's rotation (scene version 4)
        if k in traj:
            out["trace"][k] = np.asarray(traj[k]).astype(np.float32)
    return out


def _score_pivot(ep: Episode, world, traj: dict, rec) -> dict:
    """The pivot-stop trial: the angle turned before the arm came to rest, from the truth."""
    o = dm.pivot_outcome(traj["t"], traj["tcp"], world.angle_turned(),
                         world.rotation_onset_time, world.arm.stop_times)
    res = rec.result or {}
    out = {"arm": ep.arm, **o.to_dict(), "controller_reason": res.get("reason"),
           "controller_distance_m": res.get("stopping_distance_m")}
    out["success"] = dm.pivot_success(out)
    return out


def calibration_outcome(predictor, world) -> Optional[dict]:
    """Where the live per-grasp calibration got by the end of the episode, against the
    scene's true microphone gains (None for a model without calibration)."""
    if not getattr(predictor, "calibrated", False):
        return None
    s = predictor.calibration_summary()
    est = np.array(list(s["gain_db"].values()), dtype=float)
    true = 20.0 * np.log10(np.asarray(world.synth.gain, dtype=float))
    true -= true.mean()         # gains are relative: the calibration has no absolute level
    return {"converged": bool(s["calibration_converged"]),
            "converged_after_s": s.get("calibration_converged_after_s"),
            "accepted_frames": int(s["calibration_accepted_frames"]),
            "gain_error_db": float(np.sqrt(np.mean((est - true) ** 2))),
            "uncalibrated_error_db": float(np.sqrt(np.mean(true ** 2)))}


def episode_dict(ep: Episode) -> dict:
    """The episode's settings as plain JSON."""
    return asdict(ep)


def save_trace(path: Path, result: dict) -> None:
    """Write an episode's arrays (for the plots) as a compressed ``.npz``."""
    trace = result.get("trace")
    if not trace:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **trace)
    os.replace(tmp, path)
