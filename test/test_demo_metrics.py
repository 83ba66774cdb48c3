"""Table III metrics of the demo on hand-made trajectories (fast, no ROS)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks import demo_metrics as dm

N = np.array([1.0, 0.0, 0.0])


def _push(stop_at_mm: float, rest: bool = True, retract_mm: float = 100.0):
    """Start at the wall (x = 0), retract, re-approach and stop ``stop_at_mm`` past it."""
    t = np.arange(0.0, 10.0, 0.01)
    x = np.where(t < 1.0, -retract_mm * t, -retract_mm)                 # retract
    x = np.where(t >= 1.5, -retract_mm + 40.0 * (t - 1.5), x)           # approach 40 mm/s
    t_stop = 1.5 + (retract_mm + stop_at_mm) / 40.0
    x = np.where(t >= t_stop, stop_at_mm, x)
    if not rest:
        x = np.where(t >= t_stop, stop_at_mm + 40.0 * (t - t_stop), x)
    tcp = np.zeros((t.size, 3))
    tcp[:, 0] = x * 1e-3
    contacts = [(0.0, tcp[0].copy())]
    k = int(np.argmax((t > 1.5) & (x >= 0.0)))
    if x.max() >= 0.0 and k > 0:
        contacts.append((float(t[k]), tcp[k].copy()))
    return t, tcp, contacts


def test_stopping_error_is_travel_past_the_reapproach_contact():
    t, tcp, contacts = _push(6.0)
    o = dm.stop_outcome(t, tcp, N, contacts, object_length_m=0.12,
                        initial_contact=contacts[0][1])
    assert o.touched and o.at_rest and o.success
    assert o.stopping_error_m == pytest.approx(0.006, abs=1e-6)
    assert o.contact_time_s == pytest.approx(1.5 + 100.0 / 40.0, abs=0.011)


def test_stopping_short_of_the_wall_fails_with_a_negative_error():
    t, tcp, contacts = _push(-30.0)
    o = dm.stop_outcome(t, tcp, N, contacts, 0.12, initial_contact=contacts[0][1])
    assert not o.touched and not o.success
    assert o.stopping_error_m == pytest.approx(-0.030, abs=1e-6)


def test_pushing_past_the_object_length_fails():
    t, tcp, contacts = _push(130.0)
    o = dm.stop_outcome(t, tcp, N, contacts, 0.12, initial_contact=contacts[0][1])
    assert o.touched and not o.success
    assert o.stopping_error_m == pytest.approx(0.130, abs=1e-6)


def test_an_arm_still_moving_at_the_end_is_no_success():
    t, tcp, contacts = _push(5.0, rest=False)
    o = dm.stop_outcome(t, tcp, N, contacts, 0.12, initial_contact=contacts[0][1])
    assert o.touched and not o.at_rest and not o.success


def test_contacts_recomputed_from_the_object_trajectory():
    t, tcp, _ = _push(6.0)
    obj = tcp - np.array([0.002, 0.0, 0.0])      # object 2 mm behind the grasp centre
    wall = np.array([0.12 - 0.002, 0.0, 0.0])    # leading point touches at the start
    onsets = dm.contacts_from_trajectory(t, obj, N, wall, 0.12)
    assert [k for _, k in onsets][0] == 0 and len(onsets) == 2
    assert onsets[1][0] == pytest.approx(1.5 + 100.0 / 40.0, abs=0.011)


def test_pose_rmse_against_the_initial_reference():
    t = np.arange(0.0, 4.0, 0.01)
    rel = np.zeros((t.size, 2))
    assert dm.pose_rmse(t, rel) == 0.0
    rel[:, 0] = 0.05                              # a constant offset is the reference
    rel[t >= 2.0, 1] = 0.004                      # 4 mm error for half the time
    assert dm.pose_rmse(t, rel) == pytest.approx(0.004 / math.sqrt(2.0), rel=1e-9)


def test_summary_and_table():
    rows = [{"task": "slip_stop", "method": "aslip", "object": "chips_can", "success": True,
             "stopping_error_m": e} for e in (0.004, 0.006)]
    rows += [{"task": "slip_stop", "method": "svm", "object": "chips_can", "success": False,
              "stopping_error_m": -0.02},
             {"task": "slip_stop", "method": "svm", "object": "chips_can", "success": True,
              "stopping_error_m": None}]
    rows += [{"task": "slip_track", "method": "aslip", "object": "chips_can",
              "pose_rmse_m": v} for v in (0.003, 0.005)]
    s = dm.summarize(rows)
    c = s["slip_stop"]["aslip"]["chips_can"]
    assert (c["successes"], c["trials"]) == (2, 2)
    assert c["mean_mm"] == pytest.approx(5.0) and c["std_mm"] == pytest.approx(1.0)
    svm = s["slip_stop"]["svm"]["overall"]
    assert (svm["successes"], svm["trials"], svm["n_mm"]) == (1, 2, 1)
    assert svm["mean_mm"] == pytest.approx(20.0)       # |error| of the failure counts
    assert s["slip_track"]["aslip"]["overall"]["mean_mm"] == pytest.approx(4.0)
    table = dm.format_table(s)
    assert "2/2, 5.0 ± 1.0" in table and "50/50, 14.5 ± 7.8" in table


def test_summary_counts_reruns_per_cell():
    from benchmarks import demo_metrics as dm
    rows = [dict(task="slip_stop", method="aslip", object="chips_can", success=True,
                 stopping_error_m=0.006, reruns=["stale slip"], controller_reason="slip"),
            dict(task="slip_stop", method="aslip", object="chips_can", success=False,
                 stopping_error_m=None, reruns=["stale_slip", "stale_slip"],
                 controller_reason="stale_slip"),
            dict(task="slip_stop", method="aslip", object="pla_rod", success=True,
                 stopping_error_m=0.004, reruns=[], controller_reason="slip")]
    cells = dm.summarize(rows)["slip_stop"]["aslip"]
    assert cells["chips_can"]["reruns"] == 3 and cells["chips_can"]["trials_rerun"] == 2
    # A rerun is a failure in the table (#26): the first trial succeeded only on its repeat.
    assert cells["chips_can"]["stale_final"] == 1 and cells["chips_can"]["successes"] == 0
    assert cells["pla_rod"]["successes"] == 1
    assert cells["pla_rod"]["reruns"] == 0
    assert cells["overall"]["reruns"] == 3 and cells["overall"]["trials"] == 3


def test_a_slip_track_trial_that_was_rerun_is_a_failure():
    from benchmarks import demo_metrics as dm
    rows = [dict(task="slip_track", method="aslip", object="chips_can", pose_rmse_m=0.004,
                 reruns=["stale_slip"]),
            dict(task="slip_track", method="aslip", object="chips_can", pose_rmse_m=0.006,
                 reruns=[])]
    c = dm.summarize(rows)["slip_track"]["aslip"]["overall"]
    assert (c["successes"], c["trials"], c["reruns"]) == (1, 2, 1)
    assert "| aslip | - | - | 1/2 | 5.0 ± 1.0 |" in dm.methods_table(dm.summarize(rows))


def test_methods_table_lists_every_method_of_the_run():
    rows = [{"task": "slip_stop", "method": m, "object": "chips_can", "trial": 0,
             "success": True, "stopping_error_m": e}
            for m, e in (("aslip", 0.008), ("svm", 0.009), ("stream", 0.007))]
    rows += [{"task": "slip_track", "method": "stream", "object": "chips_can", "trial": 0,
              "pose_rmse_m": 0.012}]
    table = dm.methods_table(dm.summarize(rows))
    lines = {ln.split("|")[1].strip(): ln for ln in table.splitlines() if ln.startswith("| ")}
    assert set(lines) == {"method", "aslip", "stream", "svm"}
    assert "1/1" in lines["stream"] and "7.0" in lines["stream"] and "12.0" in lines["stream"]
    assert lines["svm"].rstrip().endswith("| - |")          # svm ran no slip-track episode


def test_calibration_table_counts_convergence_and_compares_with_no_correction():
    cal = [{"converged": True, "gain_error_db": 0.2, "uncalibrated_error_db": 1.0},
           {"converged": False, "gain_error_db": 0.6, "uncalibrated_error_db": 2.0}]
    rows = [{"task": "slip_track", "method": "aslip", "object": "chips_can", "calibration": c}
            for c in cal]
    rows.append({"task": "slip_track", "method": "aslip_uncalibrated", "object": "chips_can",
                 "calibration": None})
    md = dm.calibration_table(rows)
    assert "| slip-track | aslip | 1/2 | 0/2 | - | 0.40 | 1.50 |" in md
    assert "aslip_uncalibrated" not in md            # no calibration, no row
    assert dm.calibration_table(rows[2:]) == ""


def test_calibration_table_counts_convergence_within_the_bound_after_the_grasp():
    cal = [{"converged": True, "converged_after_s": a, "gain_error_db": 0.5,
            "uncalibrated_error_db": 1.0} for a in (0.7, 1.9, 2.5)]
    cal.append({"converged": False, "converged_after_s": None, "gain_error_db": 0.5,
                "uncalibrated_error_db": 1.0})
    rows = [{"task": "slip_stop", "method": "aslip", "object": "pla_rod", "calibration": c}
            for c in cal]
    md = dm.calibration_table(rows)
    assert "| slip-stop | aslip | 3/4 | 2/4 | 1.90, 2.50 | 0.50 | 1.00 |" in md


def test_slip_track_rmse_is_taken_after_the_hold_at_the_grasp():
    """The hold at the grasp is not tracking: its zero error must not dilute the RMSE."""
    t = np.arange(0.0, 5.0, 0.01)
    rel = np.zeros((t.size, 2))
    rel[t >= 1.0, 0] = 0.01                     # 10 mm off for the whole tracked part
    assert dm.pose_rmse(t, rel, t_from_s=1.0) == pytest.approx(0.01)
    assert dm.pose_rmse(t, rel) < 0.0095        # the whole episode would flatter it


def test_the_track_cell_has_an_interval_of_the_mean_median_and_p90():
    rows = [{"task": "slip_track", "method": "aslip", "object": "chips_can",
             "pose_rmse_m": v * 1e-3, "reruns": []} for v in range(1, 21)]
    c = dm.summarize(rows)["slip_track"]["aslip"]["overall"]
    lo, hi = c["mean_ci95_mm"]
    assert c["mean_mm"] == pytest.approx(10.5)
    assert lo < c["mean_mm"] < hi and hi - lo < 6.0
    assert c["median_mm"] == pytest.approx(10.5) and c["p90_mm"] == pytest.approx(18.1)
    assert f"[{lo:.1f}, {hi:.1f}]; 10.5, 18.1" in dm.methods_table(dm.summarize(rows))


def test_the_tail_table_takes_each_episodes_worst_and_counts_watchdog_gaps():
    rows = [{"task": "slip_track", "method": "aslip", "object": "chips_can",
             "controller_timing": {"slip_gap_max_ms": g, "slip_gaps_over_50ms": int(g > 50)},
             "worker_timing": {"spin_gap_max_ms": g / 2, "spin_gaps_over_50ms": 0,
                               "gc_pause_max_ms": 0.0}}
            for g in (10.0, 12.0, 60.0)]
    rows.append({"task": "slip_track", "method": "svm", "object": "chips_can"})
    md = dm.tail_table(rows)
    line = next(ln for ln in md.splitlines() if ln.startswith("| aslip "))
    assert line.startswith("| aslip | 3 | 12.0 / ") and "/ 60.0 | " in line
    assert line.rstrip().endswith("| 1 |")                # one episode beyond the watchdog
    assert "| svm " not in md                             # no figures, no row
    assert dm.tail_table(rows[3:]) == ""


class _Predictor:
    calibrated = True

    def calibration_summary(self):
        return {"calibration_converged": True, "calibration_converged_after_s": 0.8,
                "calibration_accepted_frames": 120,
                "gain_db": {"a": 1.0, "b": -1.0}}


class _World:
    class synth:                                      # noqa: N801 - stands in for an attribute
        gain = 10.0 ** (np.array([3.0, 1.0]) / 20.0)  # 2 dB apart: relative +1 / -1 dB


def test_calibration_outcome_against_the_scene_gains():
    from benchmarks.demo_episode import calibration_outcome
    out = calibration_outcome(_Predictor(), _World())
    assert out["converged"] is True and out["accepted_frames"] == 120
    assert out["converged_after_s"] == 0.8
    assert out["gain_error_db"] == pytest.approx(0.0, abs=1e-9)
    assert out["uncalibrated_error_db"] == pytest.approx(1.0)
    off = _Predictor()
    off.calibrated = False
    assert calibration_outcome(off, _World()) is None


def test_tracking_delay_is_the_lag_that_best_correlates_estimate_and_truth():
    from benchmarks import demo_metrics as dm
    t = np.arange(0.0, 6.0, 0.01)
    rng = np.random.default_rng(0)
    true = np.stack([np.convolve(rng.standard_normal(t.size), np.ones(20) / 20, "same"),
                     np.zeros(t.size)], axis=1)
    tp = np.arange(0.3, 6.0, 0.01)
    late = np.stack([np.interp(tp - 0.11, t, true[:, 0]), np.zeros(tp.size)], axis=1)
    curves = [dm.lag_curve(t, true, tp, late), dm.lag_curve(t, true, tp, late)]
    assert dm.tracking_delay_ms(curves) == pytest.approx(110.0, abs=5.0)
    assert dm.tracking_delay_ms([]) is None and dm.lag_curve(t[:1], true[:1], tp, late) == []


def test_onset_to_stop_is_the_first_stop_command_after_the_onset():
    from benchmarks import demo_metrics as dm
    assert dm.onset_to_stop_s(1.0, [0.2, 1.05, 2.0]) == pytest.approx(0.05)
    assert dm.onset_to_stop_s(None, [1.0]) is None and dm.onset_to_stop_s(3.0, [1.0]) is None
    rows = [dict(task="slip_stop", method="aslip", object="o", success=True,
                 stopping_error_m=0.005, onset_to_stop_s=s) for s in (0.03, 0.05, 0.04)]
    cell = dm.summarize(rows)["slip_stop"]["aslip"]["overall"]
    assert cell["onset_to_stop_median_ms"] == pytest.approx(40.0)
    assert "| 40 |" in dm.methods_table(dm.summarize(rows))


def test_the_worker_stall_probe_reports_the_tail_like_the_live_bench():
    from benchmarks.demo_episode import StallProbe
    probe = StallProbe()
    probe.gaps = [0.001] * 998 + [0.030, 0.060]      # seconds: one gap over the watchdog
    probe.gc_pauses = [(0, 0.0002), (2, 0.004)]
    s = probe.summary()
    assert s["spin_gaps"] == 1000 and s["spin_gaps_over_50ms"] == 1
    assert s["spin_gap_p50_ms"] == pytest.approx(1.0)
    assert s["spin_gap_max_ms"] == pytest.approx(60.0)
    assert 30.0 <= s["spin_gap_p999_ms"] <= 60.0
    assert s["gc_full_collections"] == 1 and s["gc_full_max_ms"] == pytest.approx(4.0)
    empty = StallProbe().summary()
    assert empty["spin_gap_max_ms"] is None and empty["spin_gaps_over_50ms"] == 0


# --- pivot-stop (issue #21) -------------------------------------------------------------

def _lowering(stop_s: float, rest: bool = True):
    """The arm lowers the object at 30 mm/s and stops at ``stop_s`` (or keeps going)."""
    t = np.arange(0.0, 6.0, 0.01)
    z = -0.03 * np.minimum(t, stop_s) if rest else -0.03 * t
    tcp = np.zeros((t.size, 3))
    tcp[:, 2] = z
    return t, tcp


def test_pivot_outcome_is_the_angle_turned_in_degrees_and_the_onset_to_stop():
    t, tcp = _lowering(3.0)
    o = dm.pivot_outcome(t, tcp, -math.radians(4.0), 2.95, [0.5, 3.0, 5.0])
    assert o.angle_deg == pytest.approx(4.0)          # either sense of turn, in degrees
    assert o.turned and o.at_rest
    assert o.rotation_onset_s == pytest.approx(2.95)
    assert o.onset_to_stop_s == pytest.approx(0.05)
    d = o.to_dict()
    assert d["angle_deg"] == pytest.approx(4.0) and d["onset_to_stop_s"] == pytest.approx(0.05)


def test_pivot_outcome_without_a_turn_or_a_rest():
    t, tcp = _lowering(3.0, rest=False)
    o = dm.pivot_outcome(t, tcp, 0.0, None, [])
    assert not o.turned and not o.at_rest and o.angle_deg == 0.0
    assert o.to_dict()["rotation_onset_s"] is None and o.to_dict()["onset_to_stop_s"] is None


def _pivot_rows():
    rows = []
    for k in range(10):
        for arm, angle, reason in (("rotation_aware", 2.0 + 0.1 * k, "rotation"),
                                   ("ignores_rotation", 20.0 + k, "max_travel")):
            rows.append({"task": "pivot_stop", "method": "aslip", "arm": arm,
                         "object": "chips_can" if k < 5 else "pla_rod", "trial": k % 5,
                         "angle_deg": angle, "turned": True, "at_rest": True,
                         "controller_reason": reason, "onset_to_stop_s": 0.05,
                         "reruns": []})
    return rows


def test_pivot_summary_per_arm_with_an_interval_and_the_paired_saving():
    rows = _pivot_rows()
    rows[0]["reruns"] = ["stale_slip"]                # a rerun trial fails, as elsewhere
    t = dm.summarize(rows)["pivot_stop"]
    aware, ign = t["aslip/rotation_aware"]["overall"], t["aslip/ignores_rotation"]["overall"]
    assert (aware["successes"], aware["trials"]) == (9, 10)
    assert aware["reasons"] == {"rotation": 10} and ign["reasons"] == {"max_travel": 10}
    assert ign["successes"] == 0                      # never stopped on its estimate
    assert aware["angle_mean_deg"] == pytest.approx(2.45)
    lo, hi = ign["angle_ci95_deg"]
    assert ign["angle_mean_deg"] == pytest.approx(24.5) and lo < 24.5 < hi
    assert aware["onset_to_stop_median_ms"] == pytest.approx(50.0)
    assert set(t["aslip/rotation_aware"]) == {"chips_can", "pla_rod", "overall"}
    paired = t["aslip/paired"]["overall"]
    assert paired["pairs"] == 10 and paired["aware_smaller"] == 10
    assert paired["saved_mean_deg"] == pytest.approx(24.5 - 2.45)
    md = dm.pivot_table(dm.summarize(rows))
    assert "| aslip | rotation aware | 9/10 | rotation 10 | 2.5 ± 0.3 |" in md
    assert "| aslip | ignores rotation | 0/10 | max_travel 10 | 24.5 ± 2.9 |" in md
    assert "saved 22.1 deg" in md and "paired over 10 seeds" in md
    assert dm.pivot_table(dm.summarize(rows[:0])) == ""


def test_the_pivot_rows_leave_the_other_tables_alone():
    rows = _pivot_rows()
    s = dm.summarize(rows)
    assert s["slip_stop"] == {} and s["slip_track"] == {}
    assert "aslip" not in dm.methods_table(s).split("\n", 3)[-1]
