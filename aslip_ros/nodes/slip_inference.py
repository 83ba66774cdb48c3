"""``slip_inference``: AudioFrame stream -> model -> SlipVector at the hop rate.

The node translates: AudioFrame messages into blocks for the core's live estimator
(``aslip_ros.learn.inference.live.LiveEstimator``, which owns the gate, the window, the
per-grasp calibration, the dead-channel check and the threshold: what follows describes it),
its estimates into SlipVector and rviz markers, its events into log lines, its counters
into diagnostics, and its parameters (``LiveConfig``'s defaults) into ROS parameters.

A ring buffer per channel holds the newest ``window_samples`` of the stream. Every
``hop_s`` of new audio the checkpoint's model (CNN or SVM, from the checkpoint) runs on the
latest full window; the estimate goes out on ``/aslip/slip`` stamped with the END of the
window, plus an rviz marker.

Every incoming frame passes a gate first. A frame is dropped (counted per reason in the
diagnostics, with a throttled warning) when it is empty or ragged, holds NaN/Inf or samples
beyond full scale, does not match the checkpoint (channel count or names, sample rate: the
node refuses such a stream with a clear error), repeats or goes back in sample index, or
jumps in time against its sample index. A forward gap in the sample index (blocks lost
upstream) is counted and restarts the window: a window spliced across a gap is not what the
model was trained on. A source that restarts (its index back at 0, or leaping far ahead,
while its stamps run on) is a new stream: counted, and the window restarts on it at once
(``learn.inference.audio_window.StreamGate``). Nothing that arrives can crash the node or put
NaN on ``/aslip/slip``.

Dead microphones: before the model runs, each window is checked for a channel that looks
dead or disconnected (``learn.inference.channel_check.dead_channels``: digital silence, or
more than ``dead_channel_margin_db`` below the median of the other channels). A model fed such a
window under-reports slip, so no SlipVector goes out for it: the controllers' stale-input
watchdogs then hold the arm still. Each such window is counted, a throttled error names
the channels, and the diagnostics go to ERROR naming them while it lasts.

Per-grasp calibration (a checkpoint with ``calibration``, docs/model.md): every accepted
block feeds the predictor's calibration state; each hop's window goes to the model with
the offsets the state had when the window's last block arrived, so the estimate equals the
offline computation over the same stream. A gap, a time jump or a new stream starts a new
grasp (the state resets with the window), and so does the ``~/recalibrate`` service
(std_srvs/Trigger). Until the state has converged, ``direction_sigma`` is
``UNCONVERGED_DIRECTION_SIGMA`` (pi: the direction may be anywhere); after it, and for
checkpoints without calibration, the predictor's calibrated one-sigma direction error for
the estimate's speed (``learn.calibration.output``; -1 when the checkpoint has no sigma
model, as older ones; a message that is not slipping carries -1). ``/diagnostics`` shows
``calibration_converged``, ``calibration_accepted_frames``, ``calibration_frames``,
``calibration_resets``, ``gain_db_<channel>`` and the calibration's self-check:
``calibration_spread_db`` and, once converged (with a checkpoint whose constants carry the
check's threshold), ``calibration_trusted``; an estimate it does not trust (a background
that is not common mode: docs/model.md) turns the diagnostics to WARN and is logged. Every
new grasp, every convergence and every untrusted estimate (once per grasp) is also announced
on the latched ``/aslip/calibration`` (std_msgs/String, JSON: ``calibrated``, ``grasp``,
``converged``, ``trusted``, ``reason``, ``stamp_s``), which the controllers report to the
user.

Timing: the model runs on a thread of its own, never inside the audio callback, so a slow
forward pass cannot hold up the audio subscription (which would overflow its best-effort
queue and cost a window restart). When a hop is due the callback copies the newest window
into a pre-allocated buffer and wakes the thread; if the thread is still busy, the newer
window replaces the waiting one (counted as ``hops_superseded``: the freshest estimate is
what a controller needs). torch runs with ``torch_threads`` (1) and the model is warmed up
(the first calls pay torch's lazy initialisation) before the node subscribes to audio, so
the first published estimates already come at the hop rate.

Streaming checkpoints (``aslip_stream``): no window nor model thread, a
SlipVector per 10 ms hop, state resets in ``stream_resets`` and ``last_reset_reason``.
Hybrid checkpoints (``aslip_hybrid``, ``learn.inference.hybrid_estimator``): both. The stream
part publishes a SlipVector per hop from the audio callback, and each takes the outputs
the checkpoint gives the window part from the newest window the model thread has finished
(``hops_with_window`` counts them); the window part's estimates are not published alone.

Falling behind (a machine too slow or too busy for the stream): the node degrades, it does
not stall. A window model's waiting window is replaced by a newer one (``hops_superseded``
above). A streaming model processes every block in the audio callback, so a backlog would
make every later estimate later still: a block that reaches the node more than
``max_lag_s`` later than the stream's usual delay (``aslip_ros.lag.LagMeter``: its stamps
against this host's clock, where they are on it) is skipped instead, counted in
``hops_skipped_behind`` (and ``dropped_behind``, with a throttled warning), and the stream
restarts on the first block that is on time. A lag that outlasts ``STEP_AFTER_S`` (0.25 s)
is no backlog but a step of the source's clock: the usual delay starts again there
(``lag_clock_steps``, with a throttled warning; ``aslip_ros.lag``), so a source whose stamps
fall behind once is not skipped for the meter's whole window. Every estimate keeps the stamp
of the audio it was computed from, so a controller judges its age truthfully. On simulated time
(``use_sim_time``, lockstep) nothing is behind and nothing is skipped.

Latency in the diagnostics, over the newest ``TIMING_SAMPLES`` published estimates (a
streaming block that completes several hops counts once), each as ``_p50_ms``,
``_p99_ms``, ``_p999_ms`` (p99.9) and ``_max_ms``: ``latency_*``, the audio callback's
start to the SlipVector published; ``input_age_*``, the block's age when its callback
starts (wall clock against the end stamp: the source's, the transport's and the executor's
delay together, meaningful when the source stamps with this host's clock, as
``audio_capture`` does; rclpy's EventsExecutor gives no reception time); and the live path
step by step, ``step_queue_*`` (a window model's block from the hand-over to the model
thread's start; 0 for a streaming model, processed in the callback), ``step_features_*``
(decode, gate, ring buffer, per-grasp calibration, dead-channel check, log-mel features),
``step_forward_*`` (the model) and ``step_publish_*`` (SlipVector and marker, and the event
log). The times go into a preallocated array (no allocation per block); the percentiles are
computed once per diagnostics period.
"""

