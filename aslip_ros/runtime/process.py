"""How a node program runs as a process: start, signals, shutdown, exit.

:func:`run_node` is every node executable's ``main``: it builds the node, spins it and shuts
it down however the process is asked to end (SIGINT, SIGTERM, its launch dying), within
``EXIT_GRACE_S``. :func:`ready` logs the line tests and launch files wait for. The first
code of an installed executable is :mod:`aslip_ros.runtime.launcher`; a test or benchmark
starts one in a child process with :mod:`aslip_ros.runtime.child`.
"""

from __future__ import annotations

import signal
import sys
import threading
from typing import Any, Callable, Optional

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.signals import SignalHandlerOptions

#: Exit code of a node refused at start (invalid parameters, unusable configuration).
EXIT_CONFIG = 2


class ConfigError(ValueError):
    """The node's parameters or configuration are unusable; the message says why."""


def _executor(threads: int):
    """The executor the node executables spin on.

    rclpy's EventsExecutor dispatches from C++ without rebuilding a wait set per callback;
    with MultiThreadedExecutor the per-callback Python overhead at ~300 callbacks/s (audio,
    slip, poses, a 100 Hz control timer) produced stalls over 100 ms on a 2-core machine,
    long enough to trip the controllers' 100 ms watchdog. Callbacks here are short and the
    model runs on a thread of its own, so one dispatch thread suffices.
    """
    try:
        from rclpy.experimental.events_executor import EventsExecutor
    except ImportError:  # older rclpy (Humble)
        return MultiThreadedExecutor(num_threads=threads)
    return EventsExecutor()


def run_node(factory: Callable[[], Any], args: Optional[list] = None,
             threads: int = 2, exit_process: bool = True) -> int:
    """Init, build the node, spin it (see ``_executor``), shut down cleanly.

    SIGINT and SIGTERM are handled here rather than by rclpy: rclpy's own handler shuts the
    context down at once, after which a controller could no longer publish its final stop
    command. Here a signal only ends the spin loop; the node's ``before_shutdown()`` (if
    any) runs while the context still works, then the node is destroyed.
    The process is tied to its parent (``_tie_to_parent``): when ``ros2 launch`` (or a test)
    dies without stopping it, the node gets SIGTERM and shuts down the same way. Once a signal
    came, the process exits within ``EXIT_GRACE_S`` even if a cleanup step hangs, so a launch
    never has to escalate to SIGKILL (which would skip the controllers' stop command).
    With ``exit_process`` (node executables) the process ends here once the node is shut
    down, without the interpreter's finalization: by then Python has restored the default
    signal handlers, and C++ destructors of DDS and torch threads could block for seconds
    (seen under load: the launch escalated to SIGTERM, which then killed the node, -15).
    Otherwise returns the exit code (``EXIT_CONFIG`` when the node refused its configuration).
    """
    stop = threading.Event()
    arming = threading.Lock()
    forced = []         # the forced exit, once armed

    def on_signal(signum: int) -> None:
        # The forced exit is armed before the loop may end: the cleanup that follows can
        # hold the GIL, and arming it afterwards would then wait for the GIL forever.
        with arming:
            if not stop.is_set():
                forced.append(_exit_after(EXIT_GRACE_S, _name(factory)))
                stop.set()

    _watch_signals(on_signal)
    _tie_to_parent()
    _raise_priority(_name(factory))
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    executor = None
    code = 0
    try:
        node = factory()
        executor = _executor(threads)
        executor.add_node(node)
        while not stop.is_set() and rclpy.ok() and not getattr(node, "done", False):
            executor.spin_once(timeout_sec=0.05)
        code = int(getattr(node, "exit_code", 0) or 0)
    except (ConfigError, ParameterException) as exc:
        _say(f"[{_name(factory)}] refused to start: {exc}")
        code = EXIT_CONFIG
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        # However the loop ended (a signal, the node done, an exception), the cleanup below
        # gets EXIT_GRACE_S in an executable: a hung destructor must not keep it alive.
        if exit_process and not stop.is_set():
            on_signal(0)
        _shut_down(node, executor, _name(factory), forced[0] if forced else None, code)
    if exit_process:
        _leave(code)
    return code


