"""Watchdog: staleness against an injected clock."""

import math
import threading

import pytest

from aslip_ros.control.watchdog import DEFAULT_TIMEOUT_S, Watchdog
from fake_clock import FakeClock


def test_default_timeout_is_50_ms():
    assert DEFAULT_TIMEOUT_S == pytest.approx(0.05)
    assert Watchdog().timeout_s == pytest.approx(0.05)


def test_stale_before_first_feed():
    wd = Watchdog(0.1, FakeClock())
    assert wd.is_stale()
    assert math.isinf(wd.age())


def test_fresh_until_timeout_then_stale():
    clock = FakeClock(10.0)
    wd = Watchdog(0.1, clock)
    wd.feed()
    clock.t = 10.1
    assert not wd.is_stale()
    clock.t = 10.1001
    assert wd.is_stale()
    wd.feed()
    assert not wd.is_stale()
    assert wd.age() == 0.0


def test_explicit_times_and_out_of_order_feed():
    wd = Watchdog(0.1, FakeClock())
    wd.feed(5.0)
    wd.feed(4.0)   # a late callback must not make the input look older
    assert wd.age(5.05) == pytest.approx(0.05)
    assert wd.is_stale(5.2)


def test_reset_makes_stale():
    clock = FakeClock()
    wd = Watchdog(0.1, clock)
    wd.feed()
    wd.reset()
    assert wd.is_stale()


@pytest.mark.parametrize('bad', [0.0, -1.0, float('nan'), float('inf')])
def test_bad_timeout_rejected(bad):
    with pytest.raises(ValueError):
        Watchdog(bad)


def test_concurrent_feed_and_check():
    wd = Watchdog(10.0)
    stop = threading.Event()

    def feeder():
        while not stop.is_set():
            wd.feed()

    t = threading.Thread(target=feeder)
    t.start()
    try:
        for _ in range(2000):
            wd.is_stale()
    finally:
        stop.set()
        t.join()
    assert not wd.is_stale()
