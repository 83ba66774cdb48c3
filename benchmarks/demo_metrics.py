"""Table III metrics of the closed-loop demo, ROS-free (trajectories in, numbers out).

Slip-stop (the paper's Task 1): a trial succeeds when the object touched the wall on the
re-approach and the arm came to rest before it had pushed on past the object's length. The
stopping error ``Delta x`` is how far the TCP travelled along the push direction past the
pose of that wall contact.

Slip-track (Task 2): the error is the gripper-object relative position in the grasp plane
against its reference (the median over the first 0.1 s, as in the paper's draft), and the
metric is its RMSE over the whole trajectory.

Pivot-stop (issue #21): the object, held by one end, is lowered onto a surface that meets it
off the grasp axis, so it turns between the pads instead of sliding. The measure is the angle
the object turned (relative to the finger, about the pad normal) before the arm came to
rest, in degrees; the same seeds run an arm that acts on the rotation estimate and one that
ignores it (planar slip or its travel limit only), so the two are paired trial by trial.

Inputs are the scene's true trajectory (``World.trajectory()`` or the ``trajectory_out``
``.npz`` of ``scene_sim``): ``t`` (N,), ``tcp`` (N, 3) world positions, ``rel`` (N, 2)
object position in the grasp plane relative to the grasp centre.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Iterable, Optional, Sequence

import numpy as np

#: The paper's Table III (per object: SVM successes, mean, std; A-SLIP successes, mean,
#: std; SVM pose RMSE mean, std; A-SLIP pose RMSE mean, std), millimetres, 10 trials each.
PAPER_TABLE3 = {
    "pla_rod": ((7, 39.7, 38.7), (10, 16.7, 8.9), (32.4, 20.2), (16.9, 12.4)),
    "glass_cleaner": ((6, 13.4, 18.7), (10, 10.5, 5.7), (32.4, 18.1), (15.0, 9.5)),
    "chips_can": ((8, 16.7, 16.4), (10, 19.8, 6.6), (33.8, 21.7), (12.9, 9.4)),
    "mustard_container": ((5, 17.4, 31.3), (10, 9.7, 6.7), (25.0, 14.4), (20.5, 14.4)),
    "cracker_box": ((5, 44.3, 27.6), (10, 15.8, 7.1), (35.5, 20.4), (13.0, 9.3)),
    "overall": ((31, 26.3, 29.6), (50, 14.5, 7.8), (32.0, 19.3), (15.8, 11.3)),
}
PAPER_TRIALS = {"pla_rod": 10, "glass_cleaner": 10, "chips_can": 10,
                "mustard_container": 10, "cracker_box": 10, "overall": 50}

#: A TCP slower than this over the last samples counts as at rest [m/s].
REST_SPEED_M_S = 2e-3
#: Reference window of the tracking error [s] (the paper: the first 0.1 s).
TRACK_REFERENCE_S = 0.1


@dataclass(frozen=True)
class StopOutcome:
    """One slip-stop trial. Distances in metres, signed along the push direction."""

    success: bool
    touched: bool
    at_rest: bool
    stopping_error_m: float        # final TCP past the contact pose (negative: short of it)
    contact_time_s: float          # NaN without a re-approach contact
    final_speed_m_s: float

    def to_dict(self) -> dict:
        """JSON-friendly dict (NaN becomes None)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in asdict(self).items()}


def _final_speed(t: np.ndarray, tcp: np.ndarray, span_s: float = 0.1) -> float:
    """Mean TCP speed over the last ``span_s`` of the trajectory."""
    if t.shape[0] < 2:
        return math.nan
    k = max(0, int(np.searchsorted(t, t[-1] - span_s)) - 1)
    dt = float(t[-1] - t[k])
    if dt <= 0:
        return math.nan
    return float(np.linalg.norm(tcp[-1] - tcp[k]) / dt)


