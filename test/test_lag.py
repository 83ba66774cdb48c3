"""aslip_ros.lag.LagMeter: how much later than usual a stream's blocks arrive."""

from __future__ import annotations

import pytest

from aslip_ros.lag import STEP_AFTER_S, LagMeter


def test_a_steady_stream_has_no_lag_whatever_its_clock_offset():
    m = LagMeter()
    for k in range(200):                   # stamps 40 ms behind this host's clock, jittered
        lag = m.lag(1000.0 + 0.01 * k + 0.040 + 0.002 * (k % 3), 1000.0 + 0.01 * k)
        assert 0.0 <= lag <= 0.0041


def test_a_backlog_shows_as_lag_and_clears_as_it_is_worked_off():
    m = LagMeter()
    for k in range(50):
        m.lag(100.0 + 0.01 * k + 0.002, 100.0 + 0.01 * k)
    # A 300 ms stall: the next 30 blocks are taken at once.
    t = 100.0 + 0.49 + 0.3
    lags = [m.lag(t + 0.001 * j, 100.0 + 0.01 * (50 + j)) for j in range(30)]
    assert lags[0] == pytest.approx(0.3, abs=0.02)
    assert lags == sorted(lags, reverse=True)
    assert lags[-1] < 0.03


def test_a_stream_not_on_this_hosts_clock_is_never_late():
    m = LagMeter()
    for k in range(100):                   # a replay with its recording's stamps (1970)
        assert m.lag(1.8e9 + 0.05 * k, 1000.0 + 0.01 * k) == 0.0


def test_a_jump_of_the_source_clock_starts_the_measure_again():
    m = LagMeter(reset_s=2.0)
    for k in range(20):
        m.lag(10.0 + 0.01 * k, 10.0 + 0.01 * k)
    assert m.lag(10.3, 7.0) == 0.0         # stamps 3 s back: no backlog, a new clock
    assert m.resets == 1
    assert m.lag(10.31, 7.01) == pytest.approx(0.0)


def test_a_backlog_worked_off_by_skipping_is_no_clock_step():
    m = LagMeter()
    for k in range(50):
        m.lag(100.0 + 0.01 * k + 0.002, 100.0 + 0.01 * k)
    t = 100.0 + 0.49 + 0.3                 # a 300 ms stall; the 30 blocks skipped at once
    skips = [m.behind(t + 0.0001 * j, 100.0 + 0.01 * (50 + j), 0.05)[1] for j in range(30)]
    assert skips[0] and not skips[-1]      # the late ones skipped, then on time again
    assert m.steps == 0


def test_a_step_of_the_source_clock_is_skipped_only_for_a_moment():
    # From block 50 on, every block arrives at the stream's pace but 300 ms later than its
    # stamp says (scene_sim skipping scene time): no backlog to work off. Skipped for
    # STEP_AFTER_S, then the usual delay starts again and the blocks are on time.
    m = LagMeter()
    arrive = [100.0 + 0.01 * k + 0.002 + (0.3 if k >= 50 else 0.0) for k in range(200)]
    out = [m.behind(a, 100.0 + 0.01 * k, 0.05) for k, a in enumerate(arrive)]
    skipped = [k for k, (_, skip) in enumerate(out) if skip]
    assert skipped == list(range(50, 50 + len(skipped)))
    assert STEP_AFTER_S / 0.01 - 1 <= len(skipped) <= STEP_AFTER_S / 0.01 + 1
    assert m.steps == 1
    assert all(lag < 0.005 and not skip for lag, skip in out[50 + len(skipped):])


def test_a_limit_of_0_never_skips():
    m = LagMeter()
    m.lag(10.0, 10.0)
    assert m.behind(10.5, 10.01, 0.0) == (pytest.approx(0.49), False)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError):
        LagMeter(window_s=0.0)
