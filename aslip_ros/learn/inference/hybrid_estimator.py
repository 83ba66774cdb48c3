"""The live estimator of every checkpoint, the hybrid one included (``open_estimator``), and
the hybrid's own (``HybridEstimator``: learn/models/aslip_hybrid.py).

    est = open_estimator("model.pt", LiveConfig(hop_s=0.01))
    estimates, job = est.accept(block)        # the audio thread
    if job is not None:
        est.run(job)                          # a model thread (``runs_windows``)

A hybrid runs its two parts side by side, each a whole ``LiveEstimator`` with its own gate,
per-grasp calibration, dead-channel check and counters: every block goes to both.
``accept`` returns the stream part's estimates, one per hop as soon as the block completes
it, each taking the outputs the checkpoint gives the window part from the newest window
estimate ``run`` made, where that one is no older than ``max_window_age_s`` on the stream
clock (from its window's last sample to the hop's); otherwise, at the start of a grasp or
after a restart, the stream part's own. ``run`` gives nothing to publish: the window part
only feeds the hops that follow it. ``feed`` (evaluation, tests) does both at once, the
block's hops first, as a live model thread that keeps up would: a hop never reads a window
that ends after it.
"""

from __future__ import annotations

import os
from typing import Any, Optional

import numpy as np

from aslip_ros.learn.checkpoint import Checkpoint, estimates_rotation, load_checkpoint
from aslip_ros.learn.inference.live import (Estimate, Event, Job, LiveConfig, LiveEstimator,
                                            load_predictor)
from aslip_ros.learn.inference.predictor import Prediction
from aslip_ros.learn.models.aslip_hybrid import (EITHER, LATCHED, STREAM, WINDOW,
                                                 HybridBackend)
from aslip_ros.learn.models.per_output import combine, members, role_outputs


def open_estimator(checkpoint: str | os.PathLike | Checkpoint,
                   config: LiveConfig = LiveConfig(), threshold: float | None = None):
    """The live estimator of a checkpoint (a path or one loaded): a ``HybridEstimator`` for
    an ``aslip_hybrid`` one, else a ``LiveEstimator``. ``threshold``: the decision
    threshold (None: the checkpoint's). OSError / ValueError when unusable."""
    ckpt = checkpoint if isinstance(checkpoint, Checkpoint) else load_checkpoint(checkpoint)
    if ckpt.model_type == HybridBackend.model_type:
        return HybridEstimator(ckpt, config, threshold)
    return LiveEstimator(load_predictor(ckpt, threshold, config.max_time_jump_s), config)


class _Facts:
    """What a caller reads of a hybrid's "predictor": the stream facts (the window part's:
    the longest audio an estimate reads), the calibration and the decision threshold (the
    detection part's)."""

    model_type = HybridBackend.model_type

    def __init__(self, est: "HybridEstimator") -> None:
        self._est = est
        w = est.window.predictor
        self.n_channels, self.channel_names = w.n_channels, list(w.channel_names)
        self.sample_rate, self.window_s = w.sample_rate, w.window_s
        self.window_samples = w.window_samples

    @property
    def calibrated(self) -> bool:
        return self._est.calibrated

    def _calibrated_part(self) -> Any:
        parts = (self._est.stream.predictor, self._est.window.predictor)
        return next((p for p in parts if p.calibrated), None)

    @property
    def calibration(self) -> Any:
        part = self._calibrated_part()
        return None if part is None else part.calibration

    def calibration_summary(self) -> dict[str, Any] | None:
        """The calibration state of the first calibrated part (the stream part's where both
        are: each part keeps its own, from the same audio)."""
        part = self._calibrated_part()
        return None if part is None else part.calibration_summary()

    @property
    def threshold(self) -> float:
        return self._est.threshold

    def set_threshold(self, threshold: float | None) -> float:
        return self._est.set_threshold(threshold)


