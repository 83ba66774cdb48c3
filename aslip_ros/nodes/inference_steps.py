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

from aslip_ros.learn.channel_check import dead_channels
from aslip_ros.nodes import convert

STREAM_MODEL = "aslip_stream"


def load_predictor(path: str, max_time_jump_s: float):
    """The predictor for the checkpoint at ``path``; OSError / ValueError when unusable."""
    from aslip_ros.learn.checkpoint import load_checkpoint
    ckpt = load_checkpoint(path)
    if ckpt.model_type == STREAM_MODEL:
        from aslip_ros.learn.streaming_predictor import StreamingPredictor
        return StreamingPredictor(ckpt, max_time_jump_s=max_time_jump_s)
    from aslip_ros.learn.predictor import Predictor
    return Predictor.from_checkpoint(path)


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
                                                source, frame_id))
            except ValueError:
                self.reset("non-finite estimate")
                raise
        return msgs, []
