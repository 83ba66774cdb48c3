"""Small helpers shared by every layer: atomic file writes and JSON I/O."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it into place only on success.

    Works for files and directories: whatever the caller creates at the yielded path
    replaces ``path`` with a single rename, so readers never see a half-written result.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    work = tmp / (target.name + suffix)
    try:
        yield work
        if target.is_dir() and not target.is_symlink():
            old = target.with_name(f".{target.name}.old-{os.getpid()}")
            os.replace(target, old)
            os.replace(work, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(work, target)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write text atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def read_json(path: str | os.PathLike) -> Any:
    return json.loads(Path(path).read_text())


def peak_rss_mib() -> float | None:
    """This process's own peak resident memory [MiB] since its program started (Linux
    ``VmHWM``: the current address space only, unlike ``ru_maxrss``, which keeps the peak of
    the parent a ``vfork``-ed child was exec-ed from); None where the kernel does not say."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


def die_with_parent() -> None:
    """``preexec_fn`` for child processes: SIGTERM the child when its parent dies (Linux).

    Node processes started by a benchmark or a test must not outlive it: an orphan keeps
    publishing on a ROS domain that ``domain_coordinator`` then hands to the next test. The
    signal is tied to the thread that starts the child, so start children from a thread
    that lives as long as they should. A no-op where ``prctl`` is unavailable.
    """
    import ctypes
    import signal
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)    # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@contextlib.contextmanager
def cpu_hogs(n: int) -> Iterator[list]:
    """``n`` CPU-busy processes (``yes``) at normal priority for the ``with`` block: the load
    beside which benchmarks, the flake hunt and load tests measure. They are killed when the
    block ends and die with this process should it be killed first (``die_with_parent``)."""
    import subprocess
    procs = [subprocess.Popen(["yes"], stdout=subprocess.DEVNULL, preexec_fn=die_with_parent)
             for _ in range(max(0, n))]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


#: Niceness the node processes ask for: the sensor-to-arm loop keeps its deadlines (the
#: 50 ms stale-input watchdogs) beside other CPU-bound work. ``ASLIP_NICE`` overrides it;
#: 0 leaves the priority alone.
DEFAULT_NICE = -10


def raise_cpu_priority(nice: int | None = None) -> str | None:
    """Lower the niceness of this process's threads to ``nice`` (default ``ASLIP_NICE`` or
    DEFAULT_NICE).

    Linux keeps niceness per thread and new threads inherit their creator's, so call this
    before the node starts its threads (DDS, torch, executors). Returns None when the
    process runs at that priority (or better), else why it does not: raising priority needs
    CAP_SYS_NICE or an RLIMIT_NICE of at least ``20 - nice`` (``ulimit -e``; ``nice`` in
    limits.conf).
    """
    if nice is None:
        raw = os.environ.get("ASLIP_NICE", str(DEFAULT_NICE))
        try:
            nice = int(raw)
        except ValueError:
            return f"ASLIP_NICE must be an integer niceness in [-20, 19], got {raw!r}"
    if not -20 <= nice <= 19:
        return f"niceness must lie in [-20, 19], got {nice}"
    try:
        # Every thread of the process (Linux: PRIO_PROCESS with a thread id), including
        # those that imports already started (BLAS pools); later threads inherit it.
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            if os.getpriority(os.PRIO_PROCESS, tid) > nice:
                os.setpriority(os.PRIO_PROCESS, tid, nice)
        except ProcessLookupError:     # a thread that ended meanwhile
            continue
        except OSError as exc:
            return (f"CPU priority not raised to nice {nice} ({exc.strerror}): it needs "
                    f"CAP_SYS_NICE or an RLIMIT_NICE of at least {20 - nice}")
    return None