from __future__ import annotations

import collections
import gc
import json
import threading
import time
from typing import NamedTuple, Optional

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from aslip_ros import topics
from aslip_ros.lag import STEP_AFTER_S, LagMeter
from aslip_ros.learn.inference.hybrid_estimator import open_estimator
from aslip_ros.learn.inference.live import Estimate, Job, LiveConfig
from aslip_ros.msg import AudioFrame, SlipVector
from aslip_ros.nodes import common as c
from aslip_ros.runtime.process import ConfigError, ready, run_node
from aslip_ros.runtime.qos import AUDIO_QOS, LATCHED_QOS, MARKER_QOS, RELIABLE_QOS
from aslip_ros.nodes import convert

#: Estimates the latency figures are computed over: 60 s at the 100 Hz hop rate, so p99.9
#: rests on the 6 slowest of them rather than on the single maximum.
TIMING_SAMPLES = 6000
#: How often the node asks the graph whether anyone shows its rviz markers [s] (a new
#: subscriber gets them within this).
MARKER_SUBSCRIBERS_S = 1.0
#: The diagnostics' names of the timed figures (``<name>_p50_ms`` ...; module docstring).
TIMED = ("input_age", "step_queue", "step_features", "step_forward", "step_publish",
         "latency")


class StepTimes:
    """The newest ``n`` columns of ``TIMED`` times [s], in a preallocated ring
    (thread-safe)."""

    def __init__(self, n: int = TIMING_SAMPLES) -> None:
        self._t = np.zeros((len(TIMED), n))
        self._next = 0
        self._count = 0
        self._lock = threading.Lock()

    def add(self, age: float, queue: float, features: float, forward: float, publish: float,
            total: float) -> None:
        with self._lock:
            t, i = self._t, self._next
            t[0, i], t[1, i], t[2, i], t[3, i], t[4, i], t[5, i] = \
                age, queue, features, forward, publish, total
            self._next = (i + 1) % t.shape[1]
            self._count = min(self._count + 1, t.shape[1])

    def figures(self) -> dict:
        """``<name>_<stat>_ms`` of every ``TIMED`` name (empty before any column)."""
        with self._lock:
            rows = self._t[:, :self._count] * 1e3
        if not rows.shape[1]:
            return {}
        q = np.percentile(rows, [50.0, 99.0, 99.9], axis=1)
        mx = rows.max(axis=1)
        out = {}
        for k, name in enumerate(TIMED):
            pre = name + "_"
            out.update({pre + "p50_ms": float(q[0, k]), pre + "p99_ms": float(q[1, k]),
                        pre + "p999_ms": float(q[2, k]), pre + "max_ms": float(mx[k])})
        return out


