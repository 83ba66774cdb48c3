"""Export rosbags to the windowed training dataset (library and ``aslip export``).

Everything about the recording comes from the bag: sample rate, channels from the
``AudioFrame`` messages (or audio_common's ``audio_stamped`` + ``audio_info``, read as the
AudioFrames audio_capture makes of them: :mod:`aslip_ros.data.audio_common`; a bag without
``/aslip/audio`` and with one such topic is read from it), pose rates from the stamps;
scenario fields, calibrations and pose topic names from the metadata
(``custom_data['aslip']`` or the metadata topic; without it: mocap labels, identity
calibration, trial id = the bag's name, the rest ``"unknown"``).

Windows follow a regular grid in the audio stream's sample index: window ``n =
round(window_s * sample_rate)`` frames every ``hop = round(hop_s * sample_rate)`` frames
from the first received sample. A window is kept when all its samples were received and it
has a label; otherwise it is dropped and counted under one reason:

- ``audio_gap``: the window touches samples missing from the stream
  (``first_sample_index`` jumped);
- ``label_gap``: a pose stream has a dropout longer than ``max_gap_s`` over the window;
- ``label_coverage``: the window is outside the pose streams' time span.

Labels (``data.labels``): the planar slip velocity (``vx``, ``vz``: the pad centre's, m/s),
the rotational slip ``wy`` about the pad normal (rad/s), the planar speed and
``slip = speed > epsilon``. Motion-capture labels read the window's ends from the object's
pose relative to the finger smoothed over ``label_smoothing_s`` (150 ms; the manifest
records it); robot-state labels from the arm's own poses as reported.

Audio time: the block stamps (time of each block's first sample) are fitted by a line in
the sample index, which averages out host-clock jitter and follows a slightly off nominal
rate. Labels use header stamps (log time where a stamp is zero).

Any error leaves no dataset behind (it is built in a temporary directory and renamed).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from aslip_ros.slip import ANGULAR_COMPONENT, VELOCITY_COMPONENTS
from aslip_ros.data.bags import (CUSTOM_DATA_KEY, DEFAULT_TOPICS, POSE_TOPICS, BagDamaged,
                                 BagError, BagReader, Topics, find_bags)
from aslip_ros.data.audio_common import audio_topic_in
from aslip_ros.data.dataset import WINDOW_DTYPE, DatasetWriter
from aslip_ros.data.export_bench import measure_export_speed  # noqa: F401 (public name)
from aslip_ros.data.export_read import (AudioClock, BagStreams, StreamFormat, WindowGrid,
                                        fit_clock, read_streams, window_grid)
from aslip_ros.data.labels import (DEFAULT_EPSILON_M_S, DEFAULT_HOP_S,
                                   DEFAULT_LABEL_SMOOTHING_S, DEFAULT_MAX_GAP_S,
                                   DEFAULT_WINDOW_S, IDENTITY_POSE, OK, REASONS,
                                   mocap_window_velocity, robot_window_velocity)
from aslip_ros.data.stream_labels import export_track, write_track
from aslip_ros.poses import as_pose

LABEL_SOURCES = ("auto", "mocap", "robot")
UNKNOWN = "unknown"
DROP_REASONS = ("audio_gap",) + tuple(REASONS.values())


@dataclass(frozen=True)
class ExportConfig:
    """Export parameters (SI units)."""

    window_s: float = DEFAULT_WINDOW_S
    hop_s: float = DEFAULT_HOP_S
    epsilon_m_s: float = DEFAULT_EPSILON_M_S
    label_source: str = "auto"
    max_gap_s: float = DEFAULT_MAX_GAP_S
    # Motion-capture labels read from poses smoothed over this long (0: the raw poses).
    label_smoothing_s: float = DEFAULT_LABEL_SMOOTHING_S
    topics: Topics = DEFAULT_TOPICS
    topics_given: tuple = ()    # pose topics given: the others as a bag's metadata names them
    # The finger's and object's bodies in a topic of mocap4r2 RigidBodies ('': as a bag's
    # metadata names them, its "bodies": {"finger": .., "object": ..}).
    finger_body: str = ""
    object_body: str = ""
    overwrite: bool = False
    skip_bad: bool = False
    recover: bool = False
    progress: bool = True
    jobs: int = 1               # bags read in this many processes (the dataset is the same)

    def validate(self) -> None:
        """Raise ValueError on parameters that cannot produce a dataset."""
        for name in ("window_s", "hop_s", "max_gap_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {v!r}")
        if not (math.isfinite(self.epsilon_m_s) and self.epsilon_m_s >= 0):
            raise ValueError(f"epsilon_m_s must be >= 0 m/s, got {self.epsilon_m_s!r}")
        if not (isinstance(self.label_smoothing_s, (int, float))
                and 0 <= self.label_smoothing_s <= 1):
            raise ValueError(f"label_smoothing_s must be in [0, 1] s, got "
                             f"{self.label_smoothing_s!r}")
        if not (isinstance(self.jobs, int) and self.jobs >= 1):
            raise ValueError(f"jobs must be a whole number >= 1, got {self.jobs!r}")
        if self.label_source not in LABEL_SOURCES:
            raise ValueError(f"label_source must be one of {LABEL_SOURCES}, "
                             f"got {self.label_source!r}")


def labelled_as(dataset: str | os.PathLike, cfg: ExportConfig) -> bool:
    """Whether the exported dataset at ``dataset`` read its labels as ``cfg`` would: from
    poses smoothed over the same span (one exported before the smoothing existed read the
    raw poses and has no ``label_smoothing_s``). False when it has no readable manifest."""
    try:
        man = json.loads((Path(dataset) / "manifest.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(man, dict) and man.get("label_smoothing_s", 0.0) == cfg.label_smoothing_s


@dataclass
class BagResult:
    """What one bag contributed."""

    bag: str
    trial_id: str = ""
    label_source: str = ""
    audio_s: float = 0.0
    kept: int = 0
    dropped: dict = field(default_factory=dict)
    refused_blocks: dict = field(default_factory=dict)
    body_notes: list = field(default_factory=list)
    error: str = ""


@dataclass
class ExportSummary:
    """Totals of an export; ``str()`` gives the human-readable report."""

    dataset: str
    sample_rate: float = 0.0
    channel_names: list = field(default_factory=list)
    layout: str = ""
    bags: list = field(default_factory=list)
    kept: int = 0
    dropped: dict = field(default_factory=dict)
    audio_s: float = 0.0
    elapsed_s: float = 0.0
    warnings: list = field(default_factory=list)
    worker_peak_rss_mib: float | None = None    # --jobs > 1: the largest worker's peak

    @property
    def realtime_factor(self) -> float:
        return self.audio_s / self.elapsed_s if self.elapsed_s > 0 else float("inf")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["realtime_factor"] = self.realtime_factor
        return d

    def __str__(self) -> str:
        ok = [b for b in self.bags if not b.error]
        bad = [b for b in self.bags if b.error]
        drops = ", ".join(f"{k} {v}" for k, v in self.dropped.items() if v) or "none"
        lines = [
            f"export: {len(ok)} bag(s) -> {self.dataset}",
            f"  audio: {self.sample_rate:g} Hz x {len(self.channel_names)} ch "
            f"({', '.join(self.channel_names)}), layout {self.layout or UNKNOWN!r}",
            f"  windows kept {self.kept}, dropped {sum(self.dropped.values())} ({drops})",
            f"  {self.audio_s:.1f} s of audio in {self.elapsed_s:.2f} s "
            f"({self.realtime_factor:.0f}x real time)",
        ]
        lines += [f"  skipped {b.bag}: {b.error}" for b in bad]
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


# ---------------------------------------------------------------------------------------


def _label_source(cfg: ExportConfig, meta: dict) -> str:
    if cfg.label_source != "auto":
        return cfg.label_source
    return "robot" if meta.get("induced") == "robot" else "mocap"


def _label_topics(cfg: ExportConfig, source: str) -> dict:
    t = cfg.topics
    return {"tcp": t.tcp} if source == "robot" else {"finger": t.finger, "object": t.object}


def _bodies(cfg: ExportConfig, meta: dict) -> dict:
    """The finger's and object's rigid bodies: given, else as the metadata names them."""
    named = meta.get("bodies") if isinstance(meta.get("bodies"), dict) else {}
    given = {"finger": cfg.finger_body, "object": cfg.object_body}
    return {r: str(given[r] or named.get(r) or "") for r in given}


def _calibration(meta: dict, key: str, bag: Path) -> np.ndarray:
    value = meta.get(key)
    if value is None:
        return IDENTITY_POSE.copy()
    try:
        return as_pose(value, key)
    except ValueError:
        raise BagError(f"bag {bag}: metadata {key} must be a pose x y z qx qy qz qw, "
                       f"got {value!r}") from None


def _window_labels(rec: BagStreams, meta: dict, cfg: ExportConfig, source: str,
                   clock: AudioClock, grid: WindowGrid):
    """Labels of every window, the label stream's rate, and the streaming-label track."""
    topics, path = cfg.topics, rec.path
    t0 = clock.time_of(grid.starts)
    t1 = t0 + grid.n_win * clock.slope
    track = {r: buf.track(clock.ref_ns, getattr(topics, r)) for r, buf in rec.poses.items()}
    if source == "robot":
        calib = _calibration(meta, "grasp_plane_in_tcp", path)
        labels = robot_window_velocity(track["tcp"], t0, t1, calib, cfg.max_gap_s)
        rate = track["tcp"].rate_hz
    else:
        calib = _calibration(meta, "grasp_plane_in_finger", path)
        labels = mocap_window_velocity(track["finger"], track["object"], t0, t1,
                                       calib, cfg.max_gap_s, cfg.label_smoothing_s)
        rate = track["finger"].rate_hz
    # The object-relative pose track on the audio file's sample axis: streaming labels.
    s_first = int(rec.seg_start[0])
    stream_track = export_track(
        source, track["tcp" if source == "robot" else "finger"], calib,
        None if source == "robot" else track["object"], clock.intercept, clock.slope,
        float(s_first - clock.idx0))
    return labels, rate, stream_track