def reapproach_contact(t: np.ndarray, tcp: np.ndarray, push_dir: Sequence[float],
                       contacts: Iterable[tuple[float, Sequence[float]]]
                       ) -> Optional[tuple[float, np.ndarray]]:
    """The first wall contact after the retract (or the first contact without one).

    The trial starts in contact with the wall, so the contact that counts is the first
    onset at or after the TCP's farthest point back along the push direction.
    """
    n = np.asarray(push_dir, dtype=float)
    n = n / np.linalg.norm(n)
    t_back = float(t[int(np.argmin(tcp @ n))]) if t.shape[0] else 0.0
    for tc, p in contacts:
        if tc >= t_back:
            return float(tc), np.asarray(p, dtype=float)
    return None


def contacts_from_trajectory(t, obj, push_dir, wall_point, length_m: float
                             ) -> list[tuple[float, np.ndarray]]:
    """Wall-contact onsets ``(t, index)`` recomputed from a recorded trajectory.

    For ``scene_sim``'s ``.npz`` (which stores only the first contact): the object's
    leading point is ``object . n + length``; contact while it reaches the wall plane.
    Returns ``(time, k)`` pairs, ``k`` the trajectory index of the onset.
    """
    n = np.asarray(push_dir, dtype=float)
    n = n / np.linalg.norm(n)
    lead = np.asarray(obj, dtype=float) @ n + float(length_m)
    # Sub-micrometre tolerance: the scene starts the object exactly at the wall.
    touching = lead >= float(np.asarray(wall_point, dtype=float) @ n) - 1e-6
    onsets = np.flatnonzero(touching & ~np.concatenate([[False], touching[:-1]]))
    return [(float(np.asarray(t)[k]), int(k)) for k in onsets]


def stop_outcome(t, tcp, push_dir, contacts, object_length_m: float,
                 initial_contact: Optional[Sequence[float]] = None) -> StopOutcome:
    """Score one wall-push trial from the true trajectory and the wall contacts.

    ``initial_contact``: the TCP position of the starting contact, used as the reference
    when the object never reached the wall again (then the error says how far short the
    arm stopped).
    """
    t = np.asarray(t, dtype=float)
    tcp = np.asarray(tcp, dtype=float)
    n = np.asarray(push_dir, dtype=float)
    n = n / np.linalg.norm(n)
    hit = reapproach_contact(t, tcp, n, contacts)
    speed = _final_speed(t, tcp)
    at_rest = bool(math.isfinite(speed) and speed < REST_SPEED_M_S)
    if hit is not None:
        ref, t_c = hit[1], hit[0]
    elif initial_contact is not None:
        ref, t_c = np.asarray(initial_contact, dtype=float), math.nan
    else:
        ref, t_c = None, math.nan
    err = float((tcp[-1] - ref) @ n) if ref is not None and tcp.shape[0] else math.nan
    touched = hit is not None
    success = bool(touched and at_rest and math.isfinite(err) and err < object_length_m)
    return StopOutcome(success, touched, at_rest, err, t_c, speed)


#: The pivot-stop arms: the slip-stop controller with ``stop_on_rotation`` true and false.
PIVOT_ARMS = ("rotation_aware", "ignores_rotation")
#: The controller's stop reasons that mean it stopped on its estimate.
ESTIMATE_REASONS = ("slip", "rotation")


@dataclass(frozen=True)
class PivotOutcome:
    """One pivot-stop trial: the angle turned [deg] when the episode ended, whether the arm
    was at rest then (otherwise the angle is only how far it had turned so far), and the
    time from the true rotation onset to the first stop command the arm received."""

    angle_deg: float
    turned: bool                   # the scene reports a rotation onset
    at_rest: bool
    final_speed_m_s: float
    rotation_onset_s: float        # NaN without an onset
    onset_to_stop_s: float         # NaN without an onset or a stop after it

    def to_dict(self) -> dict:
        """JSON-friendly dict (NaN becomes None)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in asdict(self).items()}


def pivot_outcome(t, tcp, angle_rad: float, rotation_onset_s: Optional[float],
                  stop_times: Sequence[float]) -> PivotOutcome:
    """Score one pivot-stop trial from the true trajectory (``t``, ``tcp``), the angle the
    object turned by the end (``World.angle_turned()`` [rad], either sense), the scene's
    rotation onset and the arm's stop commands (scene times [s])."""
    t = np.asarray(t, dtype=float)
    tcp = np.asarray(tcp, dtype=float)
    speed = _final_speed(t, tcp)
    onset = math.nan if rotation_onset_s is None else float(rotation_onset_s)
    to_stop = onset_to_stop_s(onset, stop_times)
    angle = abs(float(angle_rad)) if angle_rad is not None else math.nan
    return PivotOutcome(angle_deg=math.degrees(angle), turned=math.isfinite(onset),
                        at_rest=bool(math.isfinite(speed) and speed < REST_SPEED_M_S),
                        final_speed_m_s=speed, rotation_onset_s=onset,
                        onset_to_stop_s=math.nan if to_stop is None else to_stop)


