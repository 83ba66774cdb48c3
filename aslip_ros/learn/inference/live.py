"""The live slip estimator: audio blocks in, slip estimates out, for every checkpoint.

    est = LiveEstimator(load_predictor("model.pt"), LiveConfig(hop_s=0.01))
    for e in est.feed(block):          # block: ``audio_frame.AudioData`` (or alike)
        publish(e.stamp_ns, e.prediction, e.direction_sigma)

One object owns everything between an audio block and an estimate, for window models (CNN,
SVM, registered ones) and streaming ones (``aslip_stream``) alike:

- the stream's fit to the checkpoint (channel names, rate: refused, counted, not crashed);
- the continuity gate (``audio_window.StreamGate``): repeated or out-of-order blocks are
  dropped; a gap, a time jump or a new stream restarts the window, the per-grasp
  calibration and the recurrent state;
- window models: the ring buffer of the newest ``window_samples``, the hop, the per-grasp
  calibration state (fed every accepted block; each window is normalised with the state
  as of its last block) and ``UNCONVERGED_DIRECTION_SIGMA`` until it converges;
- the dead-microphone check (``channel_check``): no estimate for such audio;
- the decision threshold (the predictor's, ``set_threshold``);
- counters of all of it (``stats``) and the events a user should hear of (``events``).

Each estimate's ``prediction`` carries the rotational slip rate (``angular_velocity``, raw,
not gated by the planar ``slipping``, and ``angular_sigma``) for a checkpoint with a
rotational output, 0.0 / -1 for any other; an estimate with a non-finite rate is withheld
like any non-finite estimate.

``slip_inference`` only decodes messages into blocks, hands ``accept``'s window job to its
model thread (``run``) and publishes; evaluation and the closed-loop demo call ``feed``,
which runs the job at once, so what is measured offline is what runs live.

Per hop, the window of a model that reads log-mel (the CNN, an SVM on log-mel, a
``per_output`` model with such a part) reuses the log-mel frames it shares with the windows
before it (``features.SlidingLogMel``: equal to the backend's ``LogMel`` of the whole
window, which training uses, to float rounding; tested on scene audio): a job carries where
its window lies in the stream since the window last restarted (``Job.start``,
``Job.epoch``), and ``run`` computes only the frames no earlier window held, plus the first,
which reads the zeros before the window. Other window models featurise each window whole.

Timing (for the callers' tail-latency figures; nothing here changes a result): ``run`` and
a streaming ``accept`` leave the model's share of their time in ``last_forward_s`` and, for
``run``, the rest (dead-channel check, log-mel features, calibration offsets) in
``last_features_s``. The split comes from timing the log-mel features (the sliding ones, or
the backend's log-mel call) and the streaming stepper's ``step`` (``_Timed``): a window
model without a log-mel call counts its features as forward.
"""

from __future__ import annotations

import collections
import math
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from aslip_ros.learn.checkpoint import Checkpoint, load_checkpoint
from aslip_ros.learn.features import LogMel, SlidingLogMel
from aslip_ros.learn.inference.audio_window import RingBuffer, StreamGate
from aslip_ros.learn.inference.channel_check import DEAD_MARGIN_DB, dead_channels
from aslip_ros.learn.inference.predictor import BatchPrediction, Prediction, Predictor
from aslip_ros.learn.inference.stream_predictor import DEFAULT_MAX_TIME_JUMP_S, StreamingPredictor
from aslip_ros.learn.models.registry import HYBRID, PER_OUTPUT, model_backend

#: direction_sigma [rad] while the per-grasp calibration has not converged: uninformative.
UNCONVERGED_DIRECTION_SIGMA = float(np.pi)