def _window_rows(labels, grid: WindowGrid, cfg: ExportConfig) -> tuple[np.ndarray, dict]:
    """The kept windows' rows and the count of dropped ones by reason."""
    dropped = Counter()
    dropped["audio_gap"] = int((~grid.audio_ok).sum())
    for code, name in REASONS.items():
        dropped[name] = int((grid.audio_ok & (labels.reason == code)).sum())
    keep = grid.audio_ok & (labels.reason == OK)
    rows = np.zeros(int(keep.sum()), dtype=WINDOW_DTYPE)
    rows["start"] = grid.file_pos[keep]
    for name, column in zip(VELOCITY_COMPONENTS, labels.slip_velocity.T):
        rows[name] = column[keep]
    rows[ANGULAR_COMPONENT] = labels.angular[keep]
    speed = labels.speed[keep]
    rows["speed"] = speed
    rows["slip"] = speed > cfg.epsilon_m_s
    return rows, {k: int(dropped[k]) for k in DROP_REASONS}


def _trial_info(meta: dict, rec: BagStreams, res: BagResult, clock: AudioClock,
                rate: float) -> dict:
    s_first = int(rec.seg_start[0])
    return {
        "object": meta.get("object") or UNKNOWN, "pad": meta.get("pad") or UNKNOWN,
        "layout": meta.get("layout") or rec.layout or "",
        "condition": meta.get("condition") or UNKNOWN,
        "induced": meta.get("induced") or UNKNOWN,
        "source_bag": str(rec.path), "label_source": res.label_source,
        "seed": meta.get("seed"), "label_rate_hz": round(rate, 3),
        "dropped": res.dropped, "audio_gaps": len(rec.seg_start) - 1,
        "has_metadata": bool(meta),
        # Which scene defaults rendered a simulated bag (None for recorded ones).
        "scene_version": meta.get("scene_version"),
        # Where the stored audio starts in the recorded stream, so windows can be put back
        # on the stream's clock (file position p of a gap-free trial is stream sample
        # first_sample_index + p, stamped start_stamp_ns + p / sample_rate).
        "first_sample_index": s_first,
        "start_stamp_ns": int(clock.ref_ns + round(clock.time_of(s_first) * 1e9)),
    }