def pivot_row(r: dict) -> str:
    """The pivot table's row of one episode: ``<method>/<arm>``."""
    return f"{r['method']}/{r.get('arm', PIVOT_ARMS[0])}"


def pivot_success(r: dict) -> bool:
    """A pivot-stop trial stopped on the estimate: the object turned, the controller
    stopped on slip or rotation and the arm came to rest; a rerun trial is a failure, as in
    the other tasks (:func:`succeeded`)."""
    return bool(not r.get("reruns") and r.get("turned") and r.get("at_rest")
                and r.get("controller_reason") in ESTIMATE_REASONS)


def _pivot_cell(rows: Sequence[dict]) -> dict:
    angles = np.asarray([r["angle_deg"] for r in rows if r.get("angle_deg") is not None
                         and math.isfinite(r["angle_deg"])], dtype=float)
    m, s, n = mean_std(angles)
    lo, hi = mean_interval(angles)
    reasons: dict = {}
    for r in rows:
        key = str(r.get("controller_reason") or "none")
        reasons[key] = reasons.get(key, 0) + 1
    stops = [r["onset_to_stop_s"] * 1e3 for r in rows if r.get("onset_to_stop_s") is not None]
    return {"trials": len(rows), "successes": sum(pivot_success(r) for r in rows),
            "at_rest": sum(bool(r.get("at_rest")) for r in rows),
            "turned": sum(bool(r.get("turned")) for r in rows),
            "reasons": dict(sorted(reasons.items())),
            "angle_mean_deg": _num(m), "angle_std_deg": _num(s), "n_angle": n,
            "angle_ci95_deg": [_num(lo), _num(hi)],
            "angle_median_deg": _num(float(np.median(angles))) if n else None,
            "angle_p90_deg": _num(float(np.percentile(angles, 90))) if n else None,
            "onset_to_stop_median_ms": _num(float(np.median(stops))) if stops else None,
            "n_onset_to_stop": len(stops), **_reruns(rows)}


def summarize_pivot(results: Sequence[dict]) -> dict:
    """The pivot-stop cells: ``{<method>/<arm>: {object: cell, "overall": cell}}``, and
    per method with both arms ``"<method>/paired"``: the angle the rotation-aware arm saved
    against the one that ignores rotation, per trial on the same seed (mean and its 95 %
    bootstrap interval, degrees)."""
    rows = [r for r in results if r.get("task") == "pivot_stop"]
    out: dict = {}
    for label in sorted({pivot_row(r) for r in rows}):
        mine = [r for r in rows if pivot_row(r) == label]
        method, arm = label.split("/", 1)
        cells = {obj: _pivot_cell([r for r in mine if r["object"] == obj])
                 for obj in sorted({r["object"] for r in mine})}
        cells["overall"] = _pivot_cell(mine)
        for c in cells.values():
            c.update(method=method, arm=arm)
        out[label] = cells
    for method in sorted({r["method"] for r in rows}):
        saved = paired_angle_saved([r for r in rows if r["method"] == method])
        if saved is not None:
            out[f"{method}/paired"] = {"overall": saved}
    return out


