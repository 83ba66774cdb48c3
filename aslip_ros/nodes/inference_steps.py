"""slip_inference's model kinds: which predictor a checkpoint gets, and the streaming step.

Window checkpoints (CNN, SVM) get a ``learn.predictor.Predictor`` and run on the node's
model thread. ``aslip_stream`` checkpoints get a ``learn.streaming_predictor.
StreamingPredictor`` driven by :class:`StreamStep` inside the audio callback: a hop costs
~0.1 ms, less than handing the block to another thread and waking it, and the recurrent
state must see every block in order (a window can supersede a waiting one; a stream
cannot skip audio).

Streaming in the node: the stream is gated, refused and counted as for a window model; each
accepted block goes through ``StreamingPredictor.feed`` and every 10 ms hop it completes is
published (not only the newest: the state computed them anyway, and a controller or a
recorder gets the whole track), stamped at the hop's frame's last sample with
``window_length`` the 32 ms frame. ``hop_s`` does not apply (the checkpoint's hop is). A
gap, a time jump, a new stream, a dropped block (malformed, non-finite, not the
checkpoint's stream) or a block with a dead channel resets the features and the recurrent
state, at most once until audio is fed again.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

from aslip_ros.learn.channel_check import DEAD_MARGIN_DB, dead_channels
from aslip_ros.nodes import common as c
from aslip_ros.nodes import convert


def load_predictor(path: str, max_time_jump_s: float):
    """The predictor for the checkpoint at ``path``: the model registry says whether its
    model streams (``learn.backends``); OSError / ValueError when unusable."""
    from aslip_ros.learn.backends import model_backend
    from aslip_ros.learn.checkpoint import load_checkpoint
    from aslip_ros.learn.predictor import Predictor
    ckpt = load_checkpoint(path)
    backend = model_backend(ckpt.model_type)
    if backend.streaming:
        return backend.from_checkpoint(ckpt, max_time_jump_s=max_time_jump_s)
    return Predictor(ckpt)


@dataclass
class StreamStats:
    """What the node counts about its input and output (reported in its diagnostics)."""

    drops: collections.Counter = field(default_factory=collections.Counter)  # per reason
    blocks_in: int = 0
    blocks_ok: int = 0
    frames_lost: int = 0
    gaps: int = 0
    stream_restarts: int = 0
    published: int = 0
    dead_windows: int = 0                 # windows withheld for a dead channel
    hops_superseded: int = 0
    #: AudioFrame received -> SlipVector published [s], and block arrival times.
    latency: collections.deque = field(default_factory=lambda: collections.deque(maxlen=2000))
    arrivals: collections.deque = field(default_factory=lambda: collections.deque(maxlen=500))
    last_error: str = ""
    refusal: str = ""
    dead_recent: set = field(default_factory=set)   # dead channels since the last diagnostics


def inference_params() -> list:
    """The node's parameters, with their ranges."""
    return [
        c.Param("checkpoint", "", "model checkpoint (.pt) from `aslip train`", c.non_empty,
                read_only=True),
        c.Param("hop_s", 0.01, "run the model every hop_s of new audio [s]",
                c.in_range(0.001, 1.0)),
        c.Param("threshold", -1.0, "slip probability threshold; -1 = the checkpoint's",
                c.off_or(-1.0, c.in_range(0.0, 1.0), "the checkpoint's")),
        c.Param("max_time_jump_s", 0.05,
                "a stamp this far off its sample index is a time jump [s]", c.positive),
        c.Param("frame_id", convert.GRASP_FRAME, "frame of the published slip",
                c.non_empty, read_only=True),
        c.Param("marker_scale_s", 2.0, "rviz arrow length per slip speed [m per m/s]",
                c.positive),
        c.Param("torch_threads", 1, "CPU threads for the model",
                c.int_range(1, 64), read_only=True),
        c.Param("diagnostics_period_s", 1.0, "diagnostics period [s]",
                c.in_range(0.05, 60.0), read_only=True),
        c.Param("dead_channel_margin_db", DEAD_MARGIN_DB,
                "withhold the estimate when a channel is this far below the median of "
                "the others or digitally silent [dB]; 0 = no check",
                c.off_or(0.0, c.in_range(20.0, 120.0), "off")),
    ]


class StreamStep:
    """One accepted block through a StreamingPredictor, with the node's dead-channel check.

    The node gates the stream with its own ``StreamGate`` (so drops, gaps and restarts are
    counted in one place) and calls :meth:`reset` wherever the window model would restart
    its window, and for a refused block: the next block no longer follows the state's audio.
    """

    def __init__(self, predictor) -> None:
        self.predictor = predictor
        predictor.warm_up()

    def reset(self, reason: str) -> None:
        """Forget the features and state (once: a reset with nothing fed since is no reset)."""
        if not self.predictor.fresh:
            self.predictor.reset(reason)

    def block(self, a, source: str, frame_id: str, dead_margin_db: float) -> tuple[list, list]:
        """``(SlipVectors, dead channels)`` for one accepted block: one message per hop it
        completes, stamped at the hop's last sample (``dead_margin_db`` 0: no dead-channel
        check). A block with a dead channel gives none
        and resets the state: a state that has read a dead microphone would under-report
        slip for an unknown time after the microphone came back. ValueError (state reset,
        nothing to publish) if an estimate is not finite: it would stay in the state."""
        pr = self.predictor
        dead = dead_channels(a.block, pr.channel_names, dead_margin_db) \
            if dead_margin_db > 0 else []
        if dead:
            self.reset(f"dead channel(s) {', '.join(dead)}")
            return [], dead
        msgs = []
        for est in pr.feed(a):
            e = est.prediction
            try:
                msgs.append(convert.slip_to_msg(e.vx, e.vz, e.probability, e.slipping,
                                                e.threshold, est.stamp_ns, e.window_length,
                                                source, frame_id,
                                                direction_sigma=e.direction_sigma))
            except ValueError:
                self.reset("non-finite estimate")
                raise
        return msgs, []