def _export_bag(reader: BagReader, meta: dict, cfg: ExportConfig, writer: DatasetWriter,
                stream: StreamFormat, bar) -> tuple[BagResult, dict]:
    """One bag -> one trial: read, fit the audio clock, lay the window grid, label, keep."""
    source = _label_source(cfg, meta)
    res = BagResult(bag=str(reader.path), label_source=source)
    rec = read_streams(reader, cfg.topics.audio, _label_topics(cfg, source), writer, stream,
                       bar, source, _bodies(cfg, meta))
    res.refused_blocks = dict(rec.refused)
    res.body_notes = list(rec.body_notes)
    clock = fit_clock(rec)
    grid = window_grid(rec, cfg.window_s, cfg.hop_s)
    labels, rate, track = _window_labels(rec, meta, cfg, source, clock, grid)
    rows, res.dropped = _window_rows(labels, grid, cfg)
    res.kept = int(rows.size)
    res.audio_s = rec.audio.n_frames / rec.sample_rate
    return res, {"info": _trial_info(meta, rec, res, clock, rate), "rows": rows,
                 "track": track}


def no_metadata_note(bag: Path, info: dict, cfg: ExportConfig) -> str:
    """What a bag without metadata was exported with: what came from the data, and the
    defaults that stand in for the rest (a recording whose metadata was lost says so)."""
    return (f"bag {bag} has no metadata (no custom_data[{CUSTOM_DATA_KEY!r}] and no message "
            f"on {cfg.topics.metadata}). From the data: sample rate, channel names"
            f"{' and layout' if info.get('layout') else ''} (the AudioFrames), label rate "
            f"{info['label_rate_hz']:g} Hz ({info['label_source']} poses). Defaults: labels "
            f"from {info['label_source']}, identity grasp-plane calibration, trial id "
            f"{_bag_name(bag)!r} (the bag's name), object, pad, condition and induced "
            f"{UNKNOWN!r}. Record the metadata (data_collection.launch.py does) or check "
            "these before training")