def load_predictor(checkpoint: str | os.PathLike | Checkpoint, threshold: float | None = None,
                   max_time_jump_s: float = DEFAULT_MAX_TIME_JUMP_S):
    """The predictor of a checkpoint (a path or one loaded): a ``StreamingPredictor`` when
    the registry says its model streams, else a window ``Predictor``. OSError / ValueError
    when unusable."""
    ckpt = checkpoint if isinstance(checkpoint, Checkpoint) else load_checkpoint(checkpoint)
    if ckpt.model_type == HYBRID:
        raise ValueError(f"an {HYBRID} checkpoint runs two models side by side, live only "
                         "(slip_inference; learn.inference.hybrid_estimator.open_estimator): "
                         "evaluate its parts, the --stream and --window checkpoints of "
                         "aslip hybrid")
    if model_backend(ckpt.model_type).streaming:
        return StreamingPredictor(ckpt, threshold, max_time_jump_s)
    return Predictor(ckpt, threshold)


@dataclass(frozen=True)
class LiveConfig:
    """How the live estimator runs a checkpoint (``slip_inference``'s parameters)."""

    #: window models: run the model every ``hop_s`` of new audio [s] (streaming: the
    #: checkpoint's hop)
    hop_s: float = 0.01
    #: a stamp this far off its sample index is a time jump [s]
    max_time_jump_s: float = DEFAULT_MAX_TIME_JUMP_S
    #: withhold the estimate when a channel is this far below the median of the others or
    #: digitally silent [dB]; 0: no check
    dead_channel_margin_db: float = DEAD_MARGIN_DB


@dataclass(frozen=True)
class Estimate:
    """One estimate as it goes out: the instant it describes and what it says."""

    stamp_ns: int
    prediction: Prediction
    direction_sigma: float      # [rad]: pi until the per-grasp calibration converged
    raw_velocity: tuple[float, float] = (0.0, 0.0)      # ungated, for evaluation


@dataclass(frozen=True)
class Job:
    """A window due for a window model: run it with ``LiveEstimator.run``."""

    window: np.ndarray            # (window_samples, C) float32, owned by the job
    stamp_ns: int                 # end of the window
    offsets: Optional[np.ndarray]  # per-grasp calibration as of the window's end
    converged: bool
    #: the window's first sample, counted from the window's last restart (None: unknown,
    #: the window is featurised whole)
    start: Optional[int] = None
    epoch: int = 0                 # which restart ``start`` counts from


@dataclass
class Stats:
    """What the estimator counts about its input and output."""

    drops: collections.Counter = field(default_factory=collections.Counter)  # per reason
    blocks_ok: int = 0
    frames_lost: int = 0
    gaps: int = 0
    stream_restarts: int = 0
    estimates: int = 0
    dead_windows: int = 0                 # windows (blocks, streaming) withheld: dead channel
    hops_superseded: int = 0              # jobs replaced before they ran (the node counts)
    refusal: str = ""                     # why the current stream is refused ("" when not)
    dead_recent: set = field(default_factory=set)   # dead channels since last collected


#: Kinds of ``events``: ``drop`` (a block dropped, ``reason`` says why), ``refuse`` (the
#: stream does not fit the checkpoint), ``restart`` (window, calibration and state start
#: again: gap, time jump, new stream, request), ``converged`` (the per-grasp calibration),
#: ``untrusted`` (the calibration's self-check says its estimate cannot be trusted: the
#: background is not common mode; once per grasp, ``detail`` gives the figures), ``dead``
#: (channels named in ``detail``; no estimate) and ``bad_estimate``.
EVENT_KINDS = ("drop", "refuse", "restart", "converged", "untrusted", "dead", "bad_estimate")


@dataclass(frozen=True)
class Event:
    kind: str
    reason: str
    detail: str = ""


