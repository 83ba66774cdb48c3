"""The exporter's first steps: one pass over a bag, audio into the trial's file, poses into
compact buffers (:func:`read_streams`), with the dataset-wide audio format checked; then
the audio stream's clock (:func:`fit_clock`) and the window grid on its sample index
(:func:`window_grid`).

Audio blocks are checked by :func:`aslip_ros.audio_frame.decode_audio_frame`, the live
nodes' own check: a block a node would refuse (NaN/Inf, beyond full scale, empty) is left
out and counted, so its windows become audio gaps; a malformed stream (no channel names, a
changing format, an index going back) refuses the bag.

Poses come from PoseStamped topics or, for the finger and the object, from one topic of
mocap4r2 RigidBodies (the bodies named by :func:`aslip_ros.rigid_bodies.select_bodies`, the
live bridge's decoding): a body missing from some messages is a dropout of its track (the
export warns with the count), one missing from all of them refuses the bag, naming the
bodies that are there.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aslip_ros.audio_frame import AudioFrameError, decode_audio_frame
from aslip_ros.data.audio_common import AudioCommonFrames
from aslip_ros.data.bags import AUDIO_TYPE, POSE_TYPE, BagError, BagReader, stamp_to_ns
from aslip_ros.data.labels import PoseTrack
from aslip_ros.rigid_bodies import RIGID_BODIES_TYPE, ROLES, BodyTally, select_bodies

#: Defects of one AudioFrame that cost that block (as in the live node), not the bag.
REFUSED_BLOCKS = ("non_finite", "out_of_range", "empty")


class PoseBuffer:
    """Growable arrays of pose samples (stamp, log time, pose7): 72 bytes per pose rather
    than a Python object per value."""

    def __init__(self, capacity: int):
        capacity = max(16, int(capacity))
        self.n = 0
        self.stamp = np.zeros(capacity, np.int64)
        self.log = np.zeros(capacity, np.int64)
        self.pose = np.zeros((capacity, 7), np.float64)

    def append(self, stamp_ns: int, log_ns: int, pose: np.ndarray) -> None:
        if self.n == self.stamp.size:      # the index undercounted: grow geometrically
            grow = self.stamp.size
            self.stamp = np.concatenate([self.stamp, np.zeros(grow, np.int64)])
            self.log = np.concatenate([self.log, np.zeros(grow, np.int64)])
            self.pose = np.concatenate([self.pose, np.zeros((grow, 7))])
        self.stamp[self.n] = stamp_ns
        self.log[self.n] = log_ns
        self.pose[self.n] = pose
        self.n += 1

    def track(self, ref_ns: int, name: str) -> PoseTrack:
        """The samples as a :class:`PoseTrack` in seconds since ``ref_ns`` (header stamps,
        or log times where the driver left them zero)."""
        t_ns = self.stamp[:self.n]
        if not t_ns.any():
            t_ns = self.log[:self.n]
        return PoseTrack((t_ns - ref_ns) * 1e-9, self.pose[:self.n], name=name)


class StreamFormat:
    """Dataset-wide audio format, fixed by the first bag."""

    def __init__(self):
        self.sample_rate: float | None = None
        self.channel_names: tuple[str, ...] | None = None
        self.source = ""
        self.layouts: set[str] = set()

    def check(self, sample_rate: float, names: tuple[str, ...], bag: Path) -> None:
        if self.sample_rate is None:
            self.sample_rate, self.channel_names, self.source = sample_rate, names, str(bag)
            return
        if abs(sample_rate - self.sample_rate) > 1e-6 * self.sample_rate:
            raise BagError(f"bag {bag}: sample rate {sample_rate:g} Hz differs from "
                           f"{self.sample_rate:g} Hz of {self.source}; one dataset needs "
                           "one sample rate")
        if names != self.channel_names:
            raise BagError(f"bag {bag}: channel names {list(names)} differ from "
                           f"{list(self.channel_names)} of {self.source}; one dataset needs "
                           "one channel set")


@dataclass
class BagStreams:
    """What one pass over a bag gathered.

    Audio segments are the contiguous runs of the stream's sample index: each starts at
    stream index ``seg_start[k]``, at ``seg_file[k]`` in the trial's audio file, and is
    ``seg_len[k]`` frames long.
    """

    path: Path
    audio: object = None                  # the trial's audio file writer
    names: tuple = ()
    sample_rate: float = 0.0
    layout: str = ""
    blk_idx: list = field(default_factory=list)     # first sample index of each block
    blk_ns: list = field(default_factory=list)      # its header stamp
    blk_log: list = field(default_factory=list)     # its log time
    seg_start: list = field(default_factory=list)
    seg_file: list = field(default_factory=list)
    seg_len: list = field(default_factory=list)
    expected: int | None = None           # the index after the last block
    poses: dict = field(default_factory=dict)       # role (finger, object, tcp) -> PoseBuffer
    refused: Counter = field(default_factory=Counter)   # AudioFrames left out, by reason
    body_notes: list = field(default_factory=list)  # rigid bodies missing from messages

    def add_audio(self, msg, log_ns: int, writer, stream: StreamFormat) -> None:
        """One AudioFrame: appended to the trial's audio, or refused and counted."""
        path = self.path
        if self.audio is None:
            self.names = tuple(msg.channel_names)
            self.sample_rate = float(msg.sample_rate)
            self.layout = msg.layout
            if not self.names:
                raise BagError(f"bag {path}: AudioFrame without channel_names")
            if not (math.isfinite(self.sample_rate) and self.sample_rate > 0):
                raise BagError(f"bag {path}: AudioFrame sample_rate {self.sample_rate!r}")
            stream.check(self.sample_rate, self.names, path)
            self.audio = writer.begin_trial(len(self.names))
        elif float(msg.sample_rate) != self.sample_rate or \
                tuple(msg.channel_names) != self.names:
            raise BagError(f"bag {path}: sample rate or channel names change within the "
                           f"audio stream at first_sample_index {msg.first_sample_index}")
        try:
            block = decode_audio_frame(msg).block
        except AudioFrameError as exc:
            if exc.reason not in REFUSED_BLOCKS:
                raise BagError(f"bag {path}: {exc} (first_sample_index "
                               f"{msg.first_sample_index})") from None
            self.refused[exc.reason] += 1
            return
        idx = int(msg.first_sample_index)
        if self.expected is None or idx > self.expected:
            self.seg_start.append(idx)
            self.seg_file.append(self.audio.n_frames)
            self.seg_len.append(0)
        elif idx < self.expected:
            raise BagError(f"bag {path}: audio first_sample_index goes back from "
                           f"{self.expected} to {idx} (restarted capture?); split the bag")
        self.audio.append(block)
        self.seg_len[-1] += block.shape[0]
        self.expected = idx + block.shape[0]
        self.blk_idx.append(idx)
        self.blk_ns.append(stamp_to_ns(msg.header.stamp))
        self.blk_log.append(log_ns)