def _bag_name(path: Path) -> str:
    return path.stem if path.is_file() else path.name


def _read_bag(reader: BagReader, cfg: ExportConfig, writer: DatasetWriter, stream: StreamFormat,
              bar) -> tuple[dict, BagResult, dict]:
    with reader as r:
        meta = r.read_metadata(cfg.topics.metadata) or {}
        cfg = replace(cfg, topics=cfg.topics.named_in(meta, cfg.topics_given))
        audio = audio_topic_in(r, cfg.topics.audio, DEFAULT_TOPICS.audio)
        cfg = replace(cfg, topics=replace(cfg.topics, audio=audio))
        source = _label_source(cfg, meta)
        r.require([cfg.topics.audio], "audio")
        r.require(list(_label_topics(cfg, source).values()), f"labels from {source}")
        bar.set_postfix_str(_bag_name(r.path), refresh=False)
        res, trial = _export_bag(r, meta, cfg, writer, stream, bar)
    return meta, res, trial


def _export_or_recover(path: Path, cfg: ExportConfig, writer: DatasetWriter,
                       stream: StreamFormat, bar, warnings: list) -> tuple[dict, BagResult, dict]:
    """Export one bag. A damaged one (cut short, failing a CRC) is refused, or with
    ``cfg.recover`` its readable part is exported and a warning says what was lost."""
    try:
        return _read_bag(BagReader(path), cfg, writer, stream, bar)
    except BagDamaged as exc:
        writer.abort_trial()
        if not cfg.recover:
            raise BagDamaged(f"{exc}; --recover exports its readable part") from None
    from aslip_ros.data.recover import RecoveredBagReader
    reader = RecoveredBagReader(path)
    meta, res, trial = _read_bag(reader, cfg, writer, stream, bar)
    note = reader.report.describe(path)
    warnings.append(note)
    trial["info"]["recovered"] = note
    return meta, res, trial


