"""A thread of its own for every call into an :class:`~aslip_ros.arm.Arm`.

Arm I/O blocks: the xArm SDK waits for a reply over TCP on every call. Done from a control
callback, it would hold up every other callback of a single-dispatch executor (slip
estimates, poses, the stale-input deadlines) by a round trip per call. So callers only
*post* a command here and return at once; this thread sends it.

The mailbox keeps only the newest command: a newer velocity supersedes an unsent older one
(a late command is worth less than the current one). A stop is sticky: once posted, every
later velocity is dropped (and counted) until :meth:`ArmWorker.rearm`, so no motion command
can follow a stop, whatever order the callers' threads run in.

An arm without a pose stream of its own can be polled here too (``poll_period_s``), so
the pose query is also off the callers' threads; each pose is reported with the moment
it was measured, not when someone later publishes it.

An arm whose calls never block (``blocking = False``, e.g. commands published on a topic)
is called from the posting thread instead (``inline``): a thread hand-over would only add
a scheduling delay to the stop on a busy machine. The mailbox rules stay the same.
"""

from __future__ import annotations

import threading
import time
from typing import Callable, Optional

import numpy as np

from aslip_ros.arm import ArmError
from aslip_ros.control.command import VelocityCommand, apply_command

#: ``on_pose(pose7, monotonic_s, wall_ns)``: a TCP pose and when it was measured.
PoseCallback = Callable[[np.ndarray, float, int], None]


class ArmWorker:
    """Sends the newest posted command to ``arm`` from a dedicated thread.

    :param arm: the arm; only this thread calls it after construction (plus :meth:`close`
        callers, once the thread has ended).
    :param on_error: called (on this thread, no lock held) with the :class:`ArmError` of a
        failed call, after the worker has latched and tried a plain stop.
    :param on_pose: with ``poll_period_s``, receives each polled pose.
    :param poll_period_s: poll ``arm.tcp_pose()`` this often; ``None``: never.
    :param inline: send on the posting thread (for arms that never block); default: the
        arm's ``blocking`` attribute is False.
    """

    def __init__(self, arm, on_error: Callable[[ArmError], None],
                 on_pose: Optional[PoseCallback] = None,
                 poll_period_s: Optional[float] = None, name: str = "arm-io",
                 clock: Callable[[], float] = time.monotonic,
                 inline: Optional[bool] = None) -> None:
        self._arm = arm
        self._on_error = on_error
        self._on_pose = on_pose
        self._poll = poll_period_s if on_pose is not None else None
        self._clock = clock
        self._cv = threading.Condition()
        self._pending: Optional[VelocityCommand] = None
        self._latched = True         # nothing moves before the owner says so (rearm)
        self._busy = False
        self._closing = False
        self.sent = 0
        self.superseded = 0
        self.dropped_after_stop = 0
        self.errors = 0
        self.last_stop_sent: Optional[float] = None   # clock time the last stop went out
        self.io_thread_id: Optional[int] = None
        self.inline = (not getattr(arm, "blocking", True)) if inline is None else inline
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        if self.inline and self._poll is not None:
            raise ValueError("an inline arm cannot be polled")
        if not self.inline:
            self._thread.start()

    # -- callers -------------------------------------------------------------------------

    def post(self, command: Optional[VelocityCommand]) -> bool:
        """Queue ``command`` (``None``: nothing); never blocks on the arm.

        Returns False when a velocity was dropped because a stop came first.
        """
        if command is None:
            return True
        with self._cv:
            if self._closing:
                return False
            if command.stop:
                self._latched = True
            elif self._latched:
                self.dropped_after_stop += 1
                return False
            elif self._pending is not None and not self._pending.stop:
                self.superseded += 1
            if self._pending is None or not self._pending.stop or command.stop:
                self._pending = command
            if self.inline:
                # Under the mailbox lock: two posting threads cannot reorder a stop and
                # a velocity on the way to the arm.
                command, self._pending = self._pending, None
                self._send(command, locked=True)
            self._cv.notify_all()
        return True

    def rearm(self) -> None:
        """Accept velocities again (a new activation); an unsent stop still goes out first."""
        with self._cv:
            self._latched = False

    @property
    def latched(self) -> bool:
        """True from a stop until :meth:`rearm`."""
        with self._cv:
            return self._latched

    def flush(self, timeout: float = 2.0) -> bool:
        """Wait until everything posted has been sent; False on timeout."""
        deadline = time.monotonic() + timeout
        with self._cv:
            while self._pending is not None or self._busy:
                left = deadline - time.monotonic()
                if left <= 0.0 or not self._thread.is_alive():
                    return False
                self._cv.wait(left)
        return True

    def close(self, timeout: float = 2.0) -> bool:
        """Send what is pending, then end the thread; False if it did not end in time."""
        self.flush(timeout)
        with self._cv:
            self._closing = True
            self._cv.notify_all()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        return not self._thread.is_alive()

    # -- the thread ------------------------------------------------------------------------

    def _run(self) -> None:
        self.io_thread_id = threading.get_ident()
        next_poll = self._clock()
        while True:
            with self._cv:
                while self._pending is None and not self._closing:
                    if self._poll is not None:
                        wait = next_poll - self._clock()
                        if wait <= 0.0:
                            break
                        self._cv.wait(wait)
                    else:
                        self._cv.wait()
                if self._closing and self._pending is None:
                    self._cv.notify_all()
                    return
                command, self._pending = self._pending, None
                self._busy = True
            try:
                if command is not None:
                    self._send(command)
                if self._poll is not None and self._clock() >= next_poll:
                    next_poll = self._clock() + self._poll
                    self._poll_pose()
            finally:
                with self._cv:
                    self._busy = False
                    self._cv.notify_all()

    def _send(self, command: VelocityCommand, locked: bool = False) -> None:
        try:
            apply_command(self._arm, command)
        except ArmError as exc:
            self._fail(exc, locked)
            return
        self.sent += 1
        if command.stop:
            self.last_stop_sent = self._clock()

    def _poll_pose(self) -> None:
        try:
            pose = self._arm.tcp_pose()
        except ArmError as exc:
            self._fail(exc)
            return
        self._on_pose(pose, self._clock(), time.time_ns())

    def _fail(self, exc: ArmError, locked: bool = False) -> None:
        self.errors += 1
        if not locked:
            self._cv.acquire()
        try:
            self._latched = True
            if self._pending is not None and not self._pending.stop:
                self._pending = None
        finally:
            if not locked:
                self._cv.release()
        try:
            self._arm.stop()
            self.last_stop_sent = self._clock()
        except Exception:  # noqa: BLE001 - the arm may be gone; the owner hears of exc
            pass
        if locked:
            # The poster may hold its own locks, which the error handler will want.
            threading.Thread(target=self._on_error, args=(exc,), daemon=True).start()
        else:
            self._on_error(exc)