def _rigid_topics(reader: BagReader, roles_of: dict, bodies: dict) -> dict:
    """topic -> {role: body} for each finger or object topic that holds RigidBodies (the
    TCP's must be PoseStamped); BagError where a body is not named, naming the bodies of
    the topic's first message."""
    out = {}
    for topic, roles in roles_of.items():
        if reader.info.topics.get(topic) != RIGID_BODIES_TYPE or \
                not set(roles) <= set(ROLES):
            continue
        unnamed = [r for r in roles if not str(bodies.get(r) or "").strip()]
        if unnamed:
            first = next(iter(reader.messages([topic])), None)
            present = ", ".join(repr(b.rigid_body_name) for b in first.msg.rigidbodies) \
                if first is not None else "none"
            raise BagError(f"bag {reader.path}: topic {topic} holds {RIGID_BODIES_TYPE}: "
                           f"name the {' and '.join(unnamed)} bod"
                           f"{'ies' if len(unnamed) > 1 else 'y'} "
                           f"({' '.join(f'--{r}-body' for r in unnamed)}, or 'bodies' in "
                           f"the recording's metadata); bodies in its first message: "
                           f"{present}")
        out[topic] = {r: str(bodies[r]) for r in roles}
    return out


def read_streams(reader: BagReader, audio_topic: str, label_topics: dict, writer,
                 stream: StreamFormat, bar, label_source: str,
                 bodies: dict | None = None) -> BagStreams:
    """Read the audio and pose topics of ``reader`` once; BagError when either is unusable.

    ``label_topics``: role (finger, object, tcp) -> topic; a finger or object topic of
    RigidBodies gives the body that ``bodies`` names for the role. ``bar`` (tqdm) advances
    by fractions of one bag as the messages go by.
    """
    path = reader.path
    # audio_common's audio (audio_stamped + audio_info): read as the AudioFrames it makes.
    pcm = AudioCommonFrames(reader, audio_topic, reader.metadata or {}) \
        if reader.info.topics.get(audio_topic) == AudioCommonFrames.msgtype else None
    roles_of: dict = {}
    for role, topic in label_topics.items():
        roles_of.setdefault(topic, []).append(role)
    rigid = _rigid_topics(reader, roles_of, bodies or {})
    tallies = {t: BodyTally(b) for t, b in rigid.items()}
    rec = BagStreams(path=path, poses={r: PoseBuffer(reader.info.counts.get(t, 0))
                                       for r, t in label_topics.items()})
    wanted = [audio_topic] + list(roles_of)
    n_msgs = max(1, sum(reader.info.counts.get(t, 0) for t in wanted))
    pending = 0
    for m in reader.messages(wanted, fast_poses=True):
        pending += 1
        if pending >= 512:
            bar.update(pending / n_msgs)
            pending = 0
        expected_type = (pcm.msgtype if pcm else AUDIO_TYPE) if m.topic == audio_topic else \
            RIGID_BODIES_TYPE if m.topic in rigid else POSE_TYPE
        if m.msgtype != expected_type:
            raise BagError(f"bag {path}: topic {m.topic} holds {m.msgtype}, expected "
                           f"{expected_type}")
        if m.topic == audio_topic:
            rec.add_audio(pcm.frame(m.msg) if pcm else m.msg, m.log_ns, writer, stream)
        elif m.topic in rigid:
            sel = select_bodies(m.msg, rigid[m.topic])
            tallies[m.topic].add(sel)
            for role, pose in sel.poses.items():
                rec.poses[role].append(sel.stamp_ns, m.log_ns, pose)
        else:
            for role in roles_of[m.topic]:
                rec.poses[role].append(m.msg.stamp_ns, m.log_ns, m.msg.pose)
    bar.update(pending / n_msgs)
    if rec.audio is None:
        raise BagError(f"bag {path}: no messages on audio topic {audio_topic}")
    if not rec.blk_idx:
        raise BagError(f"bag {path}: every AudioFrame was refused ({dict(rec.refused)})")
    notes = {t: tally.text(f"RigidBodies messages on {t}") for t, tally in tallies.items()}
    for role, buf in rec.poses.items():
        if buf.n < 2:
            t = label_topics[role]
            if notes.get(t):
                raise BagError(f"bag {path}: {notes[t]}; labels from {label_source} need "
                               "both bodies")
            raise BagError(f"bag {path}: topic {t} has {buf.n} message(s); labels from "
                           f"{label_source} need a pose stream")
    rec.body_notes = [f"bag {path}: {n}; their windows lack that pose (a dropout)"
                      for n in notes.values() if n]
    return rec