def paired_angle_saved(rows: Sequence[dict]) -> Optional[dict]:
    """Angle [deg] of the arm that ignores rotation minus that of the rotation-aware arm,
    per (object, trial) run by both (None without such pairs)."""
    by = {}
    for r in rows:
        if r.get("angle_deg") is not None and math.isfinite(r["angle_deg"]):
            by[(r.get("arm", PIVOT_ARMS[0]), r["object"], r.get("trial"))] = r["angle_deg"]
    d = np.asarray([by[(PIVOT_ARMS[1], o, k)] - a for (arm, o, k), a in sorted(by.items())
                    if arm == PIVOT_ARMS[0] and (PIVOT_ARMS[1], o, k) in by], dtype=float)
    if d.size == 0:
        return None
    lo, hi = mean_interval(d)
    return {"pairs": int(d.size), "saved_mean_deg": _num(float(d.mean())),
            "saved_ci95_deg": [_num(lo), _num(hi)],
            "aware_smaller": int(np.sum(d > 0))}


def pivot_table(table: dict) -> str:
    """Markdown: one row per estimator and arm (overall), and the paired difference."""
    cells = table.get("pivot_stop") or {}
    rows = [(k, v["overall"]) for k, v in cells.items() if not k.endswith("/paired")]
    if not rows:
        return ""
    lines = ["", "| pivot-stop | arm | stopped on the estimate | stop reasons | angle turned "
                 "before rest deg: mean ± std | 95 % interval of the mean | median, p90 | "
                 "rotation onset to stop ms (median) |", "|---|---|---|---|---|---|---|---|"]
    for label, c in rows:
        lo, hi = c["angle_ci95_deg"]
        ci = "-" if lo is None or hi is None else f"[{lo:.1f}, {hi:.1f}]"
        spread = "-" if c["angle_median_deg"] is None else \
            f"{c['angle_median_deg']:.1f}, {c['angle_p90_deg']:.1f}"
        onset = c["onset_to_stop_median_ms"]
        reasons = ", ".join(f"{k} {v}" for k, v in c["reasons"].items())
        lines.append(f"| {c['method']} | {c['arm'].replace('_', ' ')} | "
                     f"{c['successes']}/{c['trials']} | {reasons} | "
                     f"{_fmt(c['angle_mean_deg'], c['angle_std_deg'])} | {ci} | {spread} | "
                     + ("-" if onset is None else f"{onset:.0f}") + " |")
    for label, v in cells.items():
        if label.endswith("/paired"):
            p = v["overall"]
            lo, hi = p["saved_ci95_deg"]
            ci = "" if lo is None or hi is None else f" [{lo:.1f}, {hi:.1f}]"
            lines.append("")
            saved = round(p["saved_mean_deg"], 1) + 0.0          # never "-0.0"
            lines.append(f"{label.split('/')[0]}: acting on rotation saved {saved:.1f} deg"
                         f"{ci} of turn per trial (paired over {p['pairs']} seeds; smaller "
                         f"in {p['aware_smaller']}).")
    return "\n".join(lines) + "\n"


def pose_rmse(t, rel, t_ref_s: float = TRACK_REFERENCE_S, t_from_s: float = 0.0) -> float:
    """RMSE [m] of the grasp-plane relative position against its initial reference (the
    median over the first ``t_ref_s``), over the samples from ``t_from_s`` on (the task's
    tracking part, after any hold at the grasp)."""
    t = np.asarray(t, dtype=float)
    rel = np.asarray(rel, dtype=float)
    if rel.ndim != 2 or rel.shape[0] == 0:
        return math.nan
    k = max(1, int(np.searchsorted(t, t[0] + t_ref_s, side="right")))
    ref = np.median(rel[:k], axis=0)
    e = rel[t >= t[0] + t_from_s] - ref
    if e.shape[0] == 0:
        return math.nan
    return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))


#: Shifts of the estimate against the true slip velocity searched for the tracking delay [s].
LAGS_S = np.round(np.arange(0.0, 0.3001, 0.005), 3)


