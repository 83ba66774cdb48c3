"""Which slip directions a recording holds (learn/coverage.py): sectors, shares, the sparse
ones named, and the per-direction groups that ``aslip evaluate`` scores apart."""

from __future__ import annotations

import numpy as np
import pytest

from aslip_ros.learn import coverage


def _unit(deg) -> np.ndarray:
    a = np.radians(np.asarray(deg, dtype=float))
    return np.stack([np.cos(a), np.sin(a)], axis=1) * 0.01


def test_each_velocity_falls_in_the_sector_around_its_angle():
    v = np.vstack([_unit([0, 22, 23, 90, 179, -179, -90, -23]), [[0.0, 0.0]]])
    assert coverage.sector_of(v).tolist() == [0, 0, 1, 2, 4, 4, 6, 7, -1]
    assert [coverage.sector_name(k) for k in (0, 2, 4, 6)] == \
        ["+0 deg", "+90 deg", "+180 deg", "-90 deg"]


def test_slip_in_every_direction_has_no_sparse_sector():
    rng = np.random.default_rng(0)
    v = _unit(rng.uniform(-180, 180, 4000))
    slip = np.ones(len(v), bool)
    slip[::4] = False                                   # windows without slip do not count
    cov = coverage.direction_coverage(v, slip, hop_s=0.01)
    assert cov["sparse"] == []
    assert sum(r["share"] for r in cov["sectors"]) == pytest.approx(1.0, abs=1e-3)
    assert cov["slip_s"] == pytest.approx(slip.sum() * 0.01)
    assert "every 45-degree sector" in coverage.coverage_text(cov)


def test_a_recording_that_never_slips_backwards_names_those_sectors():
    rng = np.random.default_rng(1)
    v = _unit(rng.uniform(-120, 120, 2000))             # nothing beyond +-120 degrees
    cov = coverage.direction_coverage(v, np.ones(len(v), bool), hop_s=0.01)
    assert cov["sparse"] == ["+135 deg", "+180 deg", "-135 deg"]
    text = coverage.coverage_text(cov)
    assert "+180 deg 0.0%" in text and "extrapolations" in text and "+0 deg" not in text
    none = coverage.direction_coverage(v, np.zeros(len(v), bool), hop_s=0.01)
    assert none["slip_s"] == 0 and none["sparse"] == []
    assert "no slip" in coverage.coverage_text(none)
    assert coverage.warns(cov) and coverage.warns(none)
    even = coverage.direction_coverage(_unit(np.arange(-180, 180, 5)),
                                       np.ones(72, bool), hop_s=0.01)
    assert not coverage.warns(even) and coverage.warning(even) is None
    assert coverage.warning(cov) == "warning: " + text


def test_direction_groups_put_windows_without_slip_apart():
    v = np.vstack([_unit([0, 90, 90]), [[0.0, 0.0]]])
    groups = coverage.direction_groups(v, np.array([True, True, False, True]))
    assert groups.tolist() == ["+0 deg", "+90 deg", coverage.NO_SLIP, coverage.NO_SLIP]