def _bag_warnings(path: Path, res: BagResult) -> list:
    """What a summary says of an exported bag: refused AudioFrames, missing rigid bodies."""
    out = []
    if res.refused_blocks:
        out.append(f"bag {path}: {sum(res.refused_blocks.values())} AudioFrame(s) refused "
                   f"({', '.join(f'{k} {v}' for k, v in res.refused_blocks.items())}); "
                   "their windows are dropped as audio gaps")
    return out + res.body_notes


class _Shard:
    """What a worker process writes one bag's audio into: a file of the dataset being
    built (``root``), adopted by the parent's ``DatasetWriter`` in bag order."""

    def __init__(self, root: Path, i: int) -> None:
        self.path = root / "audio" / f".bag{i}.npy.part"
        self.audio = None

    def begin_trial(self, n_channels: int):
        from aslip_ros.data.dataset import AudioFileWriter
        self.audio = AudioFileWriter(self.path, n_channels)
        return self.audio

    def abort_trial(self) -> None:
        if self.audio is not None:
            self.audio.discard()
            self.audio = None


def _read_in_worker(i: int, path: Path, cfg: ExportConfig, root: Path) -> dict:
    """One bag read in a worker process of ``export(jobs=N)``: its audio written to the
    dataset's temporary directory, the rest returned (a BagError too)."""
    from tqdm import tqdm
    shard, stream, warnings = _Shard(root, i), StreamFormat(), []
    try:
        with tqdm(disable=True) as bar:
            meta, res, trial = _export_or_recover(path, cfg, shard, stream, bar, warnings)
    except BagError as exc:
        shard.abort_trial()
        return {"error": exc}
    shard.audio.close()
    from aslip_ros.util import peak_rss_mib
    return {"got": (meta, res, trial), "warnings": warnings, "audio": str(shard.path),
            "peak_rss_mib": peak_rss_mib(),
            "n_frames": shard.audio.n_frames,
            "format": (stream.sample_rate, stream.channel_names)}


def _bags_read(paths: list, cfg: ExportConfig, writer, stream: StreamFormat, bar,
               warnings: list, worker_peaks: list):
    """``(path, read)`` per bag in order: ``read()`` gives ``_export_or_recover``'s
    ``(meta, result, trial)`` with the trial's audio open in ``writer``, or raises its
    BagError. With ``cfg.jobs`` > 1 the bags are read ahead in that many processes, at most
    two per process at a time (memory stays bounded), and taken up here in order, so the
    dataset is the one a single job writes; ``worker_peaks`` gets each bag's worker's peak
    resident memory [MiB]."""
    if cfg.jobs == 1 or len(paths) == 1:
        for p in paths:
            yield p, lambda p=p: _export_or_recover(p, cfg, writer, stream, bar, warnings)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    def taken(p: Path, out: dict):
        if "error" in out:
            raise out["error"]
        try:
            stream.check(*out["format"], p)    # the first bag read fixes the format
        except BagError:
            Path(out["audio"]).unlink(missing_ok=True)
            raise
        writer.adopt_trial(out["audio"], out["n_frames"])
        warnings.extend(out["warnings"])
        worker_peaks.append(out["peak_rss_mib"])
        return out["got"]

    wcfg = replace(cfg, progress=False)
    pool = ProcessPoolExecutor(min(cfg.jobs, len(paths)),
                               mp_context=multiprocessing.get_context("spawn"))
    try:
        ahead: list = []
        for i, p in enumerate(paths):
            ahead.append((p, pool.submit(_read_in_worker, i, p, wcfg, writer.root)))
            while len(ahead) >= 2 * cfg.jobs or (ahead and i == len(paths) - 1):
                q, fut = ahead.pop(0)
                yield q, lambda q=q, out=fut.result(): taken(q, out)
    finally:
        # An error stops the export: the bags queued are dropped, the ones being read
        # are waited for (their files are in the dataset's directory, discarded with it).
        pool.shutdown(wait=True, cancel_futures=True)