def inference_params() -> list:
    """The node's parameters, with their ranges; the estimator's from ``LiveConfig``."""
    d = LiveConfig()
    return [
        c.Param("checkpoint", "", "model checkpoint (.pt) from `aslip train`", c.non_empty,
                read_only=True),
        c.Param("hop_s", d.hop_s, "run the model every hop_s of new audio [s]",
                c.in_range(0.001, 1.0)),
        c.Param("threshold", -1.0, "slip probability threshold; -1 = the checkpoint's",
                c.off_or(-1.0, c.in_range(0.0, 1.0), "the checkpoint's")),
        c.Param("max_time_jump_s", d.max_time_jump_s,
                "a stamp this far off its sample index is a time jump [s]", c.positive),
        c.Param("frame_id", convert.GRASP_FRAME, "frame of the published slip",
                c.non_empty, read_only=True),
        c.Param("marker_scale_s", 2.0, "rviz arrow length per slip speed [m per m/s]",
                c.positive),
        c.Param("torch_threads", 1, "CPU threads for the model",
                c.int_range(1, 64), read_only=True),
        c.Param("diagnostics_period_s", 1.0, "diagnostics period [s]",
                c.in_range(0.05, 60.0), read_only=True),
        c.Param("max_lag_s", 0.05, "streaming models: skip a block that arrives this much "
                "later than the stream's usual delay (the node is behind) [s]; 0 = never",
                c.off_or(0.0, c.in_range(0.005, 1.0), "never")),
        c.Param("dead_channel_margin_db", d.dead_channel_margin_db,
                "withhold the estimate when a channel is this far below the median of "
                "the others or digitally silent [dB]; 0 = no check",
                c.off_or(0.0, c.in_range(20.0, 120.0), "off")),
    ]


