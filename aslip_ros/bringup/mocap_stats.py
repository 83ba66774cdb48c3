"""Rate, jitter, dropouts and latency of a motion-capture stream, from receive times and
header stamps (``aslip check mocap``; ROS-free, the node part is
:mod:`aslip_ros.nodes.mocap_check`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from aslip_ros.bringup.verdict import Verdict

#: Slower than this, the 200 ms label windows see too few poses (docs/data.md).
MIN_RATE_HZ = 30.0
#: A gap longer than this many median periods is a dropout.
GAP_FACTOR = 3.0
#: A latency outside [0, this] means the two clocks are not synchronised.
MAX_LATENCY_S = 0.5


@dataclass(frozen=True)
class StreamStats:
    """One topic's numbers (SI: Hz, seconds)."""

    topic: str
    count: int
    rate_hz: float = 0.0
    jitter_s: float = 0.0
    dropouts: int = 0
    longest_gap_s: float = 0.0
    latency_median_s: float = float('nan')
    latency_p95_s: float = float('nan')
    latency_min_s: float = float('nan')
    frame_ids: tuple = ()

    @property
    def clocks_unsynchronised(self) -> bool:
        """A negative latency, or one beyond :data:`MAX_LATENCY_S`."""
        return self.count > 0 and (self.latency_min_s < 0.0
                                   or self.latency_p95_s > MAX_LATENCY_S)

    def text(self) -> str:
        """Human-readable lines (ms where a person reads them)."""
        if not self.count:
            return f'{self.topic}: no messages'
        return (f'{self.topic}: {self.count} messages, {self.rate_hz:.1f} Hz, jitter '
                f'{self.jitter_s * 1e3:.2f} ms, {self.dropouts} dropout(s) (longest gap '
                f'{self.longest_gap_s * 1e3:.1f} ms), latency median '
                f'{self.latency_median_s * 1e3:.1f} ms p95 {self.latency_p95_s * 1e3:.1f} '
                f'ms, frame_id {", ".join(self.frame_ids) or "(empty)"}')


def stream_stats(topic: str, receive_ns: Sequence[int], stamp_ns: Sequence[int],
                 frame_ids: Sequence[str] = ()) -> StreamStats:
    """The numbers of one stream, messages in arrival order.

    Rate and dropouts come from the header stamps (the source's own clock: the mocap's rate,
    not the network's); where the stamps do not advance (a driver that leaves them zero)
    from the receive times. Jitter is the standard deviation of the arrival intervals.
    """
    recv = np.asarray(receive_ns, dtype=np.int64)
    stamp = np.asarray(stamp_ns, dtype=np.int64)
    if recv.shape != stamp.shape:
        raise ValueError(f'{len(recv)} receive times for {len(stamp)} stamps')
    ids = tuple(sorted(set(str(f) for f in frame_ids)))
    if recv.size == 0:
        return StreamStats(topic, 0, frame_ids=ids)
    latency = (recv - stamp) * 1e-9
    lat = dict(latency_median_s=float(np.median(latency)),
               latency_p95_s=float(np.percentile(latency, 95)),
               latency_min_s=float(latency.min()))
    if recv.size < 2:
        return StreamStats(topic, int(recv.size), frame_ids=ids, **lat)
    arrivals = np.diff(recv) * 1e-9
    periods = np.diff(np.sort(stamp)) * 1e-9
    if not np.any(periods > 0):
        periods = arrivals
    positive = periods[periods > 0]
    median = float(np.median(positive)) if positive.size else 0.0
    return StreamStats(
        topic, int(recv.size), rate_hz=1.0 / median if median > 0 else 0.0,
        jitter_s=float(np.std(arrivals)),
        dropouts=int(np.sum(periods > GAP_FACTOR * median)) if median > 0 else 0,
        longest_gap_s=float(periods.max()), frame_ids=ids, **lat)


def mocap_verdict(stats: Mapping[str, StreamStats],
                  min_rate_hz: float = MIN_RATE_HZ, missing_bodies: str = "") -> Verdict:
    """FAIL on a silent or slow stream or one with dropouts; unsynchronised clocks and
    differing frames fail too (the labels compare stamps and poses across the streams), and
    so does a rigid body missing from RigidBodies messages (``missing_bodies``, which names
    the bodies that are there: :class:`aslip_ros.rigid_bodies.BodyTally`)."""
    verdict = Verdict()
    if missing_bodies:
        verdict.fail(f'{missing_bodies}: is the body tracked, and named as the driver names '
                     'it (OptiTrack: the Motive ID)?')
    for topic, s in stats.items():
        if s.count == 0:
            verdict.fail(f'no messages on {topic}: is the mocap driver running and the rigid '
                         'body tracked? (ros2 topic list / ros2 topic hz)')
            continue
        if s.count < 2 or s.rate_hz < min_rate_hz:
            verdict.fail(f'{topic} at {s.rate_hz:.1f} Hz, below {min_rate_hz:g} Hz: raise the '
                         'mocap rate or check that the rigid body is tracked all the time')
        if s.dropouts:
            verdict.fail(f'{topic}: {s.dropouts} dropout(s), longest gap '
                         f'{s.longest_gap_s * 1e3:.0f} ms: occlusion or a lossy network')
        if s.clocks_unsynchronised:
            verdict.fail(f'{topic}: latency {s.latency_min_s * 1e3:.0f} .. '
                         f'{s.latency_p95_s * 1e3:.0f} ms: the mocap and this computer\'s '
                         'clocks look unsynchronised (chrony/PTP, or the driver\'s time '
                         'stamping option)')
    frames = {s.frame_ids for s in stats.values() if s.count}
    if len(frames) > 1:
        verdict.fail('the streams are in different frames '
                     f'({"; ".join(", ".join(f) for f in sorted(frames))}): both must be '
                     'in the mocap world frame')
    return verdict