def export(bags: Sequence[str | os.PathLike], out: str | os.PathLike,
           config: ExportConfig | None = None, **overrides: Any) -> ExportSummary:
    """Export ``bags`` (bag files/directories, or directories holding bags) to ``out``.

    ``overrides`` replace fields of ``config`` (e.g. ``window_s=0.1``). Raises ValueError
    (BagError for bag problems) with a message naming the bag and what is wrong; on any
    error no dataset is left at ``out``.
    """
    cfg = replace(config or ExportConfig(), **overrides)
    cfg.validate()
    t_start = time.perf_counter()
    paths = find_bags(bags)
    if not paths:
        raise ValueError(f"no rosbag2 bags found in {', '.join(map(str, bags))}")
    from tqdm import tqdm

    summary = ExportSummary(dataset=str(out))
    stream = StreamFormat()
    ids: Counter = Counter()
    layouts: dict[str, str] = {}
    with DatasetWriter(out, overwrite=cfg.overwrite) as writer, \
            tqdm(total=len(paths), desc="export", disable=not cfg.progress, leave=False,
                 bar_format="{l_bar}{bar}| {n:.1f}/{total} bags [{elapsed}<{remaining}"
                            "{postfix}]") as bar:
        peaks: list = []
        reads = contextlib.closing(_bags_read(paths, cfg, writer, stream, bar,
                                              summary.warnings, peaks))
        with reads as bags_read:
            for p, read in bags_read:
                done = bar.n
                try:
                    meta, res, trial = read()
                    bar.update(done + 1 - bar.n)
                except BagError as exc:
                    writer.abort_trial()
                    bar.update(done + 1 - bar.n)
                    if not cfg.skip_bad:
                        raise
                    summary.bags.append(BagResult(bag=str(p), error=str(exc)))
                    continue
                summary.warnings += _bag_warnings(p, res)
                info = trial["info"]
                if not meta:
                    summary.warnings.append(no_metadata_note(p, info, cfg))
                tid = str(meta.get("trial_id") or _bag_name(p))
                ids[tid] += 1
                if ids[tid] > 1:
                    summary.warnings.append(f"trial id {tid!r} repeats ({p}); renamed "
                                            f"{tid}~{ids[tid]}")
                    tid = f"{tid}~{ids[tid]}"
                info["id"] = res.trial_id = tid
                if info["layout"]:
                    layouts.setdefault(info["layout"], str(p))
                if len(layouts) > 1:
                    writer.abort_trial()
                    raise BagError(f"bag {p}: layouts differ within one dataset: "
                                   + ", ".join(f"{k!r} ({v})" for k, v in layouts.items()))
                write_track(writer.root, writer.end_trial(info, trial["rows"]), trial["track"])
                summary.bags.append(res)
        if stream.sample_rate is None:
            raise ValueError("no bag could be exported")
        summary.sample_rate = stream.sample_rate
        summary.channel_names = list(stream.channel_names)
        summary.layout = next(iter(layouts), "")
        ok = [b for b in summary.bags if not b.error]
        summary.kept = sum(b.kept for b in ok)
        summary.dropped = {k: sum(b.dropped.get(k, 0) for b in ok) for k in DROP_REASONS}
        summary.audio_s = sum(b.audio_s for b in ok)
        summary.worker_peak_rss_mib = max((p for p in peaks if p is not None), default=None)
        n_win = int(round(cfg.window_s * stream.sample_rate))
        writer.finish(
            sample_rate=stream.sample_rate, channel_names=list(stream.channel_names),
            layout=summary.layout, window_s=cfg.window_s, hop_s=cfg.hop_s,
            n_window_samples=n_win, hop_samples=int(round(cfg.hop_s * stream.sample_rate)),
            epsilon_m_s=cfg.epsilon_m_s, max_gap_s=cfg.max_gap_s,
            label_smoothing_s=cfg.label_smoothing_s, label_source=cfg.label_source,
            topics=asdict(cfg.topics), dropped=summary.dropped,
            skipped_bags=[b.bag for b in summary.bags if b.error], created_by="aslip export")
    summary.elapsed_s = time.perf_counter() - t_start
    return summary