def lag_curve(t_true, v_true, t_pred, v_pred, lags_s=LAGS_S, dt_s: float = 0.005) -> list:
    """Correlation of the published slip velocity with the true one shifted by each lag:
    ``sum v_pred(t) . v_true(t - lag)`` over a common ``dt_s`` grid, normalised per lag.
    Summed over the episodes of a method, its argmax is the estimate's tracking delay in
    the loop (an estimate stamped at the end of its window lags by about half a window).
    Empty when there is nothing to correlate."""
    t_true, t_pred = np.asarray(t_true, float), np.asarray(t_pred, float)
    v_true = np.asarray(v_true, float).reshape(-1, 2)
    v_pred = np.asarray(v_pred, float).reshape(-1, 2)
    if t_true.size < 2 or t_pred.size < 2:
        return []
    lo, hi = max(t_true[0] + lags_s[-1], t_pred[0]), min(t_true[-1], t_pred[-1])
    if hi - lo < 10 * dt_s:
        return []
    grid = np.arange(lo, hi, dt_s)
    pred = np.stack([np.interp(grid, t_pred, v_pred[:, j]) for j in range(2)], axis=1)
    out = []
    for lag in lags_s:
        true = np.stack([np.interp(grid - lag, t_true, v_true[:, j]) for j in range(2)], axis=1)
        den = np.sqrt((pred ** 2).sum() * (true ** 2).sum())
        out.append(float((pred * true).sum() / den) if den > 0 else 0.0)
    return out


def tracking_delay_ms(curves: Iterable[Sequence[float]], lags_s=LAGS_S) -> Optional[float]:
    """The lag [ms] that best correlates estimate and truth over the summed curves."""
    curves = [np.asarray(c, float) for c in curves if c is not None and len(c) == len(lags_s)]
    if not curves:
        return None
    return float(lags_s[int(np.argmax(np.sum(curves, axis=0)))] * 1e3)


def onset_to_stop_s(onset_s: Optional[float], stop_times: Sequence[float]) -> Optional[float]:
    """Seconds from the true slip onset to the first stop command the arm received after
    it (None without an onset or a stop)."""
    if onset_s is None or not math.isfinite(onset_s):
        return None
    after = [t for t in stop_times if t >= onset_s]
    return float(after[0] - onset_s) if after else None


def stop_hold(t_cmd_s, speeds, end_s: float) -> dict:
    """The arm commands of a slip-stop trial after its stop, from their stamps (scene time
    [s]) and speeds [m/s]: ``ends_on_stop``, the newest command is a stop and every moving
    one is older (strictly); ``stop_s``, the first stop after the newest moving command
    (None when the newest command moves); ``held_s``, the scene time from that stop to the
    episode's end ``end_s`` with no moving command. A controller that stopped and stayed
    stopped ends on a stop held for as long as the episode watched it (slip-stop: its
    ``settle_result_s``); a moving command after the stop ends the trial moving or moves the
    stop later, so ``held_s`` comes short."""
    t = np.asarray(t_cmd_s, dtype=float).reshape(-1)
    v = np.asarray(speeds, dtype=float).reshape(-1)
    moving = t[v > 0.0]
    last_move = float(moving.max()) if moving.size else -math.inf
    after = t[(v == 0.0) & (t > last_move)]
    stop = float(after.min()) if after.size else None
    return {"commands": int(t.size), "moving": int(moving.size),
            "ends_on_stop": stop is not None,
            "stop_s": None if stop is None else round(stop, 6),
            "held_s": None if stop is None else round(float(end_s) - stop, 6)}


