"""The windowed training dataset on disk (docs/design.md, "Dataset on disk").

::

    <dataset>/manifest.json   format "aslip-dataset" v2 (see :func:`Dataset` attributes)
    <dataset>/audio/<k>.npy   float32 (n_samples, n_channels) of trial k, memory-mappable
    <dataset>/windows.npy     structured array WINDOW_DTYPE, one row per window

A window row names its trial (index into ``manifest["trials"]``) and the first sample of
the window in that trial's audio file; the window is the next ``n_window_samples`` frames.
Labels are the mean slip velocity over the window in the grasp plane (m/s), the mean
rotational slip ``wy`` about the pad normal (rad/s) and ``slip = speed > epsilon_m_s``
(planar). Version 1 datasets (no ``wy`` column) still load: their rows are read into the
current dtype with ``wy`` NaN, "no angular label".

:class:`DatasetWriter` builds a dataset in a temporary directory beside the target and
renames it into place only when everything succeeded, so a failed export leaves nothing.
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from aslip_ros.slip import ANGULAR_COMPONENT, VELOCITY_COMPONENTS
from aslip_ros.util import atomic_path, read_json, write_json

FORMAT = "aslip-dataset"
VERSION = 2
#: One row per window: its trial and first sample, the slip velocity label (one column per
#: component of ``aslip_ros.slip.VELOCITY_COMPONENTS``, m/s), the rotational slip label
#: (``aslip_ros.slip.ANGULAR_COMPONENT``, rad/s; NaN: none), the planar speed and slip flag.
WINDOW_DTYPE = np.dtype([("trial", "<i4"), ("start", "<i8")]
                        + [(c, "<f4") for c in VELOCITY_COMPONENTS]
                        + [(ANGULAR_COMPONENT, "<f4")]
                        + [("speed", "<f4"), ("slip", "u1")])
#: The window rows of a version 1 dataset (before the rotational label).
WINDOW_DTYPE_V1 = np.dtype([d for d in WINDOW_DTYPE.descr if d[0] != ANGULAR_COMPONENT])
TRIAL_KEYS = ("id", "file", "n_samples", "object", "pad", "layout", "condition", "induced",
              "source_bag", "label_source")

# .npy v1.0 header reserved at the start of each streamed audio file: 128 bytes keeps the
# data 64-byte aligned and leaves room for any shape, so the header can be rewritten in
# place once the number of frames is known, without copying the data.
_NPY_HEADER_LEN = 128


def upgrade_windows(rows: np.ndarray) -> np.ndarray:
    """Window rows of any version as a new WINDOW_DTYPE array: columns copied by name, a
    rotational label the rows lack set to NaN."""
    rows = np.asarray(rows)
    if rows.dtype == WINDOW_DTYPE:
        return rows
    if rows.dtype != WINDOW_DTYPE_V1:
        raise ValueError(f"window rows have dtype {rows.dtype}, expected {WINDOW_DTYPE} "
                         f"(or version 1's {WINDOW_DTYPE_V1})")
    out = np.zeros(rows.shape, dtype=WINDOW_DTYPE)
    for name in WINDOW_DTYPE_V1.names:
        out[name] = rows[name]
    out[ANGULAR_COMPONENT] = np.nan
    return out


class DatasetWriteError(OSError):
    """The dataset could not be written (full disk, no permission...); names the dataset."""


@contextlib.contextmanager
def _writing(target: Path):
    """Turn an OSError while building ``target`` into one DatasetWriteError naming it."""
    try:
        yield
    except DatasetWriteError:
        raise
    except OSError as exc:
        err = DatasetWriteError(f"cannot write dataset {target}: "
                                f"{exc.strerror or exc}")
        err.errno = exc.errno
        raise err from None


def _npy_header(n_frames: int, n_channels: int) -> bytes:
    text = "{'descr': '<f4', 'fortran_order': False, 'shape': (%d, %d), }" % (
        n_frames, n_channels)
    body_len = _NPY_HEADER_LEN - 10
    if len(text) + 1 > body_len:
        raise ValueError(f"audio shape ({n_frames}, {n_channels}) too large for the header")
    body = (text.ljust(body_len - 1) + "\n").encode("latin1")
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(body)) + body


class AudioFileWriter:
    """Stream float32 frames into an ``.npy`` file of initially unknown length."""

    def __init__(self, path: str | os.PathLike, n_channels: int,
                 target: str | os.PathLike | None = None):
        if n_channels < 1:
            raise ValueError(f"n_channels must be >= 1, got {n_channels}")
        self.path = Path(path)
        # What a write error names: the dataset being built, not its temporary file.
        self.target = Path(target) if target is not None else self.path
        self.n_channels = int(n_channels)
        self.n_frames = 0
        with _writing(self.target):
            self._f = open(self.path, "wb")
            self._f.write(_npy_header(0, self.n_channels))

    def append(self, block: np.ndarray) -> None:
        """Append (frames, n_channels) samples."""
        if block.ndim != 2 or block.shape[1] != self.n_channels:
            raise ValueError(f"audio block shape {block.shape}, expected (frames, "
                             f"{self.n_channels})")
        with _writing(self.target):
            self._f.write(np.ascontiguousarray(block, dtype="<f4").tobytes())
        self.n_frames += block.shape[0]

    def close(self) -> None:
        """Write the final header; the file is then a regular ``.npy``."""
        if self._f.closed:
            return
        with _writing(self.target):
            self._f.seek(0)
            self._f.write(_npy_header(self.n_frames, self.n_channels))
            self._f.close()

    def discard(self) -> None:
        """Close and delete (a trial that failed half way)."""
        if not self._f.closed:
            # Closing flushes the buffer, which fails again on a full disk; the file is
            # deleted anyway, and the first error is the one to report.
            with contextlib.suppress(OSError):
                self._f.close()
        with contextlib.suppress(OSError):
            self.path.unlink(missing_ok=True)


class _WrittenAudio:
    """An audio file that another process wrote and closed (``DatasetWriter.adopt_trial``):
    what ``end_trial`` and ``abort_trial`` need of an ``AudioFileWriter``."""

    def __init__(self, path: Path, n_frames: int) -> None:
        self.path, self.n_frames = path, n_frames

    def close(self) -> None:
        pass

    def discard(self) -> None:
        with contextlib.suppress(OSError):
            self.path.unlink(missing_ok=True)


class DatasetWriter:
    """Build a dataset atomically. Use as a context manager.

    Per trial: :meth:`begin_trial` -> ``AudioFileWriter`` (append audio), then
    :meth:`end_trial` with the trial's manifest entry and its window rows (``start``
    relative to the trial's audio file), or :meth:`abort_trial`. The dataset appears at
    ``path`` when the block exits cleanly; on an exception nothing is left behind.
    """

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False):
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise FileExistsError(f"{self.path} exists already (use overwrite to replace it)")
        self._ctx = None
        self.root: Path | None = None
        self.trials: list[dict] = []
        self._windows: list[np.ndarray] = []
        self._pending: AudioFileWriter | None = None
        self._n_channels: int | None = None

    def __enter__(self) -> "DatasetWriter":
        with _writing(self.path):
            self._ctx = atomic_path(self.path)
            self.root = self._ctx.__enter__()
            try:
                (self.root / "audio").mkdir(parents=True)
            except OSError as exc:
                self._ctx.__exit__(type(exc), exc, None)
                raise
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if self._pending is not None:
            self._pending.discard()
            self._pending = None
        finished = self.root is not None and (self.root / "manifest.json").exists()
        if exc_type is None and self.root is not None and not finished:
            exc = RuntimeError("DatasetWriter closed without finish(); dataset discarded")
            self._ctx.__exit__(type(exc), exc, None)
            raise exc
        with _writing(self.path):
            return bool(self._ctx.__exit__(exc_type, exc, tb))

    def begin_trial(self, n_channels: int) -> AudioFileWriter:
        """Start the next trial's audio file."""
        if self._pending is not None:
            raise RuntimeError("begin_trial while another trial is open")
        k = len(self.trials)
        self._pending = AudioFileWriter(self.root / "audio" / f".{k}.npy.part", n_channels,
                                        target=self.path)
        return self._pending

    def adopt_trial(self, audio_path: str | os.PathLike, n_frames: int) -> None:
        """Open the next trial on an audio ``.npy`` already written (``n_frames`` frames),
        in this dataset's directory, by a process of a parallel export."""
        if self._pending is not None:
            raise RuntimeError("adopt_trial while another trial is open")
        self._pending = _WrittenAudio(Path(audio_path), int(n_frames))

    def abort_trial(self) -> None:
        """Drop the open trial (its audio is deleted; no index is used up)."""
        if self._pending is not None:
            self._pending.discard()
            self._pending = None

    def end_trial(self, info: Mapping[str, Any], windows: np.ndarray) -> int:
        """Close the open trial; ``windows`` is a WINDOW_DTYPE array (trial field ignored;
        rows of version 1's dtype get ``wy`` NaN)."""
        audio = self._pending
        if audio is None:
            raise RuntimeError("end_trial without begin_trial")
        k = len(self.trials)
        audio.close()
        final = self.root / "audio" / f"{k}.npy"
        with _writing(self.path):
            os.replace(audio.path, final)
        self._pending = None
        rows = windows if isinstance(windows, np.ndarray) and windows.dtype.names else \
            np.asarray(windows, dtype=WINDOW_DTYPE)
        rows = upgrade_windows(rows).copy()
        rows["trial"] = k
        n_win = int(rows.size)
        if n_win and (rows["start"].min() < 0):
            raise ValueError("window start before the trial's first sample")
        entry = {key: info.get(key) for key in TRIAL_KEYS}
        entry.update({k2: v for k2, v in info.items() if k2 not in entry})
        entry["file"] = f"audio/{k}.npy"
        entry["n_samples"] = int(audio.n_frames)
        entry["n_windows"] = n_win
        self.trials.append(entry)
        self._windows.append(rows)
        return k

    def finish(self, **manifest: Any) -> Path:
        """Write windows.npy and manifest.json (``manifest`` holds the dataset fields)."""
        windows = (np.concatenate(self._windows) if self._windows
                   else np.zeros(0, dtype=WINDOW_DTYPE))
        doc = {"format": FORMAT, "version": VERSION}
        doc.update(manifest)
        doc["n_windows"] = int(windows.size)
        doc["trials"] = self.trials
        with _writing(self.path):
            np.save(self.root / "windows.npy", windows)
            write_json(self.root / "manifest.json", doc)
        return self.path


