"""``aslip check realtime``: does the live inference keep its 100 Hz hop on this machine?

For each checkpoint, the live estimator (:class:`aslip_ros.learn.inference.live.LiveEstimator`,
the object ``slip_inference`` drives) is fed the simulated scene's audio block by block, one
hop (``hop_s``, 10 ms) a block, as fast as the machine goes (unpaced: the figures are per
hop, not per second of wall time). The scene is the demo's slip-stop task (a wall push,
object in contact), closed by :class:`aslip_ros.control.slip_stop.SlipStop` on the scene's
arm, so one measurement is one real-time demo worker's work without the middleware.

Per hop: the wall time of the estimator's work (``accept`` and, for a window model,
``run``), whose p50 / p99 / max are reported, and the process CPU time of the estimator,
the scene (``World.step``) and the controller, each summed into the cores that share needs
at real time (CPU seconds per second of audio). Wall time counts every stall of the process
(another process on its core, a CPU quota, a stopped process), CPU time only its own work:
a starved machine shows a long p99 at the same CPU.

The verdict (:func:`verdict`): OK when ``p99 <= margin * hop_s`` and the inference needs at
most ``max_cores``. :func:`demo_workers` turns the figures into how many real-time demo
workers fit on the machine.

No ROS here: the check runs on a machine without a ROS environment.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Iterable, Optional, Sequence, Union

import numpy as np

from aslip_ros.audio_frame import NS_PER_S, AudioData
from aslip_ros.bringup.verdict import Verdict
from aslip_ros.control.command import apply_command
from aslip_ros.node_table import DEFAULT_MODEL

#: The shipped checkpoints measured when none is given (``models/`` of the checkout, else
#: of the install's ``share/aslip_ros``).
DEFAULT_CHECKPOINTS = (DEFAULT_MODEL, "aslip_stream.pt", "aslip_cnn.pt",
                       "aslip_cnn_uncalibrated.pt", "svm.pt")
#: Seconds of audio measured per checkpoint [s].
DEFAULT_DURATION_S = 5.0
#: OK when the per-hop p99 is at most this fraction of the hop.
DEFAULT_MARGIN = 0.5
#: OK when the inference needs at most this many cores at real time.
DEFAULT_MAX_CORES = 0.5
#: The share of the machine's cores the demo's workers may use together.
DEFAULT_WORKER_BUDGET = 0.7
#: What one demo worker needs beyond what is measured here [cores]: its rclpy executor
#: and DDS (about ten callbacks and their (de)serialisation every 10 ms). An estimate, not
#: measured by this check.
DEFAULT_MIDDLEWARE_CORES = 0.15
#: torch threads, as ``slip_inference``'s ``torch_threads`` default and the demo's workers.
DEFAULT_THREADS = 1
#: Blocks fed after the first hop and before timing starts (caches, allocator, branch
#: predictors: a live node has run for a while).
_PREROLL_BLOCKS = 20
#: A per-hop wall p99 over this many times the CPU p99 (plus 1 ms) is mostly waiting.
WAITING_FACTOR = 2.0
#: What :func:`demo_workers` returning 0 means, for the caller to print.
TOO_SLOW = 'this machine is too slow for real-time episodes; use lockstep'


@dataclass(frozen=True)
class RealtimeReport:
    """What :func:`measure` found for one checkpoint (times in ms, shares in cores)."""

    checkpoint: str
    model_type: str
    hop_s: float            # the budget of one hop [s]
    hops: int               # hops timed
    p50_ms: float           # wall time of the estimator's work per hop
    p99_ms: float
    max_ms: float
    cpu_p50_ms: float       # process CPU time of the estimator per hop
    cpu_p99_ms: float
    inference_cores: float  # estimator CPU seconds per second of audio
    scene_cores: float      # the scene's (``World.step``) share
    controller_cores: float  # slip-stop's share (inputs, step, command to the arm)
    threads: int            # torch threads

    @property
    def headroom(self) -> float:
        """The hop over the per-hop p99: 2 means twice as fast as real time needs."""
        return self.hop_s * 1e3 / self.p99_ms if self.p99_ms > 0 else math.inf

    @property
    def worker_cores(self) -> float:
        """Cores one demo worker's measured work needs (inference, scene, controller)."""
        return self.inference_cores + self.scene_cores + self.controller_cores

    @property
    def name(self) -> str:
        """The checkpoint's file name."""
        return Path(self.checkpoint).name

    def to_dict(self) -> dict:
        """The figures, with ``headroom`` and ``worker_cores``, for JSON."""
        return {**asdict(self), 'headroom': self.headroom, 'worker_cores': self.worker_cores}

    def text(self) -> str:
        """One line of figures."""
        return (f'{self.name}: {self.model_type}, per {self.hop_s * 1e3:g} ms hop p50 '
                f'{self.p50_ms:.2f} ms, p99 {self.p99_ms:.2f} ms, max {self.max_ms:.2f} ms '
                f'(headroom {self.headroom:.1f}x); inference {self.inference_cores:.2f} '
                f'cores, scene {self.scene_cores:.2f}, controller '
                f'{self.controller_cores:.3f} ({self.hops} hops)')