class SlipInference(Node):
    """Runs the slip model on the live audio stream."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy.node.Node`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("slip_inference", **kwargs)
        self.p = c.declare_params(self, inference_params(), self._on_change)
        import torch
        torch.set_num_threads(int(self.p["torch_threads"]))
        config = LiveConfig(hop_s=self.p["hop_s"], max_time_jump_s=self.p["max_time_jump_s"],
                            dead_channel_margin_db=self.p["dead_channel_margin_db"])
        try:
            # Warms the model up before anything is subscribed (first torch calls are slow).
            # The one decision threshold: -1 leaves the checkpoint's.
            self.est = open_estimator(self.p["checkpoint"], config,
                                      None if self.p["threshold"] < 0 else self.p["threshold"])
            pr = self.est.predictor
        except (OSError, ValueError) as exc:
            raise ConfigError(f"cannot load checkpoint {self.p['checkpoint']!r}: {exc}") \
                from exc
        self.predictor = pr
        self.source = pr.model_type
        self._lock = threading.Lock()            # the node's own counters below
        self.blocks_in = 0
        self.published = 0
        self.last_error = ""
        #: Per-step times of the live path (module docstring), and block arrival times.
        self.timing = StepTimes()
        self.arrivals: collections.deque = collections.deque(maxlen=500)
        #: The window waiting for the model, with its timing so far (``_Handed``).
        self._job: Optional[tuple[Job, "_Handed"]] = None
        self._wake = threading.Condition(threading.Lock())
        self._stop = False
        self._running = False                    # the model thread is on a window
        #: Compute time of the newest block's estimates [s] (audio callback to published,
        #: the model's queue wait excluded): what a lockstep driver may charge for it.
        self.last_compute_s = 0.0
        #: Falling behind (module docstring): off for window models and on simulated time.
        sim_time = bool(self.get_parameter("use_sim_time").value)
        self._lag = LagMeter() if self.est.streaming and not sim_time else None
        self._arrival_s = time.time
        self.skipped_behind = 0
        self.lag_s = 0.0
        self.pub_slip = self.create_publisher(SlipVector, c.SLIP_TOPIC, RELIABLE_QOS)
        self.pub_marker = self.create_publisher(MarkerArray, c.MARKER_TOPIC, MARKER_QOS)
        self._slip_msg = SlipVector()            # filled again for each estimate (_publish)
        self._marker_subscribers = 0
        self._marker_check_at = 0.0              # monotonic [s] of the next subscriber count
        self.pub_calibration = self.create_publisher(String, topics.CALIBRATION, LATCHED_QOS)
        self._grasp = 0                          # grasps begun (resets of the calibration)
        # The audio, model and service threads all report the estimator's events: one at a
        # time, so the grasp count and the announcements keep their order.
        self._report_lock = threading.Lock()
        self._announce_calibration("start")
        self.diag = c.Diagnostics(self, "aslip: slip_inference", self.source)
        self._worker = threading.Thread(target=self._infer_loop, name="slip_inference_model",
                                        daemon=True)
        if self.est.runs_windows:
            self._worker.start()
        # The audio callback only decodes, gates, buffers and hands over: its own group, so
        # neither diagnostics nor metadata ever wait behind it (or it behind them).
        self.create_subscription(AudioFrame, c.AUDIO_TOPIC, self._on_audio, AUDIO_QOS,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.create_subscription(String, c.METADATA_TOPIC, self._on_metadata, LATCHED_QOS,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(self.p["diagnostics_period_s"], self._diagnose,
                          callback_group=MutuallyExclusiveCallbackGroup())
        self.create_service(Trigger, "~/recalibrate", self._on_recalibrate,
                            callback_group=MutuallyExclusiveCallbackGroup())
        hop = "streaming" if self.est.streaming else f"hop {self.est.hop_frames} frames"
        ready(self, f"{self.source} model, {pr.n_channels} channels "
                    f"{pr.channel_names} at {pr.sample_rate:g} Hz, window "
                    f"{pr.window_s * 1e3:.0f} ms, {hop}, "
                    f"calibration {pr.calibration.method if pr.calibrated else 'none'}")

    # -- parameters -------------------------------------------------------------------------

    def _on_change(self, changed: dict) -> None:
        if "hop_s" in changed:
            self.est.set_hop(changed["hop_s"])
        if "threshold" in changed:
            t = changed["threshold"]
            self.est.set_threshold(None if t < 0 else t)
        if "max_time_jump_s" in changed:
            self.est.set_max_time_jump(changed["max_time_jump_s"])
        if "marker_scale_s" in changed:
            self.p["marker_scale_s"] = changed["marker_scale_s"]
        if "max_lag_s" in changed:
            self.p["max_lag_s"] = changed["max_lag_s"]
        if "dead_channel_margin_db" in changed:
            self.est.dead_margin_db = float(changed["dead_channel_margin_db"])

    # -- input --------------------------------------------------------------------------------

    def _on_metadata(self, msg: String) -> None:
        self.get_logger().debug(f"metadata: {msg.data[:200]}")

    def _on_recalibrate(self, request, response):
        """``~/recalibrate``: a new grasp; the calibration starts again from zero gain."""
        response.success = self.est.new_grasp("~/recalibrate")
        self._report()
        response.message = "calibration reset" if response.success else \
            "the checkpoint has no per-grasp calibration"
        self.get_logger().info(f"~/recalibrate: {response.message}")
        return response

    def _announce_calibration(self, reason: str) -> None:
        """A new grasp (``reason``) or, when already announced, its convergence."""
        calibrated = self.est.calibrated            # a streaming model has none
        converged = self.est.calibration_converged
        if not converged:
            self._grasp += 1
        self.pub_calibration.publish(String(data=json.dumps({
            "calibrated": calibrated, "grasp": self._grasp, "converged": converged,
            "trusted": self.est.calibration_trusted, "reason": reason,
            "stamp_s": time.time()})))

    def _report(self) -> None:
        """The estimator's events as log lines and calibration announcements."""
        if not self.est.has_events:          # the common case: nothing to take or lock
            return
        with self._report_lock:
            self._log_events(self.est.take_events())

    def _log_events(self, events) -> None:
        log = self.get_logger()
        for e in events:
            if e.kind == "drop":
                log.warning(f"dropped AudioFrame ({e.reason}): {e.detail}",
                            throttle_duration_sec=1.0)
            elif e.kind == "bad_estimate":
                log.warning(f"dropped estimate: {e.detail}", throttle_duration_sec=1.0)
            elif e.kind == "refuse":
                log.error(f"refusing the audio stream: {e.detail}", throttle_duration_sec=2.0)
            elif e.kind == "dead":
                log.error(f"dead microphone channel(s) {e.detail}: no slip estimate "
                          "published", throttle_duration_sec=1.0)
            elif e.kind == "restart":
                if not e.reason.startswith("~"):
                    log.warning(f"audio {e.reason}; window restarts", throttle_duration_sec=1.0)
                if self.est.calibrated:
                    self._announce_calibration(e.reason)
            elif e.kind == "converged":
                self._announce_calibration("converged")
            elif e.kind == "untrusted":
                log.warning(f"per-grasp calibration not trusted ({e.detail}): the background "
                            "does not reach the microphones alike, so the gain estimate mixes "
                            "its paths with the coupling; directions may be biased")
                self._announce_calibration("untrusted")

    def _on_audio(self, msg: AudioFrame) -> None:
        t_in = time.perf_counter()
        wall_in = time.time_ns()
        with self._lock:
            self.blocks_in += 1
            self.arrivals.append(time.monotonic())
        try:
            self._handle(msg, t_in, wall_in)
        except Exception as exc:  # noqa: BLE001 - a bad frame must never take the node down
            self._internal_error(exc)

    def _internal_error(self, exc: Exception) -> None:
        with self._lock:
            self.last_error = f"{type(exc).__name__}: {exc}"
        self.est.drop("internal_error", self.last_error)
        self.get_logger().error(f"inference failed: {self.last_error}",
                                throttle_duration_sec=1.0)

    def _handle(self, msg: AudioFrame, t_in: float, wall_in: int = 0) -> None:
        try:
            a = convert.audio_from_msg(msg)
        except convert.AudioFrameError as exc:
            self.est.drop(exc.reason, str(exc))
            self._report()
            return
        age = (wall_in - a.end_stamp_ns) * 1e-9 if wall_in else 0.0
        if self._behind(a.end_stamp_ns):
            self._report()
            return
        estimates, job = self.est.accept(a)
        t_acc = time.perf_counter()
        self._report()
        if estimates:                # streaming: every hop the block completed
            for e in estimates:
                self._publish(e, marker=e is estimates[-1])
            t_out = time.perf_counter()
            fwd = self.est.last_forward_s
            self.timing.add(age, 0.0, t_acc - t_in - fwd, fwd, t_out - t_acc, t_out - t_in)
            self.last_compute_s = t_out - t_in
        if job is not None:
            handed = _Handed(t_in, age, t_acc - t_in, time.perf_counter())
            with self._wake:
                if self._job is not None:
                    self.est.count_superseded()
                self._job = (job, handed)
                self._wake.notify()

    def _behind(self, end_stamp_ns: int) -> bool:
        """True when this block is skipped because the node is behind the stream."""
        if self._lag is None:
            return False
        with self._lock:
            limit = self.p["max_lag_s"]
            steps = self._lag.steps
            lag, skip = self._lag.behind(self._arrival_s(), end_stamp_ns * 1e-9, limit)
            self.lag_s = lag
            if skip:
                self.skipped_behind += 1
        if self._lag.steps != steps:
            self.get_logger().warning(
                f"the audio's stamps stay over max_lag_s ({limit * 1e3:.0f} ms) late for "
                f"{STEP_AFTER_S * 1e3:.0f} ms: its source's clock stepped (no backlog); the "
                "usual delay starts again", throttle_duration_sec=1.0)
        if not skip:
            return False
        self.est.drop("behind", f"{lag * 1e3:.0f} ms behind the stream (max_lag_s "
                                f"{limit * 1e3:.0f} ms): block skipped, the stream restarts")
        return True

    def _publish(self, e: Estimate, marker: bool = True) -> None:
        p = e.prediction
        # One message, filled again for each estimate: the audio thread (streaming) or the
        # model thread (window models) publishes, never both, and publish serialises it.
        out = convert.slip_to_msg(p.vx, p.vz, p.probability, p.slipping, p.threshold,
                                  e.stamp_ns, p.window_length, self.source, self.p["frame_id"],
                                  direction_sigma=e.direction_sigma,
                                  angular_velocity=p.angular_velocity,
                                  angular_sigma=p.angular_sigma, out=self._slip_msg)
        self.pub_slip.publish(out)
        with self._lock:
            self.published += 1
        # rviz needs only the newest arrow, and only when someone shows it (asked at most
        # every MARKER_SUBSCRIBERS_S: the graph query costs more than the estimate).
        if not marker:
            return
        now = time.monotonic()
        if now >= self._marker_check_at:
            self._marker_check_at = now + MARKER_SUBSCRIBERS_S
            self._marker_subscribers = self.pub_marker.get_subscription_count()
        if self._marker_subscribers > 0:
            self.pub_marker.publish(convert.slip_markers(out,
                                                         scale_s=self.p["marker_scale_s"]))

    def _infer_loop(self) -> None:
        """The model thread: newest window in, SlipVector out."""
        while True:
            with self._wake:
                while self._job is None and not self._stop:
                    self._wake.wait(0.5)
                if self._stop:
                    return
                job, h = self._job
                self._job = None
                self._running = True
            try:
                t_run = time.perf_counter()
                e = self.est.run(job)
                self._report()
                if e is not None:
                    t_pub = time.perf_counter()
                    self._publish(e)
                    t_out = time.perf_counter()
                    est = self.est
                    self.timing.add(h.age, t_run - h.handed, h.accept + est.last_features_s,
                                    est.last_forward_s, t_out - t_pub, t_out - h.t_in)
                    self.last_compute_s = h.accept + (t_out - t_run)
            except Exception as exc:  # noqa: BLE001 - the thread must outlive a bad window
                if self._stop:
                    return
                self._internal_error(exc)
            finally:
                with self._wake:
                    self._running = False
                    self._wake.notify_all()

    def idle(self) -> bool:
        """True when no window waits for the model and the model thread is not on one (a
        streaming model works in the audio callback: always idle between callbacks)."""
        return self.wait_idle(0.0)

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait at most ``timeout_s`` for :meth:`idle`; whether it is. For a caller that
        must know the model thread is done without an event to wake it: a hybrid's window
        part publishes nothing of its own."""
        with self._wake:
            return self._wake.wait_for(lambda: self._job is None and not self._running,
                                       timeout_s)

    def destroy_node(self) -> None:
        """Stop the model thread, then destroy the node."""
        with self._wake:
            self._stop = True
            self._wake.notify()
        if self._worker.is_alive() and self._worker is not threading.current_thread():
            self._worker.join(timeout=2.0)
        super().destroy_node()

    # -- diagnostics --------------------------------------------------------------------------

    def _diagnose(self) -> None:
        with self._lock:
            arr = list(self.arrivals)
            values = {"blocks_received": self.blocks_in, "estimates_published": self.published,
                      "model": self.source, "hops_skipped_behind": self.skipped_behind,
                      "lag_clock_steps": self._lag.steps if self._lag else 0,
                      "lag_ms": self.lag_s * 1e3}
        rep = self.est.report()
        values.update(rep["values"])
        values.update({f"dropped_{k}": v for k, v in sorted(rep["drops"].items())})
        dead, drops, refusal, cal = rep["dead"], sum(rep["drops"].values()), rep["refusal"], \
            rep["summary"]
        if cal is not None:
            gains = cal.pop("gain_db")
            values.update(cal)
            values.update({f"gain_db_{n}": g for n, g in gains.items()})
        values["dead_channels"] = ",".join(dead)
        recent = [t for t in arr if t > time.monotonic() - 2.0]
        values["input_rate_hz"] = (len(recent) - 1) / (recent[-1] - recent[0]) \
            if len(recent) > 2 and recent[-1] > recent[0] else 0.0
        values.update(self.timing.figures())
        level, message = c.Diagnostics.OK, "running"
        if refusal:
            level, message = c.Diagnostics.ERROR, f"stream refused: {refusal}"
        elif dead:
            level, message = c.Diagnostics.ERROR, (f"dead microphone channel(s): "
                                                   f"{', '.join(dead)}; no estimates published")
        elif drops:
            level, message = c.Diagnostics.WARN, f"{drops} frames dropped"
        elif not recent:
            level, message = c.Diagnostics.WARN, "no audio"
        elif cal is not None and cal.get("calibration_trusted") is False:
            level, message = c.Diagnostics.WARN, (
                f"per-grasp calibration not trusted: spread "
                f"{cal['calibration_spread_db']:.2f} dB above "
                f"{cal['calibration_trust_spread_db']:.2f} dB")
        if self.last_error:
            values["last_error"] = self.last_error
        self.diag.publish(level, message, values)


class _Handed(NamedTuple):
    """A window model's block on its way to the model thread: its timing so far [s]."""

    t_in: float          # the audio callback's start (perf_counter)
    age: float           # the block's age when its callback started
    accept: float        # callback: decode, gate, buffers, calibration
    handed: float        # handed to the model thread (perf_counter)


def _frozen_node() -> SlipInference:
    """The node, then everything it allocated moved out of the garbage collector's reach
    (``gc.freeze``). The process then holds ~225 000 objects (rclpy, torch, the model): a
    full collection over them stalled every thread for 50-110 ms (measured in this process
    at start-up); after the freeze one covers only what came later (< 1 ms). The live
    path itself leaves no garbage cycles (no collection at all in 60 s of steady
    streaming), so this only guards against a collection that something else triggers
    (parameters, services, reconnections)."""
    node = SlipInference()
    gc.collect()
    gc.freeze()
    return node


_frozen_node.__name__ = SlipInference.__name__        # run_node names the node by it


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros slip_inference``."""
    return run_node(_frozen_node, args)


if __name__ == "__main__":
    raise SystemExit(main())