def mean_std(values: Iterable[float]) -> tuple[float, float, int]:
    """Mean, population std and count of the finite values (NaN, NaN, 0 if none)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if v.size == 0:
        return math.nan, math.nan, 0
    return float(v.mean()), float(v.std()), int(v.size)


def summarize(results: Sequence[dict]) -> dict:
    """Table III from episode results.

    Each result: ``task`` (``slip_stop``/``slip_track``), ``method``, ``object`` and, for
    slip-stop, ``success`` and ``stopping_error_m`` (its absolute value is averaged, over
    all trials that have one, failures included, as the paper's spread includes them);
    for slip-track, ``pose_rmse_m``. Values reported in millimetres. Pivot-stop episodes
    (``angle_deg``, ``arm``) add ``pivot_stop`` (:func:`summarize_pivot`, degrees).
    """
    out: dict = {}
    for task in ("slip_stop", "slip_track"):
        rows = [r for r in results if r.get("task") == task]
        methods = sorted({r["method"] for r in rows})
        out[task] = {}
        for method in methods:
            mine = [r for r in rows if r["method"] == method]
            groups = {}
            for obj in sorted({r["object"] for r in mine}):
                groups[obj] = [r for r in mine if r["object"] == obj]
            groups["overall"] = mine
            out[task][method] = {g: _cell(task, rs) for g, rs in groups.items()}
    pivot = summarize_pivot(results)
    if pivot:
        out["pivot_stop"] = pivot
    return out


def _reruns(rows: Sequence[dict]) -> dict:
    """Repeats after a watchdog stop on stale input: visible per cell, never hidden.

    ``reruns``: repeated runs in all; ``trials_rerun``: trials that needed at least one;
    ``stale_final``: trials whose last run still ended on stale input (counted as failures).
    """
    return {"reruns": int(sum(len(r.get("reruns") or []) for r in rows)),
            "trials_rerun": int(sum(1 for r in rows if r.get("reruns"))),
            "stale_final": int(sum(1 for r in rows
                                   if str(r.get("controller_reason") or "")
                                   .startswith("stale")))}


def _cell(task: str, rows: Sequence[dict]) -> dict:
    return {**_cell_values(task, rows), **_reruns(rows), **_timing(rows)}


def _timing(rows: Sequence[dict]) -> dict:
    """The estimate's tracking delay in the loop and, for slip-stop, slip onset to stop."""
    stops = [r["onset_to_stop_s"] * 1e3 for r in rows if r.get("onset_to_stop_s") is not None]
    return {"tracking_delay_ms": tracking_delay_ms(r.get("lag_curve") for r in rows),
            "onset_to_stop_median_ms": _num(float(np.median(stops))) if stops else None,
            "n_onset_to_stop": len(stops)}


def succeeded(task: str, r: dict) -> bool:
    """One trial's verdict in the table. A trial that had to be run again after a watchdog
    stop on stale input is a failure, whatever its repeat did: on a robot that trial was
    lost (its repeats stay visible in ``reruns``)."""
    if r.get("reruns"):
        return False
    if task == "slip_stop":
        return bool(r.get("success"))
    return r.get("pose_rmse_m") is not None


def _cell_values(task: str, rows: Sequence[dict]) -> dict:
    ok_rows = [r for r in rows if succeeded(task, r)]
    if task == "slip_stop":
        errs = [abs(r["stopping_error_m"]) * 1e3 if r.get("stopping_error_m") is not None
                else None for r in rows]
        m, s, n = mean_std(errs)
        ok = [abs(r["stopping_error_m"]) * 1e3 for r in ok_rows
              if r.get("stopping_error_m") is not None]
        ms, ss, _ = mean_std(ok)
        return {"successes": len(ok_rows), "trials": len(rows), "mean_mm": _num(m),
                "std_mm": _num(s), "n_mm": n, "mean_success_mm": _num(ms),
                "std_success_mm": _num(ss)}
    vals = [r["pose_rmse_m"] * 1e3 if r.get("pose_rmse_m") is not None else None
            for r in rows]
    m, s, n = mean_std(vals)
    fin = np.asarray([v for v in vals if v is not None and math.isfinite(v)], dtype=float)
    lo, hi = mean_interval(fin)
    return {"successes": len(ok_rows), "trials": len(rows),
            "mean_mm": _num(m), "std_mm": _num(s), "n_mm": n,
            "median_mm": _num(float(np.median(fin))) if fin.size else None,
            "p90_mm": _num(float(np.percentile(fin, 90))) if fin.size else None,
            "mean_ci95_mm": [_num(lo), _num(hi)]}


def mean_interval(values: np.ndarray, n_boot: int = 2000, seed: int = 0
                  ) -> tuple[float, float]:
    """95 % percentile-bootstrap interval of the mean (NaN, NaN for fewer than 2 values)."""
    v = np.asarray(values, dtype=float)
    if v.size < 2:
        return math.nan, math.nan
    idx = np.random.default_rng(seed).integers(0, v.size, (n_boot, v.size))
    means = v[idx].mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def _num(x: float) -> Optional[float]:
    return None if x is None or not math.isfinite(x) else round(float(x), 3)


def _fmt(mean, std) -> str:
    if mean is None:
        return "n/a"
    return f"{mean:.1f} ± {std:.1f}"


def format_table(summary: dict, methods: Sequence[str] = ("svm", "aslip")) -> str:
    """Markdown Table III: this run's numbers beside the paper's."""
    objects = [o for o in PAPER_TABLE3 if o != "overall"]
    stop = summary.get("slip_stop", {})
    track = summary.get("slip_track", {})
    present = [o for o in objects if any(o in stop.get(m, {}) or o in track.get(m, {})
                                         for m in methods)] + ["overall"]
    head = ("| object | stop SVM (demo) | stop A-SLIP (demo) | stop SVM (paper) | "
            "stop A-SLIP (paper) | track SVM (demo) | track A-SLIP (demo) | "
            "track SVM (paper) | track A-SLIP (paper) |")
    lines = [head, "|" + "---|" * 9]
    for o in present:
        p = PAPER_TABLE3[o]
        cells = [o.replace("_", " ")]
        for m in methods:
            c = stop.get(m, {}).get(o)
            cells.append("-" if c is None else
                         f"{c['successes']}/{c['trials']}, {_fmt(c['mean_mm'], c['std_mm'])}")
        cells.append(f"{p[0][0]}/{PAPER_TRIALS[o]}, {p[0][1]:.1f} ± {p[0][2]:.1f}")
        cells.append(f"{p[1][0]}/{PAPER_TRIALS[o]}, {p[1][1]:.1f} ± {p[1][2]:.1f}")
        for m in methods:
            c = track.get(m, {}).get(o)
            cells.append("-" if c is None else _fmt(c["mean_mm"], c["std_mm"]))
        cells.append(f"{p[2][0]:.1f} ± {p[2][1]:.1f}")
        cells.append(f"{p[3][0]:.1f} ± {p[3][1]:.1f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def methods_table(summary: dict) -> str:
    """Every method of this run side by side, overall: slip-stop successes and |error|, and
    slip-track pose RMSE (mean ± std, mm)."""
    stop = summary.get("slip_stop", {})
    track = summary.get("slip_track", {})
    methods = sorted(set(stop) | set(track))
    lines = ["", "| method | slip-stop successes | slip-stop error mm | slip-track successes "
                 "| slip-track RMSE mm | slip-track RMSE: 95 % interval of the mean; median, "
                 "p90 | tracking delay ms (slip-track) | slip onset to stop ms (median) |",
             "|---|---|---|---|---|---|---|---|"]
    for m in methods:
        c = stop.get(m, {}).get("overall")
        t = track.get(m, {}).get("overall")
        delay = (t or {}).get("tracking_delay_ms")
        onset = (c or {}).get("onset_to_stop_median_ms")
        lines.append(f"| {m} | " + (f"{c['successes']}/{c['trials']}" if c else "-") + " | "
                     + (_fmt(c["mean_mm"], c["std_mm"]) if c else "-") + " | "
                     + (f"{t['successes']}/{t['trials']}" if t else "-") + " | "
                     + (_fmt(t["mean_mm"], t["std_mm"]) if t else "-") + " | "
                     + (_spread(t) if t else "-") + " | "
                     + ("-" if delay is None else f"{delay:.0f}") + " | "
                     + ("-" if onset is None else f"{onset:.0f}") + " |")
    return "\n".join(lines) + "\n"


#: The issue's bound on the per-grasp calibration: converged this soon after the grasp [s].
CONVERGE_BOUND_S = 2.0


def _spread(cell: dict) -> str:
    lo, hi = cell.get("mean_ci95_mm") or (None, None)
    if lo is None or hi is None or cell.get("median_mm") is None:
        return "-"
    return f"[{lo:.1f}, {hi:.1f}]; {cell['median_mm']:.1f}, {cell['p90_mm']:.1f}"


def calibration_table(results: Sequence[dict]) -> str:
    """Where the live per-grasp calibration got by each episode's end, per task and method
    with one: episodes converged, and the RMS error of the relative microphone gains [dB]
    against leaving them uncorrected (mean over episodes). Empty without such methods."""
    rows = [r for r in results if isinstance(r.get("calibration"), dict)]
    if not rows:
        return ""
    lines = ["", f"| task | method | calibration converged | within {CONVERGE_BOUND_S:g} s "
                 "of the grasp | time to converge s (median, max) | gain error dB | "
                 "uncorrected gain error dB |", "|---|---|---|---|---|---|---|"]
    for task in ("slip_stop", "slip_track", "pivot_stop"):
        for method in sorted({r["method"] for r in rows if r["task"] == task}):
            cal = [r["calibration"] for r in rows
                   if r["task"] == task and r["method"] == method]
            err, _, _ = mean_std(c.get("gain_error_db") for c in cal)
            raw, _, _ = mean_std(c.get("uncalibrated_error_db") for c in cal)
            after = [c["converged_after_s"] for c in cal
                     if c.get("converged_after_s") is not None]
            within = sum(1 for a in after if a <= CONVERGE_BOUND_S)
            spread = f"{np.median(after):.2f}, {max(after):.2f}" if after else "-"
            lines.append(f"| {task.replace('_', '-')} | {method} | "
                         f"{sum(bool(c.get('converged')) for c in cal)}/{len(cal)} | "
                         f"{within}/{len(cal)} | {spread} | {err:.2f} | {raw:.2f} |")
    return "\n".join(lines) + "\n"


#: The tail figures of the live path per episode (the worker's StallProbe and the
#: controller's input gaps) [ms]: (summary key, where, what).
TAIL_FIGURES = (("slip_gap_max_ms", "controller_timing", "SlipVector gap at the controller"),
                ("spin_gap_max_ms", "worker_timing", "executor gap in the worker"),
                ("gc_pause_max_ms", "worker_timing", "garbage-collector pause"))


def tail_values(results: Sequence[dict], method: str, key: str, where: str) -> np.ndarray:
    """Per episode of ``method``, its worst ``key`` [ms] (episodes without it left out)."""
    return np.asarray([r[where][key] for r in results if r.get("method") == method
                       and isinstance(r.get(where), dict) and r[where].get(key) is not None],
                      dtype=float)


def tail_table(results: Sequence[dict]) -> str:
    """Per method, the worst step of each episode: median, p99, p99.9 and max over the
    episodes, for the controller's SlipVector gaps, the worker's executor gaps and the
    garbage collector's pauses [ms]; and how many episodes had a gap over the 50 ms
    watchdog. Empty when no episode carries the figures."""
    methods = sorted({r["method"] for r in results
                      if isinstance(r.get("worker_timing"), dict)})
    if not methods:
        return ""
    heads = " | ".join(f"{what}: p50 / p99 / p99.9 / max ms" for _, _, what in TAIL_FIGURES)
    lines = ["", f"| method | episodes | {heads} | episodes with a gap over 50 ms |",
             "|---|---|" + "---|" * 4]
    for m in methods:
        cells = []
        for key, where, _ in TAIL_FIGURES:
            v = tail_values(results, m, key, where)
            stats = (*np.percentile(v, [50, 99, 99.9]), v.max()) if v.size else ()
            cells.append(" / ".join(f"{x:.1f}" for x in stats) or "-")
        over = sum(1 for r in results if r.get("method") == m and (
            (r.get("controller_timing") or {}).get("slip_gaps_over_50ms", 0) > 0
            or (r.get("worker_timing") or {}).get("spin_gaps_over_50ms", 0) > 0))
        n = sum(1 for r in results if r.get("method") == m)
        lines.append(f"| {m} | {n} | " + " | ".join(cells) + f" | {over} |")
    return "\n".join(lines) + "\n"