def _shut_down(node, executor, name: str, forced: Optional["_ForcedExit"],
               code: int) -> None:
    """The node's ``before_shutdown`` (its own work), then the middleware's teardown; with
    ``forced`` (the armed forced exit) the step under way is known to it and the work's
    end is told to it. A shutdown over ``SLOW_SHUTDOWN_S`` says where its time went."""
    steps = ShutdownSteps("before_shutdown")
    if forced is not None:
        forced.steps = steps
    if node is not None:
        hook = getattr(node, "before_shutdown", None)
        if hook is not None and rclpy.ok():
            try:
                hook()
            except Exception as exc:  # noqa: BLE001 - shutdown must go on
                _say(f"[{name}] error while shutting down: {exc}")
    if forced is not None:
        forced.work_done(code)
    if executor is not None:
        # Before destroying the node, so no callback runs on a destroyed entity.
        steps.begin("executor.shutdown")
        executor.shutdown(timeout_sec=2.0)
    if node is not None:
        steps.begin("destroy_node")
        node.destroy_node()
    steps.begin("rclpy.try_shutdown")
    rclpy.try_shutdown()
    if steps.total() > SLOW_SHUTDOWN_S:
        _say(f"[{name}] shutdown took {steps.summary()}")


#: A shutdown slower than this [s] says where its time went (``ShutdownSteps.summary``).
SLOW_SHUTDOWN_S = 1.0


class ShutdownSteps:
    """The steps of a node's shutdown and when each began: the line a slow shutdown writes,
    and the step the forced exit names. CI's launch logs showed nodes taking 2-4 s to exit
    after SIGINT (most take under 0.3 s) without saying in which step."""

    def __init__(self, first: str) -> None:
        import time
        self._clock = time.monotonic
        self.marks = [(first, self._clock())]

    def begin(self, name: str) -> None:
        self.marks.append((name, self._clock()))

    def total(self) -> float:
        return self._clock() - self.marks[0][1]

    def current(self) -> str:
        """The step under way and how long it has run, e.g. ``destroy_node, 2.1 s in``."""
        name, t = self.marks[-1]
        return f"{name}, {self._clock() - t:.1f} s in"

    def summary(self) -> str:
        """``2.05 s: before_shutdown 0.00 s, executor.shutdown 2.00 s, ...``."""
        ends = [t for _, t in self.marks[1:]] + [self._clock()]
        parts = [f"{name} {end - t:.2f} s" for (name, t), end in zip(self.marks, ends)]
        return f"{self.total():.2f} s: " + ", ".join(parts)


def _watch_signals(handler: Callable[[int], None]) -> None:
    """SIGINT and SIGTERM go to a thread of their own, which calls ``handler(signum)``.

    A Python signal handler runs only when the main thread returns to the interpreter; a
    node whose main thread was stuck inside a C call (seen: mocap_bridge ignored the
    launch's SIGINT and SIGTERM until SIGKILL) would never start its forced exit. The node
    executables block both signals before any import (``runtime/launcher.py``), so every
    thread inherits the mask and only this one receives them. Blocking them here again
    covers ``python -m aslip_ros.nodes.<node>``; a thread that still has them unblocked
    (started by an import before this call) is named on stderr."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    open_threads = threads_receiving(sigs)     # (before the signal thread exists)
    if open_threads:
        _say(f"[aslip] threads {open_threads} can receive SIGINT/SIGTERM: start the node "
             "through its installed executable (aslip_ros.runtime.launcher) so that a "
             "shutdown signal cannot miss the signal thread")

    def wait() -> None:
        _name_os_thread(SIGNAL_THREAD)
        while True:
            handler(signal.sigwait(sigs))
    threading.Thread(target=wait, name=SIGNAL_THREAD, daemon=True).start()


#: The signal thread's name, also its OS name (``top -H``, ``/proc/<pid>/task/*/comm``).
SIGNAL_THREAD = "aslip_signals"


def _name_os_thread(name: str) -> None:
    """Give the calling thread an OS-level name (Linux ``prctl(PR_SET_NAME)``; a no-op
    elsewhere). While it waits in ``sigwait`` the kernel shows its mask without the waited
    signals, so this name is how a check tells it from a thread that left them open."""
    import ctypes
    try:
        ctypes.CDLL(None).prctl(15, name.encode()[:15], 0, 0, 0)
    except (OSError, AttributeError):
        pass


def threads_receiving(sigs, pid: str = "self") -> list:
    """Thread ids of process ``pid`` that do not block every signal in ``sigs`` (Linux
    ``/proc``; empty where it cannot be read)."""
    import glob
    want = 0
    for s in sigs:
        want |= 1 << (int(s) - 1)
    out = []
    for status in glob.glob(f"/proc/{pid}/task/*/status"):
        try:
            with open(status) as f:
                blocked = next((int(line.split()[1], 16) for line in f
                                if line.startswith("SigBlk:")), None)
        except (OSError, ValueError):
            continue
        if blocked is not None and blocked & want != want:
            out.append(int(status.split("/")[-2]))
    return sorted(out)


def _say(line: str) -> None:
    """One line on stderr, if it can still be written: once the launch is gone, stderr is
    a broken pipe, and nothing on the way out may raise."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _name(factory) -> str:
    return getattr(factory, "__name__", "aslip node")