def default_checkpoints(root: Union[str, os.PathLike, None] = None) -> list:
    """Paths of :data:`DEFAULT_CHECKPOINTS`: in ``<root>/models`` (default: the working
    directory) when there, else in the installed ``share/aslip_ros/models``."""
    local = Path(root or '.') / 'models'
    if all((local / f).is_file() for f in DEFAULT_CHECKPOINTS):
        return [str(local / f) for f in DEFAULT_CHECKPOINTS]
    try:
        from ament_index_python.packages import get_package_share_directory
        share = Path(get_package_share_directory('aslip_ros')) / 'models'
    except Exception:   # no ROS environment, or the package is not installed
        share = None
    if share is not None and all((share / f).is_file() for f in DEFAULT_CHECKPOINTS):
        return [str(share / f) for f in DEFAULT_CHECKPOINTS]
    return [str(local / f) for f in DEFAULT_CHECKPOINTS]   # the error names these


def load(checkpoint: Union[str, os.PathLike]):
    """The checkpoint, or ValueError naming the path (missing, unreadable, not one)."""
    if not Path(checkpoint).is_file():      # before torch's import: seconds
        raise ValueError(f'no checkpoint at {checkpoint}')
    from aslip_ros.learn.checkpoint import load_checkpoint
    try:
        return load_checkpoint(checkpoint)
    except OSError as exc:
        text = f'cannot read checkpoint {checkpoint}: {exc.strerror}' if exc.strerror \
            else str(exc)
        raise ValueError(text) from None
    except ValueError as exc:
        raise ValueError(_first_sentence(str(exc))) from None


def _first_sentence(text: str) -> str:
    """A refusal as one line: torch's unpickling errors run over several."""
    line = text.strip().splitlines()[0] if text.strip() else text
    end = line.find('. ')
    return line[:end + 1] if end >= 0 else line


def _scene_layout(ckpt) -> str:
    """The scene layout whose channels are the checkpoint's (its ``layout`` first)."""
    from aslip_ros.scene.layouts import LAYOUTS
    names = list(ckpt.channel_names)
    named = ckpt.meta.get('layout')
    if named in LAYOUTS and LAYOUTS[named].channel_names == names:
        return named
    for key, layout in LAYOUTS.items():
        if layout.channel_names == names:
            return key
    raise ValueError(f'the checkpoint\'s channels {names} are those of no scene layout '
                     f'({", ".join(LAYOUTS)}): its audio cannot be simulated')


class _Episode:
    """The demo's slip-stop episode without the middleware: scene, estimator, controller."""

    def __init__(self, ckpt, hop_s: float, seed: int) -> None:
        from aslip_ros.control.slip_stop import SlipStop, SlipStopConfig
        from aslip_ros.hw.sources import world_metadata
        from aslip_ros.learn.inference.hybrid_estimator import open_estimator
        from aslip_ros.learn.inference.live import LiveConfig
        from aslip_ros.scene import scenarios
        from aslip_ros.scene.world import World
        self.layout = _scene_layout(ckpt)
        self.world = World(scenarios.wall_push(seed=seed, layout=self.layout,
                                               sample_rate=ckpt.sample_rate,
                                               wall_distance_m=0.0))
        self.world.arm.connect()
        self.world.arm.enable_velocity_mode()
        self.names = list(world_metadata(self.world)['channel_names'])
        direction = world_metadata(self.world)['task']['push_direction']
        self.task = SlipStop(SlipStopConfig(direction=direction))
        self.est = open_estimator(ckpt, LiveConfig(hop_s=hop_s))
        self.block_frames = max(1, int(round(hop_s * self.world.fs)))
        self.started = False

    def audio(self):
        """The scene's next block, as the estimator takes it."""
        c = self.world.step(self.block_frames)
        return AudioData(c.first_sample_index, int(round(c.t0 * NS_PER_S)), self.world.fs,
                         self.names, self.layout, 'sensor', c.audio)

    def infer(self, block) -> list:
        """The estimator's work for one block: its estimates."""
        estimates, job = self.est.accept(block)
        if job is not None:
            e = self.est.run(job)
            if e is not None:
                estimates.append(e)
        return estimates

    def control(self, estimates: list) -> None:
        """Slip-stop's work for one block (scene time is its clock)."""
        t, task = self.world.t, self.task
        task.on_tcp_pose(self.world.tcp_pose(), now=t)
        for e in estimates:
            task.on_slip(e.prediction.slipping, now=t,
                         angular_velocity=e.prediction.angular_velocity)
        if not self.started:
            task.start(now=t)
            self.started = True
        apply_command(self.world.arm, task.step(now=t))