def _load_array(path: Path, what: str) -> np.ndarray:
    """Memory-map one ``.npy`` of a dataset; ValueError naming it when it is unreadable."""
    try:
        return np.load(path, mmap_mode="r", allow_pickle=False)
    except FileNotFoundError:
        raise ValueError(f"{path}: {what} missing (dataset damaged? export it again)") from None
    except (OSError, ValueError, EOFError) as exc:
        raise ValueError(f"{path}: cannot read the {what} ({exc}); truncated or damaged? "
                         "export the dataset again") from None


class Dataset:
    """A dataset opened read-only with memory-mapped audio and windows.

    Attributes: ``manifest`` (dict), ``version`` (of the format on disk), ``trials`` (list
    of dict), ``windows`` (structured array of WINDOW_DTYPE, memory-mapped; a version 1
    table is read into memory with ``wy`` NaN), ``sample_rate``, ``channel_names``,
    ``layout``, ``window_s``, ``hop_s``, ``epsilon_m_s``, ``n_window_samples``.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        mf = self.path / "manifest.json"
        if not mf.is_file():
            raise ValueError(f"{self.path} is not an aslip dataset (no manifest.json)")
        try:
            self.manifest = read_json(mf)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{mf}: not valid JSON ({exc})") from None
        if self.manifest.get("format") != FORMAT:
            raise ValueError(f"{mf}: format {self.manifest.get('format')!r} is not {FORMAT!r}")
        try:
            self.version = int(self.manifest.get("version", 1))
        except (TypeError, ValueError):
            raise ValueError(f"{mf}: version {self.manifest.get('version')!r} is not a "
                             "number") from None
        if self.version > VERSION:
            raise ValueError(f"{mf}: version {self.version} is newer than this reader "
                             f"({VERSION})")
        try:
            self.trials: list[dict] = [dict(t) for t in self.manifest["trials"]]
            self.sample_rate = float(self.manifest["sample_rate"])
            self.channel_names: list[str] = list(self.manifest["channel_names"])
            self.layout: str = self.manifest.get("layout", "")
            self.window_s = float(self.manifest["window_s"])
            self.hop_s = float(self.manifest["hop_s"])
            self.epsilon_m_s = float(self.manifest["epsilon_m_s"])
            self.n_window_samples = int(self.manifest.get(
                "n_window_samples", round(self.window_s * self.sample_rate)))
            for t in self.trials:
                str(t["file"])
        except KeyError as exc:
            raise ValueError(f"{mf}: lacks {exc} (damaged?)") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"{mf}: malformed ({exc})") from None
        self.windows = _load_array(self.path / "windows.npy", "window table")
        stored = WINDOW_DTYPE if self.version >= 2 else WINDOW_DTYPE_V1
        if self.windows.dtype != stored:
            raise ValueError(f"{self.path}/windows.npy has dtype {self.windows.dtype}, "
                             f"expected {stored} (version {self.version})")
        if stored != WINDOW_DTYPE:      # read into memory with the rotational label NaN
            self.windows = upgrade_windows(self.windows)
        self._audio: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return int(self.windows.shape[0])

    def __repr__(self) -> str:
        return (f"Dataset({str(self.path)!r}, {len(self.trials)} trials, {len(self)} windows, "
                f"{self.sample_rate:g} Hz x {len(self.channel_names)} ch, "
                f"window {self.window_s:g} s)")

    @property
    def n_channels(self) -> int:
        return len(self.channel_names)

    def audio(self, trial: int) -> np.ndarray:
        """Memory-mapped (n_samples, n_channels) float32 audio of trial index ``trial``."""
        arr = self._audio.get(trial)
        if arr is None:
            if not 0 <= trial < len(self.trials):
                raise IndexError(f"trial {trial} out of range (0..{len(self.trials) - 1})")
            arr = _load_array(self.path / self.trials[trial]["file"], "trial audio")
            self._audio[trial] = arr
        return arr

    def release_audio(self) -> None:
        """Drop the trials' audio maps opened so far (the next read opens them again): the
        pages a long pass has read leave this process's resident memory, whatever the
        hours of audio (they stay in the kernel's page cache while it has room)."""
        self._audio.clear()

    def window_audio(self, trial: int, start: int) -> np.ndarray:
        """(n_window_samples, C) float32 read-only view of one window."""
        a = self.audio(int(trial))
        start = int(start)
        stop = start + self.n_window_samples
        if start < 0 or stop > a.shape[0]:
            raise IndexError(f"window [{start}, {stop}) outside trial {trial} "
                             f"({a.shape[0]} samples)")
        return a[start:stop]

    def window(self, i: int) -> tuple[np.ndarray, np.void]:
        """Audio view and label row of window ``i``."""
        row = self.windows[int(i)]
        return self.window_audio(row["trial"], row["start"]), row

    def trial_field(self, key: str) -> np.ndarray:
        """Per-window value of a trial field (e.g. ``"object"``), as an object array."""
        per_trial = np.array([t.get(key) for t in self.trials] + [None], dtype=object)[:-1]
        return per_trial[np.asarray(self.windows["trial"])]

    def select_trials(self, *, induced: str | Iterable[str] | None = None,
                      condition: str | Iterable[str] | None = None,
                      object: str | Iterable[str] | None = None,
                      pad: str | Iterable[str] | None = None,
                      ids: Iterable[str] | None = None) -> np.ndarray:
        """Trial indices matching every given filter (a value or a collection of values)."""
        def norm(v):
            return None if v is None else ({v} if isinstance(v, str) else set(v))
        filters = {"induced": norm(induced), "condition": norm(condition),
                   "object": norm(object), "pad": norm(pad), "id": norm(ids)}
        out = [k for k, t in enumerate(self.trials)
               if all(f is None or t.get(key) in f for key, f in filters.items())]
        return np.asarray(out, dtype=np.int64)

    def trial_splits(self, seed: int = 0) -> list[str]:
        """Split name (train/val/test) of every trial: :func:`split_trials` over all trials
        of the dataset, so a trial keeps its split whatever subset is selected later."""
        out = [""] * len(self.trials)
        for name, positions in split_trials(self.trials, seed=seed).items():
            for k in positions:
                out[int(k)] = name
        return out

    def select(self, split: str = "all", *, seed: int = 0, trials: Iterable[int] | None = None,
               **filters: Any) -> np.ndarray:
        """Window indices of ``split`` ("train", "val", "test" or "all"; by trial, seed
        ``seed``), of the trials matching ``filters`` (see :meth:`select_trials`) and, if
        given, among the trial indices ``trials``."""
        if split not in SPLITS + ("all",):
            raise ValueError(f"split must be one of {SPLITS + ('all',)}, got {split!r}")
        keep = np.zeros(len(self.trials), dtype=bool)
        keep[self.select_trials(**filters) if filters else slice(None)] = True
        if trials is not None:
            chosen = np.zeros_like(keep)
            chosen[np.asarray(list(trials), dtype=np.int64)] = True
            keep &= chosen
        if split != "all":
            keep &= np.array([s == split for s in self.trial_splits(seed)], dtype=bool)
        return np.flatnonzero(keep[np.asarray(self.windows["trial"])]).astype(np.int64)


SPLITS = ("train", "val", "test")
DEFAULT_FRACTIONS = {"train": 0.7, "val": 0.15, "test": 0.15}


def split_summary(trials: Sequence[Mapping[str, Any]], seed: int = 0,
                  fractions: Mapping[str, float] | None = None) -> str:
    """How :func:`split_trials` shares ``trials`` out, for messages: "3 trials: 2 train,
    1 val, 0 test (split seed 0)"."""
    parts = split_trials(trials, fractions, seed)
    return (f"{len(trials)} trial(s): "
            + ", ".join(f"{len(v)} {k}" for k, v in parts.items())
            + f" (split seed {seed})")


def split_trials(trials: Sequence[Mapping[str, Any]],
                 fractions: Mapping[str, float] | None = None, seed: int = 0,
                 stratify: Sequence[str] = ("object", "condition")) -> dict[str, np.ndarray]:
    """Assign whole trials to splits, deterministically by ``seed``.

    Trials sharing an ``id`` always land in the same split. Strata (trials with equal values
    of the ``stratify`` keys) are visited in a seeded order, and each trial goes to the split
    furthest below its target share so far; so every stratum is spread over the splits in
    proportion as far as its size allows, and the overall shares are as close to
    ``fractions`` as whole trials permit. Returns positions into ``trials`` per split.
    """
    fr = dict(DEFAULT_FRACTIONS if fractions is None else fractions)
    if not fr or any((not np.isfinite(v)) or v < 0 for v in fr.values()):
        raise ValueError(f"fractions must be non-negative numbers, got {fr}")
    total = sum(fr.values())
    if total <= 0:
        raise ValueError(f"fractions sum to {total}; need a positive total")
    names = list(fr)
    share = np.array([fr[n] / total for n in names])

    # Group trial positions by id (one unit per recording), then units by stratum.
    units: dict[str, list[int]] = defaultdict(list)
    for pos, t in enumerate(trials):
        units[str(t.get("id", pos))].append(pos)
    strata: dict[tuple, list[str]] = defaultdict(list)
    for uid, members in units.items():
        t = trials[members[0]]
        strata[tuple(str(t.get(k)) for k in stratify)].append(uid)

    rng = np.random.default_rng(seed)
    keys = sorted(strata)
    assigned = np.zeros(len(names))
    out: dict[str, list[int]] = {n: [] for n in names}
    done = 0
    for si in rng.permutation(len(keys)):
        uids = sorted(strata[keys[si]])
        for ui in rng.permutation(len(uids)):
            done += 1
            deficit = share * done - assigned
            j = int(np.argmax(deficit))
            assigned[j] += 1
            out[names[j]].extend(units[uids[ui]])
    return {n: np.asarray(sorted(v), dtype=np.int64) for n, v in out.items()}