def _leave(code: int) -> None:
    """Flush Python's and C's output buffers (rcutils logs through C stdio), then exit.

    Nothing here may stop the exit: after ``ros2 launch`` died (SIGTERM ends it without
    stopping its nodes), stdout and stderr are broken pipes and a flush raises."""
    import ctypes
    import os
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass
    os._exit(code)


#: Seconds from SIGINT/SIGTERM to a forced exit; below launch's 5 s SIGINT->SIGTERM step.
EXIT_GRACE_S = 4.0


def _tie_to_parent() -> None:
    """Get SIGTERM when the parent process dies (Linux), e.g. ``ros2 launch`` killed by
    SIGTERM or SIGKILL: a node must never outlive its launch."""
    import os

    from aslip_ros.util import die_with_parent
    parent = os.getppid()
    die_with_parent()
    if os.getppid() != parent:     # the parent died before the tie was made
        os.kill(os.getpid(), signal.SIGTERM)


def _raise_priority(name: str) -> None:
    """Run the node above ordinary CPU-bound work (``util.raise_cpu_priority``), before
    rclpy, DDS or torch start threads (they inherit it). Beside two CPU-busy processes on 2
    cores, the stale-input watchdogs stopped 2 of 16 closed-loop trials at normal priority
    and 0 of 20 at nice -10 (``python -P -m benchmarks.stale_input``)."""
    from aslip_ros.util import raise_cpu_priority
    why = raise_cpu_priority()
    if why:
        print(f"[{name}] {why}; on a busy computer the stale-input watchdogs may then stop "
              "the arm (README, Reliability)", file=sys.stderr, flush=True)


def _exit_after(seconds: float, name: str) -> "_ForcedExit":
    """Force the process out ``seconds`` from now unless it has exited by then.

    Two timers: a Python one that exits 0 with a line on stderr, and a C one
    (``faulthandler.dump_traceback_later``) ``C_EXIT_MARGIN_S`` later that needs no GIL:
    an interpreter stuck in a C call that holds the GIL still exits, with every thread's
    stack on stderr (exit code 1), instead of waiting for the launch's SIGKILL. Once the
    node's own shutdown work is over, :meth:`_ForcedExit.work_done` makes both exit with
    the node's code."""
    return _ForcedExit(seconds, name)


class _ForcedExit:
    """The forced exit of :func:`_exit_after`."""

    def __init__(self, seconds: float, name: str) -> None:
        import time
        self.name = name
        self.seconds = seconds
        self.deadline = time.monotonic() + seconds
        self.code = 0
        self.steps: Optional[ShutdownSteps] = None      # run_node's, once shutting down
        timer = threading.Timer(seconds, self._force)
        timer.daemon = True
        timer.start()
        self.dump = _dump_stacks_later(seconds + C_EXIT_MARGIN_S, exit=True)

    def _force(self) -> None:
        import os
        where = f" (in {self.steps.current()})" if self.steps is not None else ""
        _say(f"[{self.name}] shutdown took over {self.seconds:g} s{where}; exiting now")
        os._exit(self.code)

    def work_done(self, code: int) -> None:
        """The node's shutdown work (``before_shutdown``) is over; what remains is the
        middleware's teardown (``destroy_node``, ``rclpy.try_shutdown``). That teardown
        once held the GIL past the grace in CI (mocap_bridge in ``destroy_node``, exit 1
        from faulthandler): a hang there now ends in ``code``, the node's own exit code,
        from a C timer that needs no GIL (:func:`_c_exit_later`), its stacks dumped
        ``TEARDOWN_DUMP_LEAD_S`` before the deadline. Where the C library has no such
        timer, faulthandler's exit 1 stays."""
        import time
        self.code = code
        if not self.dump:
            return
        left = max(self.deadline - time.monotonic(), 0.0)
        if _c_exit_later(left + TEARDOWN_C_EXIT_S, code):
            _dump_stacks_later(max(left - TEARDOWN_DUMP_LEAD_S, 0.01), exit=False)