def measure(checkpoint, duration_s: float = DEFAULT_DURATION_S, hop_s: float = 0.01,
            threads: int = DEFAULT_THREADS, seed: int = 0,
            on_start: Optional[Callable[[str], None]] = None,
            source: Optional[str] = None) -> RealtimeReport:
    """Time ``duration_s`` of the scene's audio through the live estimator of
    ``checkpoint`` (a path or a loaded :class:`~aslip_ros.learn.checkpoint.Checkpoint`),
    one ``hop_s`` block at a time, unpaced, with ``threads`` torch threads (restored after).

    ``on_start(name)`` is called just before the timed blocks (after loading, warm-up and
    the first window); ``source`` is the path the report names (default: ``checkpoint``
    when it is one). ValueError for an unusable checkpoint or argument.
    """
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f'duration must be positive, got {duration_s!r} s')
    if not (math.isfinite(hop_s) and 0.001 <= hop_s <= 0.1):
        raise ValueError(f'hop must be within 1 to 100 ms, got {hop_s!r} s')
    if int(threads) < 1:
        raise ValueError(f'threads must be at least 1, got {threads!r}')
    from aslip_ros.learn.checkpoint import Checkpoint
    ckpt = checkpoint if isinstance(checkpoint, Checkpoint) else load(checkpoint)
    if source is None:
        source = '<checkpoint>' if isinstance(checkpoint, Checkpoint) else str(checkpoint)
    import torch
    before = torch.get_num_threads()
    torch.set_num_threads(int(threads))
    try:
        ep = _Episode(ckpt, hop_s, seed)
        _preroll(ep)
        if on_start is not None:
            on_start(Path(source).name)
        figures = _timed_blocks(ep, max(1, int(round(duration_s / hop_s))))
    finally:
        torch.set_num_threads(before)
    return RealtimeReport(str(source), ckpt.model_type, float(hop_s), threads=int(threads),
                          **figures)


def _preroll(ep: _Episode) -> None:
    """Feed blocks, untimed, until the estimator gives its first hop, then a few more."""
    limit = 10 * int(math.ceil(ep.est.predictor.sample_rate / ep.block_frames))  # 10 s
    for _ in range(limit):
        block = ep.audio()
        _, job = ep.est.accept(block)
        if job is not None:
            ep.est.run(job)
            break
        if ep.est.stats.estimates:
            break
    else:
        raise ValueError(f'no estimate after {limit} blocks of scene audio: '
                         f'{ep.est.stats.refusal or dict(ep.est.stats.drops)}')
    for _ in range(_PREROLL_BLOCKS):
        ep.control(ep.infer(ep.audio()))


def _timed_blocks(ep: _Episode, n: int) -> dict:
    """Run ``n`` blocks; the per-hop figures and the shares in cores."""
    wall, cpu = np.empty(n), np.empty(n)
    scene_cpu = ctl_cpu = 0.0
    clock, cpu_clock = time.perf_counter, time.process_time
    for i in range(n):
        c0 = cpu_clock()
        block = ep.audio()
        c1, w1 = cpu_clock(), clock()
        estimates = ep.infer(block)
        w2, c2 = clock(), cpu_clock()
        ep.control(estimates)
        c3 = cpu_clock()
        wall[i], cpu[i] = w2 - w1, c2 - c1
        scene_cpu += c1 - c0
        ctl_cpu += c3 - c2
    audio_s = n * ep.block_frames / ep.world.fs
    q50, q99 = np.percentile(wall, [50.0, 99.0]) * 1e3
    return {'hops': n, 'p50_ms': float(q50), 'p99_ms': float(q99),
            'max_ms': float(wall.max() * 1e3),
            'cpu_p50_ms': float(np.percentile(cpu, 50.0) * 1e3),
            'cpu_p99_ms': float(np.percentile(cpu, 99.0) * 1e3),
            'inference_cores': float(cpu.sum() / audio_s),
            'scene_cores': scene_cpu / audio_s, 'controller_cores': ctl_cpu / audio_s}