class HybridEstimator:
    """A streaming and a window estimator as one (module docstring)."""

    streaming = True            # estimates come out of ``accept``, hop by hop
    runs_windows = True         # and ``accept`` hands out window jobs for ``run``

    def __init__(self, ckpt: Checkpoint, config: LiveConfig = LiveConfig(),
                 threshold: float | None = None) -> None:
        backend = HybridBackend.from_checkpoint(ckpt)
        self.cfg = backend.cfg
        self.roles = self.cfg.roles()
        jump = config.max_time_jump_s
        self.stream = LiveEstimator(load_predictor(backend.parts[STREAM], None, jump), config)
        self.window = LiveEstimator(load_predictor(backend.parts[WINDOW], None, jump), config)
        # Both parts push every block to their calibration: the frames are cut once.
        self.window.predictor.share_calibration_frames(self.stream.predictor)
        self.detector = self.stream if self.cfg.threshold_part == STREAM else self.window
        self.set_threshold(threshold)
        rot = estimates_rotation(backend.parts[STREAM].meta) and self.cfg.rotation is not None
        #: The roles when no window estimate is fresh: the stream part gives them all.
        self.stream_roles = {r: STREAM for r in self.roles if r != "rotation" or rot}
        self.max_age_ns = int(round(self.cfg.max_window_age_s * 1e9))
        self.predictor = _Facts(self)
        self._latest: Optional[Estimate] = None     # the newest window estimate (``run``)
        self._slipping = False                      # the last hop's decision (``latched``)
        self.merged = 0                             # hops that read a window estimate

    # --- settings, shared by both parts ---------------------------------------------------
    def set_hop(self, hop_s: float) -> None:
        self.window.set_hop(hop_s)

    @property
    def hop_frames(self) -> int:
        return self.window.hop_frames

    def set_max_time_jump(self, seconds: float) -> None:
        self.stream.set_max_time_jump(seconds)
        self.window.set_max_time_jump(seconds)

    def set_threshold(self, threshold: float | None) -> float:
        return self.detector.set_threshold(threshold)

    @property
    def threshold(self) -> float:
        return self.detector.threshold

    @property
    def dead_margin_db(self) -> float:
        return self.stream.dead_margin_db

    @dead_margin_db.setter
    def dead_margin_db(self, margin_db: float) -> None:
        self.stream.dead_margin_db = self.window.dead_margin_db = float(margin_db)

    # --- state, events and counters -------------------------------------------------------
    @property
    def calibrated(self) -> bool:
        return self.stream.calibrated or self.window.calibrated

    @property
    def calibration_converged(self) -> bool:
        parts = [e for e in (self.stream, self.window) if e.calibrated]
        return bool(parts) and all(e.calibration_converged for e in parts)

    @property
    def calibration_trusted(self) -> Optional[bool]:
        said = [e.calibration_trusted for e in (self.stream, self.window)]
        if False in said:
            return False
        return None if all(s is None for s in said) else True

    @property
    def stats(self):
        return self.stream.stats

    @property
    def last_forward_s(self) -> float:
        return self.stream.last_forward_s

    @property
    def last_features_s(self) -> float:
        return self.window.last_features_s

    @property
    def has_events(self) -> bool:
        return self.stream.has_events or self.window.has_events

    def take_events(self) -> list[Event]:
        """Both parts' events, each told once (both see every block, so both tell of a gap)."""
        out: list[Event] = []
        for e in self.stream.take_events() + self.window.take_events():
            if e not in out:
                out.append(e)
        return out

    def report(self) -> dict:
        """The stream part's counters (both parts see the same blocks), with the window
        part's windows superseded and the hops that read a window estimate."""
        rep = self.stream.report()
        win = self.window.report()
        rep["values"]["hops_superseded"] = win["values"]["hops_superseded"]
        rep["values"]["hops_with_window"] = self.merged
        rep["dead"] = sorted(set(rep["dead"]) | set(win["dead"]))
        rep["summary"] = self.predictor.calibration_summary()
        return rep

    def count_superseded(self) -> None:
        self.window.count_superseded()

    def drop(self, reason: str, detail: str) -> None:
        self.stream.drop(reason, detail)
        self.window.drop(reason, detail)

    def restart(self, reason: str) -> None:
        self.stream.restart(reason)
        self.window.restart(reason)
        self._latest, self._slipping = None, False

    def new_grasp(self, reason: str) -> bool:
        stream, window = self.stream.new_grasp(reason), self.window.new_grasp(reason)
        self._latest, self._slipping = None, False
        return stream or window

    # --- the estimates --------------------------------------------------------------------
    def accept(self, a) -> tuple[list[Estimate], Optional[Job]]:
        """The stream part's hops of this block, merged (module docstring), and the window
        part's job, if one is due."""
        hops, _ = self.stream.accept(a)
        _, job = self.window.accept(a)
        return [self._merge(e) for e in hops], job

    def run(self, job: Job) -> None:
        """The window part's estimate of ``job``, kept for the hops that follow; None: the
        window part publishes nothing of its own."""
        e = self.window.run(job)
        if e is not None:
            self._latest = e
        return None

    def feed(self, a) -> list[Estimate]:
        out, job = self.accept(a)
        if job is not None:
            self.run(job)
        return out

    def _decider(self, hop: Estimate, win: Optional[Estimate]) -> tuple[str, float]:
        """The part whose p(slip) the estimate carries, and its threshold."""
        part = self.cfg.detection
        if win is None:
            part = STREAM
        elif part == EITHER or part == LATCHED:
            keeps = part == EITHER or self._slipping
            part = (WINDOW if keeps and win.prediction.slipping
                    and not hop.prediction.slipping else STREAM)
        return part, (self.stream if part == STREAM else self.window).threshold

    def _merge(self, hop: Estimate) -> Estimate:
        win = self._latest
        fresh = win is not None and 0 <= hop.stamp_ns - win.stamp_ns <= self.max_age_ns
        decider, t = self._decider(hop, win if fresh else None)
        roles = dict(self.roles if fresh else self.stream_roles, detection=decider)
        outs = {STREAM: _outputs(hop, self.stream.predictor.estimates_rotation)}
        if fresh:
            outs[WINDOW] = _outputs(win, self.window.predictor.estimates_rotation)
            self.merged += 1
        prob, v, rate = combine(role_outputs(roles, outs))
        p, s = float(prob[0]), hop.prediction
        slipping = self._slipping = p >= t
        vx, vz = (float(v[0, 0]), float(v[0, 1])) if slipping else (0.0, 0.0)
        speed = float(np.hypot(vx, vz))
        sigma_from = win if fresh and WINDOW in members(roles["direction"]) else hop
        rot = roles.get("rotation")
        rate_from = win if fresh and rot and WINDOW in members(rot) else hop
        pred = Prediction(
            p, slipping, vx, vz, speed, (vx / speed, vz / speed) if speed > 0 else (0.0, 0.0),
            win.prediction.window_length if fresh else s.window_length, t,
            sigma_from.prediction.direction_sigma,
            0.0 if rate is None else float(rate[0]),
            rate_from.prediction.angular_sigma if rate is not None else -1.0)
        return Estimate(hop.stamp_ns, pred, sigma_from.direction_sigma,
                        (float(v[0, 0]), float(v[0, 1])))


def _outputs(e: Estimate, rotates: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """An estimate as ``combine`` reads a part's outputs: p, the ungated velocity and the
    rate (None for a part that estimates none)."""
    p = e.prediction
    rate = np.array([p.angular_velocity], np.float64) if rotates else None
    return (np.array([p.probability], np.float64), np.array([e.raw_velocity], np.float64),
            rate)