# ---------------------------------------------------------------------------------------
# Command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``aslip export``."""
    parser.add_argument("bags", nargs="*", type=Path,
                        help="bag directories, .mcap files, or directories holding bags")
    parser.add_argument("-o", "--out", type=Path, help="dataset directory to create")
    parser.add_argument("--window", type=float, default=DEFAULT_WINDOW_S,
                        help="window length in s (paper: 0.1, 0.2, 0.3; default %(default)s)")
    parser.add_argument("--hop", type=float, default=DEFAULT_HOP_S,
                        help="hop between window starts in s (default %(default)s)")
    parser.add_argument("--epsilon", type=float, default=DEFAULT_EPSILON_M_S,
                        help="slip threshold on the window's mean speed in m/s "
                             "(default %(default)s)")
    parser.add_argument("--labels", choices=LABEL_SOURCES, default="auto",
                        help="label source: robot state for induced=robot, else motion "
                             "capture (auto), or forced")
    parser.add_argument("--max-gap", type=float, default=DEFAULT_MAX_GAP_S,
                        help="longest pose dropout bridged by interpolation in s "
                             "(default %(default)s)")
    parser.add_argument("--label-smoothing", type=float, default=DEFAULT_LABEL_SMOOTHING_S,
                        metavar="S", help="motion-capture labels from poses smoothed over S "
                        "seconds (a quadratic fit; 0: the raw poses at each window's ends; "
                        "default %(default)s)")
    for name in ("audio", "metadata", "finger", "object", "tcp"):     # poses: as recorded
        pose, default = name in POSE_TOPICS, getattr(DEFAULT_TOPICS, name)
        parser.add_argument(f"--{name}-topic", default=None if pose else default, help=(
            f"{name} topic (default: {'as the metadata names it, else ' * pose}{default})"))
    for name in ("finger", "object"):
        parser.add_argument(f"--{name}-body", default="", metavar="NAME_OR_ID", help=(
            f"the {name}'s rigid body where the poses are mocap4r2 RigidBodies: its "
            "rigid_body_name or numeric ID (default: as the metadata names it)"))
    parser.add_argument("--overwrite", action="store_true", help="replace an existing dataset")
    parser.add_argument("--skip-bad", action="store_true",
                        help="skip unreadable or inconsistent bags instead of failing")
    parser.add_argument("--recover", action="store_true",
                        help="export the readable part of a damaged bag (a recording cut "
                             "short by a crash, a chunk failing its CRC) instead of refusing "
                             "it; a warning says what was lost")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="read the bags in N processes (the dataset is the same as "
                             "with one; default %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--summary-json", type=Path, help="also write the summary as JSON")
    parser.add_argument("--bench", type=float, metavar="SECONDS", nargs="?", const=60.0,
                        help="measure export speed and peak memory on a synthetic bag of "
                             "this many seconds (48 kHz x 4 ch) and print JSON")


def run(args: argparse.Namespace) -> int:
    """Entry point of ``aslip export``."""
    if args.bench is not None:
        print(json.dumps(measure_export_speed(args.bench), indent=2))
        return 0
    if not args.bags or args.out is None:
        print("aslip export: give bags and -o/--out", file=sys.stderr)
        return 2
    cfg = ExportConfig(
        window_s=args.window, hop_s=args.hop, epsilon_m_s=args.epsilon,
        label_source=args.labels, max_gap_s=args.max_gap,
        label_smoothing_s=args.label_smoothing,
        topics=Topics(**{k: getattr(args, f"{k}_topic") or getattr(DEFAULT_TOPICS, k)
                         for k in ("audio", "metadata") + POSE_TOPICS}),
        topics_given=tuple(k for k in POSE_TOPICS if getattr(args, f"{k}_topic")),
        finger_body=args.finger_body, object_body=args.object_body,
        overwrite=args.overwrite, skip_bad=args.skip_bad, recover=args.recover,
        progress=not args.no_progress, jobs=args.jobs)
    try:
        summary = export(args.bags, args.out, cfg)
        print(summary)
        if args.summary_json:
            from aslip_ros.util import peak_rss_mib, write_json
            write_json(args.summary_json, dict(summary.to_dict(), peak_rss_mib=peak_rss_mib()))
    except (ValueError, OSError) as exc:        # OSError: a full disk, no permission...
        print(f"aslip export: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    p = argparse.ArgumentParser(prog="aslip export")
    add_arguments(p)
    sys.exit(run(p.parse_args()))