def verdict(reports: Union[RealtimeReport, Sequence[RealtimeReport]],
            margin: float = DEFAULT_MARGIN,
            max_cores: float = DEFAULT_MAX_CORES) -> Verdict:
    """OK when every report's p99 per hop is at most ``margin`` of the hop and its inference
    needs at most ``max_cores``; each failure names the checkpoint and the figure. A note
    says when the p99 is mostly waiting (wall time well over CPU time): the machine is busy
    or the process throttled, not the model slow."""
    if not (math.isfinite(margin) and margin > 0):
        raise ValueError(f'margin must be positive, got {margin!r}')
    if not (math.isfinite(max_cores) and max_cores > 0):
        raise ValueError(f'max cores must be positive, got {max_cores!r}')
    v = Verdict()
    for r in _as_list(reports):
        for problem in model_problems(r, margin, max_cores):
            v.fail(f'{r.name}: {problem}')
        if r.p99_ms > WAITING_FACTOR * r.cpu_p99_ms + 1.0:
            v.notes.append(f'{r.name}: p99 {r.p99_ms:.2f} ms of wall time against '
                           f'{r.cpu_p99_ms:.2f} ms of CPU time per hop: the process waited '
                           'for a core (other load, a CPU quota, a throttled container)')
    return v


def model_problems(report: RealtimeReport, margin: float = DEFAULT_MARGIN,
                   max_cores: float = DEFAULT_MAX_CORES) -> list:
    """Why one checkpoint does not keep up with margin (empty when it does)."""
    out = []
    budget_ms = margin * report.hop_s * 1e3
    if not report.p99_ms <= budget_ms:
        out.append(f'p99 {report.p99_ms:.2f} ms per hop is over {budget_ms:.2f} ms '
                   f'({margin:g} of the {report.hop_s * 1e3:g} ms hop)')
    if not report.inference_cores <= max_cores:
        out.append(f'needs {report.inference_cores:.2f} cores, over {max_cores:g}')
    return out


def model_line(report: RealtimeReport, margin: float = DEFAULT_MARGIN,
               max_cores: float = DEFAULT_MAX_CORES) -> str:
    """``<file>: OK (headroom 3.1x)`` or ``<file>: FAIL: <reasons>``: one checkpoint's
    verdict."""
    problems = model_problems(report, margin, max_cores)
    if problems:
        return f'{report.name}: FAIL: ' + '; '.join(problems)
    return f'{report.name}: OK (headroom {report.headroom:.1f}x)'


def demo_workers(reports: Union[RealtimeReport, Iterable[RealtimeReport]],
                 cores: Optional[int] = None, budget: float = DEFAULT_WORKER_BUDGET,
                 middleware_cores: float = DEFAULT_MIDDLEWARE_CORES) -> int:
    """How many real-time demo workers (one closed-loop episode each: scene, inference,
    controller, middleware, in one process) this machine carries: 0 when it is too slow
    (:data:`TOO_SLOW`).

    Each worker needs the heaviest report's ``worker_cores`` plus ``middleware_cores``;
    together they stay within ``budget`` of ``cores`` (default ``os.cpu_count()``). A model
    whose p99 per hop exceeds the hop cannot keep real time however few workers run: 0.
    """
    items = _as_list(reports)
    if not items:
        raise ValueError('demo_workers needs at least one report')
    if not (0 < budget <= 1):
        raise ValueError(f'budget must be in (0, 1], got {budget!r}')
    if not (math.isfinite(middleware_cores) and middleware_cores >= 0):
        raise ValueError(f'middleware_cores must be >= 0, got {middleware_cores!r}')
    n_cores = (os.cpu_count() or 1) if cores is None else int(cores)
    if any(not r.headroom >= 1.0 for r in items):
        return 0
    per_worker = max(r.worker_cores for r in items) + middleware_cores
    if not per_worker > 0:
        return max(0, n_cores)
    return max(0, int(math.floor(budget * n_cores / per_worker + 1e-9)))


def workers_line(n: int, reports: Union[RealtimeReport, Iterable[RealtimeReport]],
                 cores: Optional[int] = None,
                 middleware_cores: float = DEFAULT_MIDDLEWARE_CORES) -> str:
    """The sentence about :func:`demo_workers`' answer ``n``."""
    items = _as_list(reports)
    n_cores = (os.cpu_count() or 1) if cores is None else int(cores)
    if n <= 0:
        return f'demo workers: 0: {TOO_SLOW}'
    per = max(r.worker_cores for r in items) + middleware_cores
    return (f'demo workers: {n} real-time worker{"s" if n != 1 else ""} on {n_cores} '
            f'CPUs ({per:.2f} cores each, {middleware_cores:g} of them middleware, '
            f'estimated)')


def _as_list(reports) -> list:
    return [reports] if isinstance(reports, RealtimeReport) else list(reports)
