"""The stream watch's verdict (aslip_ros/data/stream_watch.py) on a hand-stepped clock.

Through ``ros2 launch``: test_data_collection_failures.py.
"""

from __future__ import annotations

import pytest

from aslip_ros.data.stream_watch import (START_TIMEOUT_RANGE_S, STALL_TIMEOUT_RANGE_S,
                                         StreamWatch, WatchConfig)

CFG = WatchConfig(start_timeout_s=5.0, stall_timeout_s=1.0)


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _watch(streams=("/audio", "/finger", "/object")):
    clock = Clock()
    return StreamWatch(list(streams), CFG, clock=clock), clock


def test_streams_that_keep_arriving_are_well():
    w, clock = _watch()
    for _ in range(200):              # 20 s at 10 Hz, well inside both thresholds
        clock.t += 0.1
        for s in w.streams:
            w.arrived(s)
        assert w.check() is None
    assert w.waiting() == [] and w.counts() == {s: 200 for s in w.streams}


def test_a_stream_that_never_arrives_fails_once_the_start_timeout_passed():
    w, clock = _watch()
    for _ in range(49):               # 4.9 s of audio and finger poses, no object
        clock.t += 0.1
        w.arrived("/audio")
        w.arrived("/finger")
        assert w.check() is None
    assert w.waiting() == ["/object"]
    clock.t += 0.2
    fault = w.check()
    assert fault is not None and fault.stream == "/object" and fault.never
    assert fault.message().startswith("/object: no message in the first 5.1 s")
    assert "never arrived" in fault.message()


def test_a_stream_that_stops_fails_once_the_stall_timeout_passed():
    w, clock = _watch()
    for _ in range(30):
        clock.t += 0.1
        for s in w.streams:
            w.arrived(s)
    for _ in range(9):                # the finger stops: 0.9 s of the others only
        clock.t += 0.1
        w.arrived("/audio")
        w.arrived("/object")
        assert w.check() is None
    clock.t += 0.2
    w.arrived("/audio")
    w.arrived("/object")
    fault = w.check()
    assert fault is not None and fault.stream == "/finger" and not fault.never
    assert fault.count == 30
    assert fault.message().startswith("/finger: no message for 1.1 s after 30 messages")
    assert "stopped mid-trial" in fault.message()


def test_the_stream_whose_threshold_passed_first_is_named():
    """Found late (a busy checker), the verdict still names the first stream to fail."""
    w, clock = _watch()
    w.arrived("/audio", now=100.2)
    w.arrived("/finger", now=100.2)
    w.arrived("/finger", now=104.0)    # audio silent since 100.2 -> failed at 101.2
    clock.t = 110.0                   # the object never came -> failed at 105.0
    assert w.check().stream == "/audio"
    w2, clock2 = _watch()
    w2.arrived("/audio", now=100.1)
    w2.arrived("/finger", now=100.1)
    w2.arrived("/object", now=100.1)
    w2.arrived("/audio", now=104.5)    # finger, object failed at 101.1, audio at 105.5
    w2.arrived("/object", now=100.9)   # object fails at 101.9: after the finger
    clock2.t = 106.0
    assert w2.check().stream == "/finger"


def test_a_late_stamp_never_makes_a_stream_look_older():
    w, clock = _watch(["/a"])
    w.arrived("/a", now=103.0)
    w.arrived("/a", now=102.0)         # out of order
    clock.t = 103.9
    assert w.check() is None


def test_a_trial_is_complete_duration_after_every_stream_is_in():
    w, clock = _watch()
    w.arrived("/audio", now=100.5)
    w.arrived("/finger", now=101.0)
    clock.t = 110.0
    assert not w.complete(3.0)        # the object has not come: no trial yet
    w.arrived("/object", now=102.0)
    assert not w.complete(3.0, now=104.9)
    assert w.complete(3.0, now=105.0)


def test_unknown_streams_and_bad_settings_are_refused():
    w, _ = _watch()
    with pytest.raises(KeyError, match="/nope is not watched"):
        w.arrived("/nope")
    with pytest.raises(ValueError, match="distinct"):
        StreamWatch(["/a", "/a"])
    with pytest.raises(ValueError, match="distinct"):
        StreamWatch([])
    for bad in (0.0, float("nan"), START_TIMEOUT_RANGE_S[1] + 1):
        with pytest.raises(ValueError, match="start_timeout_s"):
            WatchConfig(start_timeout_s=bad)
    with pytest.raises(ValueError, match="stall_timeout_s"):
        WatchConfig(stall_timeout_s=STALL_TIMEOUT_RANGE_S[0] / 2)