class _Timed:
    """A callable that adds the time of each call to ``seconds`` (timing only: arguments,
    result and attributes are the wrapped one's)."""

    def __init__(self, fn: Any) -> None:
        self._fn = fn
        self.seconds = 0.0

    def __call__(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return self._fn(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - t0

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fn, name)

    def take(self) -> float:
        out, self.seconds = self.seconds, 0.0
        return out


def _sliding_features(predictor: Any) -> Optional[SlidingLogMel]:
    """The sliding log-mel of the windows of a model that reads log-mel (a backend whose
    ``reads_logmel`` says its ``predict`` is its ``infer_features`` of ``logmel`` less the
    offsets: the CNN, an SVM on log-mel), or of a ``per_output`` one with such a part (its
    ``predict_with_features``); None for any other model."""
    backend = getattr(predictor, "backend", None)
    logmel = getattr(backend, "logmel", None)
    if not isinstance(logmel, LogMel):
        return None
    if getattr(backend, "reads_logmel", False) and hasattr(backend, "infer_features") or \
            predictor.model_type == PER_OUTPUT and hasattr(backend, "predict_with_features"):
        return SlidingLogMel(logmel, predictor.window_samples)
    return None


def _time_model(predictor: Any, streaming: bool) -> Optional[_Timed]:
    """Wrap the model's own compute (the stepper of a streaming predictor; a window
    backend's log-mel features) so its time can be told from the rest."""
    if streaming:
        stepper = getattr(predictor, "stepper", None)
        if stepper is None:
            return None
        stepper.step = _Timed(stepper.step)
        return stepper.step
    backend = getattr(predictor, "backend", None)
    if isinstance(getattr(backend, "logmel", None), LogMel):
        backend.logmel = _Timed(backend.logmel)
        return backend.logmel
    return None


class LiveEstimator:
    """Slip estimates from a live stream of audio blocks (see the module docstring)."""

    def __init__(self, predictor: Any, config: LiveConfig = LiveConfig()) -> None:
        self.predictor = predictor
        self.config = config
        self.streaming = bool(model_backend(predictor.model_type).streaming)
        self.gate = StreamGate(config.max_time_jump_s)
        self.ring = None if self.streaming else RingBuffer(predictor.window_samples,
                                                           predictor.n_channels)
        self.hop_frames = 1
        self.set_hop(config.hop_s)
        self.dead_margin_db = float(config.dead_channel_margin_db)
        self.stats = Stats()
        self.events: list[Event] = []      # since the caller last took them (``take_events``)
        # ``accept`` (the audio thread) and ``run`` (a model thread) share the bookkeeping.
        self._lock = threading.RLock()
        self._since_hop = 0
        self._pushed = 0                   # samples into the window since its last restart
        self._epoch = 0                    # window restarts so far
        self._announced_converged = False
        self._announced_untrusted = False
        #: Timing of the last ``run`` (window models) or streaming block [s]: see the module
        #: docstring. Each is written and read on the thread that runs the model.
        self.last_features_s = 0.0
        self.last_forward_s = 0.0
        self._sliding = None if self.streaming else _sliding_features(predictor)
        self._sliding_lock = threading.Lock()
        self._timed = _time_model(predictor, self.streaming)
        if self.streaming:
            predictor.warm_up()
        else:
            for _ in range(3):     # the first torch calls are slow: keep them out of the stream
                predictor.predict(np.zeros((predictor.window_samples, predictor.n_channels),
                                           np.float32))

    @classmethod
    def from_checkpoint(cls, checkpoint: str | os.PathLike | Checkpoint,
                        config: LiveConfig = LiveConfig(),
                        threshold: float | None = None) -> "LiveEstimator":
        return cls(load_predictor(checkpoint, threshold, config.max_time_jump_s), config)

    # --- settings -------------------------------------------------------------------------
    @property
    def runs_windows(self) -> bool:
        """Whether ``accept`` hands out window jobs for ``run`` (a caller's model thread)."""
        return not self.streaming

    def set_hop(self, hop_s: float) -> None:
        self.hop_frames = max(1, int(round(hop_s * self.predictor.sample_rate)))

    def set_max_time_jump(self, seconds: float) -> None:
        self.gate.max_time_jump_ns = int(seconds * 1e9)

    def set_threshold(self, threshold: float | None) -> float:
        """The decision threshold (None: the checkpoint's); ValueError outside [0, 1]."""
        return self.predictor.set_threshold(threshold)

    @property
    def threshold(self) -> float:
        return self.predictor.threshold

    # --- what the caller hears of ---------------------------------------------------------
    @property
    def has_events(self) -> bool:
        """Whether events wait to be taken (a peek without the lock: one appended meanwhile
        is taken by the next ``take_events``)."""
        return bool(self.events)

    def take_events(self) -> list[Event]:
        with self._lock:
            out, self.events = self.events, []
        return out

    def _event(self, kind: str, reason: str, detail: str = "") -> None:
        self.events.append(Event(kind, reason, detail))

    def report(self) -> dict:
        """A consistent copy of the counters for diagnostics (thread-safe): ``values`` by
        name, ``drops`` by reason, the ``dead`` channels seen since the last report (then
        forgotten), the current ``refusal`` and the calibration ``summary`` (or None)."""
        with self._lock:
            st = self.stats
            dead = [n for n in self.predictor.channel_names if n in st.dead_recent]
            st.dead_recent.clear()
            values = {"blocks_accepted": st.blocks_ok, "blocks_dropped": sum(st.drops.values()),
                      "gaps": st.gaps, "stream_restarts": st.stream_restarts,
                      "frames_lost": st.frames_lost, "hops_superseded": st.hops_superseded,
                      "dead_channel_windows": st.dead_windows, "threshold": self.threshold}
            if self.streaming:
                values.update(stream_resets=self.predictor.resets,
                              last_reset_reason=self.predictor.last_reset_reason)
            return {"values": values, "drops": dict(st.drops), "dead": dead,
                    "refusal": st.refusal, "summary": self.predictor.calibration_summary()}

    def count_superseded(self) -> None:
        """A caller's waiting window was replaced by a newer one before the model ran it."""
        with self._lock:
            self.stats.hops_superseded += 1

    @property
    def calibrated(self) -> bool:
        return bool(self.predictor.calibrated)

    @property
    def calibration_converged(self) -> bool:
        return self.calibrated and bool(self.predictor.calibration_converged)

    @property
    def calibration_trusted(self) -> Optional[bool]:
        """The calibration's self-check: False when its estimate cannot be trusted, True when
        it can, None when not known (no calibration, not converged, no threshold)."""
        return self.predictor.calibration_trusted if self.calibrated else None

    # --- input ----------------------------------------------------------------------------
    def drop(self, reason: str, detail: str) -> None:
        """Count a block the caller could not decode, or that ``accept`` refused; a streaming
        state forgets its audio (the next block follows a hole)."""
        with self._lock:
            self._drop(reason, detail)

    def _drop(self, reason: str, detail: str) -> None:
        if self.streaming and reason not in ("repeated", "out_of_order", "time_jump"):
            self._reset_stream(f"dropped block ({reason})")
        self.stats.drops[reason] += 1
        self._event("drop", reason, detail)

    def restart(self, reason: str) -> None:
        """The stream is not continuous here: a new window, a new per-grasp calibration, a
        fresh recurrent state."""
        with self._lock:
            self._restart(reason)

    def new_grasp(self, reason: str) -> bool:
        """A new grasp (``slip_inference``'s ``~/recalibrate``): the per-grasp calibration
        starts again from zero gain, the window runs on. False without a calibration."""
        with self._lock:
            if not self.calibrated:
                return False
            self.predictor.reset_calibration()
            self._announced_converged = False
            self._announced_untrusted = False
            self._event("restart", reason)
            return True

    def _restart(self, reason: str) -> None:
        if self.streaming:
            self._reset_stream(reason)        # features, state and calibration
        else:
            self.ring.reset()
            self.predictor.reset_calibration()
            self._since_hop = 0
            self._pushed = 0
            self._epoch += 1
        self._announced_converged = False
        self._announced_untrusted = False
        self._event("restart", reason)

    def _reset_stream(self, reason: str) -> None:
        if not self.predictor.fresh:          # a reset with nothing fed since is no reset
            self.predictor.reset(reason)

    def _refuse(self, reason: str, detail: str) -> None:
        self.stats.refusal = detail
        if self.streaming:
            self._reset_stream(f"refused stream ({reason})")
        self.stats.drops[reason] += 1
        self._event("refuse", reason, detail)

    def accept(self, a) -> tuple[list[Estimate], Optional[Job]]:
        """Take one decoded block: the estimates it completes (streaming) and the window
        due for the model (window models; None when no hop is due). What else happened is
        in ``events`` and ``stats``."""
        pr = self.predictor
        if list(a.channel_names) != list(pr.channel_names):
            self._refuse("channels", f"stream channels {list(a.channel_names)} do not match "
                                     f"the checkpoint's {pr.channel_names}")
            return [], None
        try:
            pr.check_stream(a.sample_rate, a.channel_names)
        except ValueError as exc:
            self._refuse("sample_rate", str(exc))
            return [], None
        block = np.asarray(a.block)
        if block.shape != (a.frames, pr.n_channels) or not np.isfinite(block).all():
            self._drop("non_finite" if block.shape == (a.frames, pr.n_channels) else "ragged",
                       f"block shaped {block.shape}, {a.frames} frames expected, or not finite")
            return [], None
        verdict, detail = self.gate.check(a)
        if verdict in ("repeated", "out_of_order"):
            self._drop(verdict, detail)
            return [], None
        if verdict == "time_jump":
            # Re-anchor on this block so a real clock step costs one window, not the stream.
            self._drop(verdict, detail)
            self.gate.accept(a)
            self._restart(f"time jump: {detail}")
            return [], None
        if verdict == "new_stream":
            self.stats.stream_restarts += 1
            self._restart(f"new stream: {detail}")
        elif verdict == "gap":
            self.stats.gaps += 1
            self.stats.frames_lost += a.first_sample_index - self.gate.next_index
            self._restart(f"gap: {detail}")
        self.gate.accept(a)
        self.stats.blocks_ok += 1
        self.stats.refusal = ""
        if self.streaming:
            return self._stream_block(a), None
        return [], self._window_block(a)

    def _window_block(self, a) -> Optional[Job]:
        pr = self.predictor
        self.ring.push(a.block)
        pr.push_audio(a.block)
        self._note_convergence()
        self._since_hop += a.frames
        self._pushed += a.frames
        if self.ring.filled < self.ring.length or self._since_hop < self.hop_frames:
            return None
        # Several hops inside one block: one estimate on the newest window is what matters.
        self._since_hop %= self.hop_frames
        return Job(self.ring.window().copy(), int(a.end_stamp_ns), pr.calibration_offsets(),
                   self.calibration_converged, self._pushed - self.ring.length, self._epoch)

    def _dead(self, audio: np.ndarray) -> list[str]:
        margin = self.dead_margin_db
        dead = dead_channels(audio, self.predictor.channel_names, margin) if margin > 0 else []
        if dead:
            self._count_dead(dead)
        return dead

    def _count_dead(self, dead: list[str]) -> None:
        self.stats.dead_windows += 1
        self.stats.dead_recent.update(dead)
        self._event("dead", "dead", ", ".join(dead))

    def _stream_block(self, a) -> list[Estimate]:
        """Every hop the block completes. A block with a dead channel gives none and resets
        the state: a state that has read a dead microphone would under-report slip for an
        unknown time after the microphone came back."""
        if self._timed is not None:
            self._timed.take()
        self.last_forward_s = 0.0
        if self._dead(np.asarray(a.block)):
            self._reset_stream("dead channel(s)")
            return []
        out = []
        feed = self.predictor.feed(a)
        if self._timed is not None:
            self.last_forward_s = self._timed.take()
        for est in feed:
            e = est.prediction
            if not _finite(e):
                self._reset_stream("non-finite estimate")
                self.stats.drops["bad_estimate"] += 1
                self._event("bad_estimate", "bad_estimate", f"non-finite estimate {e}")
                return out
            sigma = UNCONVERGED_DIRECTION_SIGMA \
                if self.calibrated and not self.calibration_converged else e.direction_sigma
            out.append(Estimate(est.stamp_ns, e, sigma, est.raw_velocity))
        self._note_convergence()
        self.stats.estimates += len(out)
        return out

    def _note_convergence(self) -> None:
        if not self.calibrated or not self.predictor.calibration_converged:
            return
        if not self._announced_converged:
            self._announced_converged = True
            self._event("converged", "converged")
        # The self-check, once per grasp (a cached statistic: a comparison per block).
        if not self._announced_untrusted and self.predictor.calibration_trusted is False:
            self._announced_untrusted = True
            s = self.predictor.calibration_summary()
            self._event("untrusted", "untrusted",
                        f"spread {s['calibration_spread_db']:.2f} dB above "
                        f"{s['calibration_trust_spread_db']:.2f} dB")

    # --- the model ------------------------------------------------------------------------
    def run(self, job: Job) -> Optional[Estimate]:
        """A window through the model (a thread of the caller's may do this): the estimate,
        or None when withheld (dead channel, non-finite output: see ``events``)."""
        t0 = time.perf_counter()
        if self._timed is not None:
            self._timed.take()
        margin = self.dead_margin_db
        dead = dead_channels(job.window, self.predictor.channel_names, margin) \
            if margin > 0 else []
        t1 = time.perf_counter()
        problem, pred, features, raw = "", None, 0.0, (0.0, 0.0)
        if not dead:
            try:
                batch, features = self._predict(job)
                pred = batch[0]
                raw = (float(batch.raw_velocity[0, 0]), float(batch.raw_velocity[0, 1]))
            except ValueError as exc:
                problem = str(exc)
            if pred is not None and not _finite(pred):
                problem = f"non-finite estimate {pred}"
        features += self._timed.take() if self._timed is not None else 0.0
        self.last_features_s = t1 - t0 + features
        self.last_forward_s = time.perf_counter() - t1 - features
        with self._lock:
            if dead:
                self._count_dead(dead)
                return None
            if problem:
                self.stats.drops["bad_estimate"] += 1
                self._event("bad_estimate", "bad_estimate", problem)
                return None
            self.stats.estimates += 1
        sigma = UNCONVERGED_DIRECTION_SIGMA if job.offsets is not None and not job.converged \
            else pred.direction_sigma
        return Estimate(job.stamp_ns, pred, sigma, raw)

    def _predict(self, job: Job) -> tuple[BatchPrediction, float]:
        """The model's estimate of ``job`` (a batch of one, with its ungated velocity) and the
        seconds its sliding features took (0.0 when the backend featurised the window
        itself)."""
        if self._sliding is None or job.start is None:
            offsets = None if job.offsets is None else np.asarray(job.offsets)[None]
            return self.predictor.predict_batch(job.window[None], offsets=offsets), 0.0
        t0 = time.perf_counter()
        with self._sliding_lock:
            feats = self._sliding(job.window, job.start, job.epoch)
        t1 = time.perf_counter()
        offsets = None if job.offsets is None else np.asarray(job.offsets)[None]
        if self.predictor.model_type == PER_OUTPUT:
            return self.predictor.predict_window_features(job.window[None], feats[None],
                                                          offsets), t1 - t0
        return self.predictor.predict_features(feats[None], offsets), t1 - t0

    def feed(self, a) -> list[Estimate]:
        """``accept`` and, for a window model, ``run`` at once: every estimate of the block."""
        out, job = self.accept(a)
        if job is not None:
            est = self.run(job)
            if est is not None:
                out.append(est)
        return out


def _finite(p: Prediction) -> bool:
    return all(math.isfinite(v) for v in (p.probability, p.vx, p.vz, p.threshold,
                                          p.direction_sigma, p.angular_velocity,
                                          p.angular_sigma))