def _dump_stacks_later(seconds: float, exit: bool) -> bool:
    """``faulthandler.dump_traceback_later`` on the original stderr (replacing any pending
    one); False where it cannot be armed (no usable stderr)."""
    import faulthandler
    try:
        faulthandler.dump_traceback_later(seconds, exit=exit, file=sys.__stderr__)
    except (OSError, ValueError, AttributeError, RuntimeError):
        return False
    return True


def _c_exit_later(seconds: float, code: int) -> bool:
    """Have the C library call ``_exit(code)`` ``seconds`` from now, on a thread of its own
    (POSIX ``timer_create`` with ``SIGEV_THREAD``): an exit that needs neither the GIL nor a
    signal handler. False where it cannot be armed (not Linux, no such call)."""
    import ctypes
    if not sys.platform.startswith("linux"):
        return False
    ptr = ctypes.sizeof(ctypes.c_void_p)

    class SigEvent(ctypes.Structure):       # struct sigevent: 64 bytes on Linux
        _fields_ = [("value", ctypes.c_void_p), ("signo", ctypes.c_int),
                    ("notify", ctypes.c_int), ("function", ctypes.c_void_p),
                    ("attributes", ctypes.c_void_p),
                    ("pad", ctypes.c_byte * (64 - 3 * ptr - 8))]

    class TimeSpec(ctypes.Structure):
        _fields_ = [("sec", ctypes.c_long), ("nsec", ctypes.c_long)]

    class ITimerSpec(ctypes.Structure):
        _fields_ = [("interval", TimeSpec), ("value", TimeSpec)]

    sigev_thread, clock_monotonic = 2, 1
    for lib in (None, "librt.so.1"):        # glibc < 2.34 keeps timer_create in librt
        try:
            libc = ctypes.CDLL(lib)
            create, settime = libc.timer_create, libc.timer_settime
            exit_fn = ctypes.cast(ctypes.CDLL(None)._exit, ctypes.c_void_p).value
        except (OSError, AttributeError):
            continue
        event = SigEvent(value=code or None, notify=sigev_thread, function=exit_fn)
        timer = ctypes.c_void_p()
        if create(clock_monotonic, ctypes.byref(event), ctypes.byref(timer)) != 0:
            return False
        whole = int(seconds)
        spec = ITimerSpec(value=TimeSpec(whole, max(int((seconds - whole) * 1e9), 1)))
        return settime(timer, 0, ctypes.byref(spec), None) == 0
    return False


#: Seconds after the Python forced exit at which the C-level one ends a stuck interpreter.
C_EXIT_MARGIN_S = 0.5

#: Once the node's own work is done (``_ForcedExit.work_done``): a teardown still running
#: ``TEARDOWN_DUMP_LEAD_S`` before the Python forced exit has its stacks dumped then, and
#: the C exit comes ``TEARDOWN_C_EXIT_S`` after that forced exit. Both exits then give the
#: same code, so the C one need not wait ``C_EXIT_MARGIN_S``: the earlier it comes, the
#: further it stays from the launch's SIGTERM, 5 s after its SIGINT (a node exiting as that
#: signal is sent may be reaped by the signal's ``Popen.poll``; asyncio's child watcher then
#: reports 255: seen once by hand, cause not confirmed). The dump and the exit run on two
#: threads of their own, each woken by its own timer: 0.1 s apart (the dump after the
#: deadline), a loaded machine once woke the exit first and the dump never came
#: (``make test``, 2026-11-30); 0.65 s apart it has that long to be scheduled. A teardown
#: that ends between the dump and the deadline leaves the dump on stderr: it was slow.
TEARDOWN_DUMP_LEAD_S = 0.5
TEARDOWN_C_EXIT_S = 0.15


def ready(node, detail: str = "") -> None:
    """Log the readiness line tests and launch files wait for."""
    node.get_logger().info(f"ready{': ' + detail if detail else ''}")
