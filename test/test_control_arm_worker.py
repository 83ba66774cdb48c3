"""The arm thread: posting never waits for the arm, the newest command wins, a stop is sticky,
an arm error latches a stop, polled poses carry the time they were measured."""

import threading
import time

import numpy as np

from aslip_ros.arm import ArmError
from aslip_ros.control.arm_worker import ArmWorker
from aslip_ros.control.command import VelocityCommand


class SlowArm:
    """Every call takes ``delay_s``; ``gate`` (when cleared) holds velocity calls."""

    def __init__(self, delay_s=0.005):
        self.delay_s = delay_s
        self.calls = []
        self.threads = set()
        self.gate = threading.Event()
        self.gate.set()
        self.inside = threading.Event()
        self.fail_next = False

    def send_velocity(self, v, duration_s):
        self.threads.add(threading.get_ident())
        self.inside.set()
        assert self.gate.wait(10)
        time.sleep(self.delay_s)
        if self.fail_next:
            self.fail_next = False
            raise ArmError("refused")
        self.calls.append(("move", tuple(np.asarray(v, float))))

    def stop(self):
        self.threads.add(threading.get_ident())
        time.sleep(self.delay_s)
        self.calls.append(("stop",))

    def tcp_pose(self):
        time.sleep(self.delay_s)
        return np.array([0.4, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0])


def move(x):
    return VelocityCommand(np.array([x, 0.0, 0.0]), 0.1)


def test_post_never_waits_for_the_arm_and_io_runs_on_the_arm_thread():
    arm = SlowArm()
    w = ArmWorker(arm, on_error=lambda e: None)
    w.rearm()
    arm.gate.clear()
    assert w.post(move(0.01))
    assert arm.inside.wait(5)               # the arm thread is now stuck inside the call
    t0 = time.monotonic()
    for k in range(100):
        w.post(move(0.02 + k * 1e-4))
    assert time.monotonic() - t0 < 1.0      # 100 posts while the arm is blocked
    arm.gate.set()
    assert w.flush(5)
    assert arm.threads == {w.io_thread_id} and threading.get_ident() not in arm.threads
    # The newest command wins: the 99 older ones were superseded, not queued.
    assert [c for c in arm.calls if c[0] == "move"][-1][1][0] == 0.02 + 99 * 1e-4
    assert len(arm.calls) == 2 and w.superseded == 99
    w.close()


def test_no_motion_command_after_a_stop_until_rearmed():
    arm = SlowArm()
    w = ArmWorker(arm, on_error=lambda e: None)
    w.rearm()
    arm.gate.clear()
    w.post(move(0.01))
    assert arm.inside.wait(5)
    w.post(move(0.02))                       # pending behind the blocked call
    w.post(VelocityCommand.halt("stale"))    # supersedes the pending move
    assert not w.post(move(0.03))            # refused: a stop came first
    arm.gate.set()
    assert w.flush(5)
    time.sleep(0.05)
    assert w.post(move(0.04)) is False
    assert w.flush(5)
    kinds = [c[0] for c in arm.calls]
    assert kinds == ["move", "stop"], arm.calls
    assert w.dropped_after_stop == 2 and w.last_stop_sent is not None
    w.rearm()                                # a new activation
    w.post(move(0.05))
    assert w.flush(5)
    assert arm.calls[-1] == ("move", (0.05, 0.0, 0.0))
    w.close()


def test_arm_error_latches_a_stop_and_reports_it():
    arm = SlowArm(delay_s=0.0)
    errors = []
    w = ArmWorker(arm, on_error=errors.append)
    w.rearm()
    arm.fail_next = True
    w.post(move(0.01))
    assert w.flush(5)
    assert len(errors) == 1 and isinstance(errors[0], ArmError)
    assert arm.calls == [("stop",)] and w.latched
    assert not w.post(move(0.02))
    w.close()


def test_polled_pose_is_stamped_when_measured():
    arm = SlowArm(delay_s=0.02)
    got = []
    w = ArmWorker(arm, on_error=lambda e: None,
                  on_pose=lambda p, t, ns: got.append((p, t, ns, time.monotonic())),
                  poll_period_s=0.01)
    deadline = time.monotonic() + 5
    while len(got) < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    w.close()
    assert len(got) >= 3
    for pose, t, ns, _ in got:
        assert pose.shape == (7,) and abs(ns * 1e-9 - time.time()) < 10


def test_close_sends_the_pending_stop_first():
    arm = SlowArm()
    w = ArmWorker(arm, on_error=lambda e: None)
    w.rearm()
    w.post(move(0.01))
    w.post(VelocityCommand.halt("shutdown"))
    assert w.close(5)
    assert arm.calls[-1] == ("stop",)
    assert not w.post(move(0.01))


class TopicLikeArm(SlowArm):
    blocking = False


def test_non_blocking_arm_is_called_inline_with_the_same_mailbox_rules():
    arm = TopicLikeArm(delay_s=0.0)
    errors = []
    w = ArmWorker(arm, on_error=errors.append)
    assert w.inline
    w.rearm()
    w.post(move(0.01))
    assert arm.calls == [("move", (0.01, 0.0, 0.0))]       # sent before post returned
    assert arm.threads == {threading.get_ident()}
    w.post(VelocityCommand.halt("stale"))
    assert not w.post(move(0.02))
    assert [c[0] for c in arm.calls] == ["move", "stop"]
    w.rearm()
    arm.fail_next = True
    w.post(move(0.03))
    deadline = time.monotonic() + 5
    while not errors and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(errors) == 1 and w.latched and arm.calls[-1] == ("stop",)
    assert w.close()