# --------------------------------------------------------------------------- the audio axis

def audio_clock(idx: np.ndarray, stamps_ns: np.ndarray, sample_rate: float,
                ref_ns: int):
    """Return (intercept_s, slope_s_per_sample): t(i) = intercept + (i - idx[0]) * slope."""
    x = (idx - idx[0]).astype(np.float64)
    y = (stamps_ns - ref_ns).astype(np.float64) * 1e-9
    nominal = 1.0 / sample_rate
    if x.size >= 2 and x[-1] > 0:
        slope, intercept = np.polyfit(x, y, 1)
        # A fit far from the nominal rate means bad stamps, not a slow ADC: fall back.
        if abs(slope * sample_rate - 1.0) < 0.01:
            return float(intercept), float(slope)
    return float(np.median(y - x * nominal)), nominal


@dataclass(frozen=True)
class AudioClock:
    """Host time of the stream's samples: ``t(i) = intercept + (i - idx0) * slope`` [s since
    ``ref_ns``]."""

    ref_ns: int
    idx0: int
    intercept: float
    slope: float

    def time_of(self, index):
        return self.intercept + (index - self.idx0) * self.slope


def fit_clock(rec: BagStreams) -> AudioClock:
    idx = np.asarray(rec.blk_idx, dtype=np.int64)
    stamps = np.asarray(rec.blk_ns, dtype=np.int64)
    if not stamps.any():           # unstamped driver: the recorder's clock is all we have
        stamps = np.asarray(rec.blk_log, dtype=np.int64)
    ref_ns = int(stamps[0])
    intercept, slope = audio_clock(idx, stamps, rec.sample_rate, ref_ns)
    return AudioClock(ref_ns, int(idx[0]), intercept, slope)


@dataclass(frozen=True)
class WindowGrid:
    """Window starts on the stream's sample index, whether all their audio was received,
    and where they start in the trial's audio file."""

    n_win: int
    starts: np.ndarray
    audio_ok: np.ndarray
    file_pos: np.ndarray


def window_grid(rec: BagStreams, window_s: float, hop_s: float) -> WindowGrid:
    n_win = int(round(window_s * rec.sample_rate))
    hop = int(round(hop_s * rec.sample_rate))
    if n_win < 1 or hop < 1:
        raise BagError(f"window {window_s} s / hop {hop_s} s is below one sample at "
                       f"{rec.sample_rate:g} Hz")
    starts = np.arange(int(rec.seg_start[0]), int(rec.expected) - n_win + 1, hop,
                       dtype=np.int64)
    seg_s = np.asarray(rec.seg_start, dtype=np.int64)
    seg_n = np.asarray(rec.seg_len, dtype=np.int64)
    seg_f = np.asarray(rec.seg_file, dtype=np.int64)
    j = np.searchsorted(seg_s, starts, side="right") - 1
    return WindowGrid(n_win, starts, starts + n_win <= seg_s[j] + seg_n[j],
                      seg_f[j] + (starts - seg_s[j]))
