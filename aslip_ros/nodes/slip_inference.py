"""``slip_inference``: AudioFrame stream -> model -> SlipVector at the hop rate.

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
(``aslip_ros.learn.stream.StreamGate``). Nothing that arrives can crash the node or put
NaN on ``/aslip/slip``.

Dead microphones: before the model runs, each window is checked for a channel that looks
dead or disconnected (``learn.channel_check.dead_channels``: digital silence, or more than
``dead_channel_margin_db`` below the median of the other channels). A model fed such a
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
the estimate's speed (``learn.output_calibration``; -1 when the checkpoint has no sigma
model, as older ones; a message that is not slipping carries -1). ``/diagnostics`` shows
``calibration_converged``, ``calibration_accepted_frames``, ``calibration_frames``,
``calibration_resets`` and ``gain_db_<channel>``. Every new grasp and every convergence is
also announced on the latched ``/aslip/calibration`` (std_msgs/String, JSON: ``calibrated``,
``grasp``, ``converged``, ``reason``, ``stamp_s``), which the controllers report to the user.

Timing: the model runs on a thread of its own, never inside the audio callback, so a slow
forward pass cannot hold up the audio subscription (which would overflow its best-effort
queue and cost a window restart). When a hop is due the callback copies the newest window
into a pre-allocated buffer and wakes the thread; if the thread is still busy, the newer
window replaces the waiting one (counted as ``hops_superseded``: the freshest estimate is
what a controller needs). torch runs with ``torch_threads`` (1) and the model is warmed up
(the first calls pay torch's lazy initialisation) before the node subscribes to audio, so
the first published estimates already come at the hop rate.

Streaming checkpoints (``aslip_stream``, ``inference_steps``): no window nor model thread, a
SlipVector per 10 ms hop, state resets in ``stream_resets`` and ``last_reset_reason``.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Optional

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from aslip_ros import topics
from aslip_ros.learn.backends import model_backend
from aslip_ros.learn.channel_check import dead_channels
from aslip_ros.learn.stream import RingBuffer, StreamGate
from aslip_ros.msg import AudioFrame, SlipVector
from aslip_ros.nodes import common as c
from aslip_ros.nodes import convert
from aslip_ros.nodes.inference_steps import (StreamStats, StreamStep, inference_params,
                                             load_predictor)

#: The audio subscription: the sensor QoS (best effort, volatile) with a 1 s queue at 10 ms
#: blocks. With the default 10-deep queue, a process starved of CPU for 100 ms (two busy
#: processes on a 2-core host do it) lost blocks, and each gap restarts the window: a 200 ms
#: model then published nothing for 200 ms, tripping the controllers' stale-input stop. A
#: backlog is cheap to catch up with (a hop supersedes the waiting one); lost audio is not.
AUDIO_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                       reliability=c.SENSOR_QOS.reliability, durability=c.SENSOR_QOS.durability)

#: direction_sigma [rad] while the per-grasp calibration has not converged: uninformative.
UNCONVERGED_DIRECTION_SIGMA = float(np.pi)

DROP_REASONS = ("no_channels", "bad_rate", "empty", "ragged", "non_finite", "out_of_range",
                "channels", "sample_rate", "repeated", "out_of_order", "time_jump")


class SlipInference(Node):
    """Runs the slip model on the live audio stream."""

    def __init__(self, **kwargs) -> None:
        """``kwargs`` go to ``rclpy.node.Node`` (e.g. ``parameter_overrides``, ``context``)."""
        super().__init__("slip_inference", **kwargs)
        self.p = c.declare_params(self, inference_params(), self._on_change)
        import torch
        torch.set_num_threads(int(self.p["torch_threads"]))
        try:
            self.predictor = load_predictor(self.p["checkpoint"], self.p["max_time_jump_s"])
        except (OSError, ValueError) as exc:
            raise c.ConfigError(f"cannot load checkpoint {self.p['checkpoint']!r}: {exc}") \
                from exc
        pr = self.predictor
        # The predictor holds the one decision threshold; -1 leaves the checkpoint's.
        pr.set_threshold(None if self.p["threshold"] < 0 else self.p["threshold"])
        self.source = pr.model_type
        self.dead_margin_db = float(self.p["dead_channel_margin_db"])
        self.stream = StreamStep(pr) if model_backend(pr.model_type).streaming else None
        self.ring = RingBuffer(pr.window_samples, pr.n_channels)
        self.gate = StreamGate(self.p["max_time_jump_s"])
        self.hop_frames = max(1, int(round(self.p["hop_s"] * pr.sample_rate)))
        self._since_hop = 0
        self._lock = threading.Lock()
        self.stats = StreamStats()
        # Double buffer between the audio callback and the inference thread, allocated once.
        self._back = np.zeros((pr.window_samples, pr.n_channels), np.float32)
        self._front = np.zeros_like(self._back)
        self._job: Optional[tuple] = None        # (end stamp ns, t_in, calibration) of _back
        self._wake = threading.Condition(threading.Lock())
        self._stop = False
        # Warm-up before anything is subscribed: the first torch calls are slow (lazy
        # initialisation, allocator); a few passes keep them out of the live stream.
        for _ in range(0 if self.stream else 3):      # (StreamStep warmed its model up)
            pr.predict(self._front)
        self.pub_slip = self.create_publisher(SlipVector, c.SLIP_TOPIC, c.RELIABLE_QOS)
        self.pub_marker = self.create_publisher(MarkerArray, c.MARKER_TOPIC, c.MARKER_QOS)
        self.pub_calibration = self.create_publisher(String, topics.CALIBRATION, c.LATCHED_QOS)
        self._grasp = 0                          # grasps begun (resets of the calibration)
        self._announced_converged = False
        self._announce_calibration("start")
        self.diag = c.Diagnostics(self, "aslip: slip_inference", self.source)
        self._worker = threading.Thread(target=self._infer_loop, name="slip_inference_model",
                                        daemon=True)
        if self.stream is None:
            self._worker.start()
        # The audio callback only gates, buffers and hands over: its own group, so neither
        # diagnostics nor metadata ever wait behind it (or it behind them).
        self.create_subscription(AudioFrame, c.AUDIO_TOPIC, self._on_audio, AUDIO_QOS,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.create_subscription(String, c.METADATA_TOPIC, self._on_metadata, c.LATCHED_QOS,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(self.p["diagnostics_period_s"], self._diagnose,
                          callback_group=MutuallyExclusiveCallbackGroup())
        self.create_service(Trigger, "~/recalibrate", self._on_recalibrate,
                            callback_group=MutuallyExclusiveCallbackGroup())
        hop = "streaming" if self.stream else f"hop {self.hop_frames} frames"
        c.ready(self, f"{self.source} model, {pr.n_channels} channels "
                      f"{pr.channel_names} at {pr.sample_rate:g} Hz, window "
                      f"{pr.window_s * 1e3:.0f} ms, {hop}, "
                      f"calibration {pr.calibration.method if pr.calibrated else 'none'}")

    # -- parameters -------------------------------------------------------------------------

    def _on_change(self, changed: dict) -> None:
        with self._lock:
            if "hop_s" in changed:
                self.hop_frames = max(1, int(round(changed["hop_s"] *
                                                   self.predictor.sample_rate)))
            if "threshold" in changed:
                t = changed["threshold"]
                self.predictor.set_threshold(None if t < 0 else t)
            if "max_time_jump_s" in changed:
                self.gate.max_time_jump_ns = int(changed["max_time_jump_s"] * 1e9)
            if "marker_scale_s" in changed:
                self.p["marker_scale_s"] = changed["marker_scale_s"]
            if "dead_channel_margin_db" in changed:
                self.dead_margin_db = float(changed["dead_channel_margin_db"])

    # -- input --------------------------------------------------------------------------------

    def _on_metadata(self, msg: String) -> None:
        self.get_logger().debug(f"metadata: {msg.data[:200]}")

    def _on_recalibrate(self, request, response):
        """``~/recalibrate``: a new grasp; the calibration starts again from zero gain."""
        with self._lock:
            if self.predictor.calibrated:
                self.predictor.reset_calibration()
                self._announce_calibration("~/recalibrate")
        response.success = self.predictor.calibrated
        response.message = "calibration reset" if response.success else \
            "the checkpoint has no per-grasp calibration"
        self.get_logger().info(f"~/recalibrate: {response.message}")
        return response

    def _restart_window(self, reason: str) -> None:
        """The stream is not continuous here: a new window, and a new grasp to calibrate."""
        if self.stream:
            return self.stream.reset(reason)
        self.ring.reset()
        self.predictor.reset_calibration()
        self._since_hop = 0
        if self.predictor.calibrated:
            self._announce_calibration(reason)

    def _announce_calibration(self, reason: str) -> None:
        """A new grasp (``reason``) or, when already announced, its convergence."""
        pr = self.predictor
        calibrated = pr.calibrated             # a streaming model has none
        converged = calibrated and pr.calibration_converged
        if not converged:
            self._grasp += 1
        self._announced_converged = converged
        self.pub_calibration.publish(String(data=json.dumps({
            "calibrated": calibrated, "grasp": self._grasp, "converged": converged,
            "reason": reason, "stamp_s": time.time()})))

    def _drop(self, reason: str, detail: str) -> None:
        if self.stream and reason not in ("repeated", "out_of_order", "time_jump"):
            self.stream.reset(f"dropped block ({reason})")    # the next one follows a hole
        self.stats.drops[reason] += 1
        self.get_logger().warning(f"dropped AudioFrame ({reason}): {detail}",
                                  throttle_duration_sec=1.0)

    def _on_audio(self, msg: AudioFrame) -> None:
        t_in = time.perf_counter()
        self.stats.blocks_in += 1
        self.stats.arrivals.append(time.monotonic())
        try:
            with self._lock:
                self._handle(msg, t_in)
        except Exception as exc:  # noqa: BLE001 - a bad frame must never take the node down
            self.stats.last_error = f"{type(exc).__name__}: {exc}"
            self.stats.drops["internal_error"] += 1
            self.get_logger().error(f"inference failed: {self.stats.last_error}",
                                    throttle_duration_sec=1.0)

    def _handle(self, msg: AudioFrame, t_in: float) -> None:
        pr = self.predictor
        try:
            a = convert.audio_from_msg(msg)
        except convert.AudioFrameError as exc:
            self._drop(exc.reason, str(exc))
            return
        if a.channel_names != pr.channel_names:
            self._refuse("channels", f"stream channels {a.channel_names} do not match the "
                                     f"checkpoint's {pr.channel_names}")
            return
        try:
            pr.check_stream(a.sample_rate, a.channel_names)
        except ValueError as exc:
            self._refuse("sample_rate", str(exc))
            return
        verdict, detail = self.gate.check(a)
        if verdict in ("repeated", "out_of_order"):
            self._drop(verdict, detail)
            return
        if verdict == "time_jump":
            # Re-anchor on this frame so a real clock step costs one window, not the stream.
            self._drop(verdict, detail)
            self.gate.accept(a)
            self._restart_window(f"time jump: {detail}")
            return
        if verdict == "new_stream":
            # A restarted or re-numbered source: its blocks are good audio, only the old
            # anchor is void. No frames are counted lost (the index difference means nothing).
            self.stats.stream_restarts += 1
            self.get_logger().warning(f"new audio stream: {detail}; window restarts",
                                      throttle_duration_sec=1.0)
            self._restart_window(f"new stream: {detail}")
        if verdict == "gap":
            self.stats.gaps += 1
            self.stats.frames_lost += a.first_sample_index - self.gate.next_index
            self.get_logger().warning(f"audio gap: {detail}; window restarts",
                                      throttle_duration_sec=1.0)
            self._restart_window(f"gap: {detail}")
        self.gate.accept(a)
        self.stats.blocks_ok += 1
        self.stats.refusal = ""
        if self.stream:
            return self._stream_block(a, t_in)
        self.ring.push(a.block)
        pr.push_audio(a.block)
        if pr.calibration_converged and not self._announced_converged:
            self._announce_calibration("converged")
        self._since_hop += a.frames
        if self.ring.filled < self.ring.length or self._since_hop < self.hop_frames:
            return
        # Several hops inside one block: one estimate on the newest window is what matters.
        self._since_hop %= self.hop_frames
        with self._wake:
            np.copyto(self._back, self.ring.window())
            if self._job is not None:
                self.stats.hops_superseded += 1
            # The calibration as of this window's end, whenever the model gets to it.
            self._job = (a.end_stamp_ns, t_in, pr.calibration_offsets(),
                         pr.calibration_converged)
            self._wake.notify()

    def _stream_block(self, a, t_in: float) -> None:
        """A streaming checkpoint: every hop the block completes goes out (under the lock)."""
        try:
            msgs, dead = self.stream.block(a, self.source, self.p["frame_id"],
                                           self.dead_margin_db)
        except ValueError as exc:                  # a non-finite estimate: nothing goes out
            self._drop("bad_estimate", str(exc))
            return
        if dead:
            self._withhold(dead)
            return
        for out in msgs:
            self.pub_slip.publish(out)
            self.stats.latency.append(time.perf_counter() - t_in)
        self.stats.published += len(msgs)
        scale = self.p["marker_scale_s"]
        if msgs:        # rviz needs only the newest arrow
            self.pub_marker.publish(convert.slip_markers(msgs[-1], scale_s=scale))

    def _infer_loop(self) -> None:
        """The model thread: newest window in, SlipVector out."""
        pr = self.predictor
        while True:
            with self._wake:
                while self._job is None and not self._stop:
                    self._wake.wait(0.5)
                if self._stop:
                    return
                stamp_ns, t_in, offsets, converged = self._job
                self._job = None
                self._back, self._front = self._front, self._back
            try:
                with self._lock:
                    margin_db = self.dead_margin_db
                dead = dead_channels(self._front, pr.channel_names, margin_db) \
                    if margin_db > 0 else []
                if dead:
                    with self._lock:
                        self._withhold(dead)
                    continue
                try:
                    out = self._estimate(self._front, stamp_ns, offsets, converged)
                except ValueError as exc:
                    with self._lock:
                        self._drop("bad_estimate", str(exc))
                    continue
                self.pub_slip.publish(out)
                with self._lock:
                    self.stats.latency.append(time.perf_counter() - t_in)
                    self.stats.published += 1
                self.pub_marker.publish(convert.slip_markers(
                    out, scale_s=self.p["marker_scale_s"]))
            except Exception as exc:  # noqa: BLE001 - the thread must outlive a bad window
                if self._stop:
                    return
                with self._lock:
                    self.stats.last_error = f"{type(exc).__name__}: {exc}"
                    self.stats.drops["internal_error"] += 1
                self.get_logger().error(f"inference failed: {self.stats.last_error}",
                                        throttle_duration_sec=1.0)

    def _estimate(self, window: np.ndarray, stamp_ns: int, offsets: Optional[np.ndarray],
                  converged: bool):
        """One hop: the window (and its calibration) through the model, as a SlipVector."""
        pred = self.predictor.predict(window, offsets)
        sigma = UNCONVERGED_DIRECTION_SIGMA if offsets is not None and not converged \
            else pred.direction_sigma
        return convert.slip_to_msg(pred.vx, pred.vz, pred.probability, pred.slipping,
                                   pred.threshold, stamp_ns, pred.window_length, self.source,
                                   self.p["frame_id"], direction_sigma=sigma)

    def _withhold(self, dead: list) -> None:
        """A window with dead channels: counted, reported, no estimate published (call with
        the lock held)."""
        self.stats.dead_windows += 1
        self.stats.dead_recent.update(dead)
        self.get_logger().error(f"dead microphone channel(s) {', '.join(dead)}: "
                                "no slip estimate published", throttle_duration_sec=1.0)

    def destroy_node(self) -> None:
        """Stop the model thread, then destroy the node."""
        with self._wake:
            self._stop = True
            self._wake.notify()
        if self._worker.is_alive() and self._worker is not threading.current_thread():
            self._worker.join(timeout=2.0)
        super().destroy_node()

    def _refuse(self, reason: str, detail: str) -> None:
        self.stats.refusal = detail
        if self.stream:
            self.stream.reset(f"refused stream ({reason})")
        self.stats.drops[reason] += 1
        self.get_logger().error(f"refusing the audio stream: {detail}",
                                throttle_duration_sec=2.0)

    # -- diagnostics --------------------------------------------------------------------------

    def _diagnose(self) -> None:
        st = self.stats
        with self._lock:
            lat = np.array(st.latency) * 1e3
            arr = list(st.arrivals)
            values = {"blocks_received": st.blocks_in, "blocks_accepted": st.blocks_ok,
                      "blocks_dropped": sum(st.drops.values()), "gaps": st.gaps,
                      "stream_restarts": st.stream_restarts,
                      "frames_lost": st.frames_lost, "estimates_published": st.published,
                      "hops_superseded": self.stats.hops_superseded,
                      "dead_channel_windows": self.stats.dead_windows,
                      "threshold": self.predictor.threshold, "model": self.source}
            values.update({f"dropped_{k}": v for k, v in sorted(self.stats.drops.items())})
            names = self.predictor.channel_names
            dead = [n for n in names if n in self.stats.dead_recent]
            self.stats.dead_recent.clear()
            cal = None if self.stream else self.predictor.calibration_summary()
            if self.stream:
                values.update(stream_resets=self.predictor.resets,
                              last_reset_reason=self.predictor.last_reset_reason)
        if cal is not None:
            gains = cal.pop("gain_db")
            values.update(cal)
            values.update({f"gain_db_{n}": g for n, g in gains.items()})
        values["dead_channels"] = ",".join(dead)
        recent = [t for t in arr if t > time.monotonic() - 2.0]
        values["input_rate_hz"] = (len(recent) - 1) / (recent[-1] - recent[0]) \
            if len(recent) > 2 and recent[-1] > recent[0] else 0.0
        if lat.size:
            values.update(latency_p50_ms=float(np.percentile(lat, 50)),
                          latency_p99_ms=float(np.percentile(lat, 99)),
                          latency_max_ms=float(lat.max()))
        level, message = c.Diagnostics.OK, "running"
        if self.stats.refusal:
            level, message = c.Diagnostics.ERROR, f"stream refused: {self.stats.refusal}"
        elif dead:
            level, message = c.Diagnostics.ERROR, (f"dead microphone channel(s): "
                                                   f"{', '.join(dead)}; no estimates published")
        elif self.stats.drops:
            level, message = c.Diagnostics.WARN, f"{sum(self.stats.drops.values())} frames dropped"
        elif not recent:
            level, message = c.Diagnostics.WARN, "no audio"
        if self.stats.last_error:
            values["last_error"] = self.stats.last_error
        self.diag.publish(level, message, values)


def main(args: Optional[list] = None) -> int:
    """Entry point of ``ros2 run aslip_ros slip_inference``."""
    return c.run_node(SlipInference, args)


if __name__ == "__main__":
    raise SystemExit(main())
