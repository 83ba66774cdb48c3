"""Labels for the streaming estimator: the slip velocity *now*, from smoothed poses.

A window model learns the mean slip of its window, the difference of two positions. A
streaming model is asked for the velocity at one instant, and differencing motion capture
over one 10 ms hop would give a label dominated by noise (0.15 mm per marker, ~0.2 mm
relative: tens of mm/s at 10 ms). The label is therefore the derivative of a non-causal
Savitzky-Golay fit to the object's pose in the grasp plane; the smoother sees the
future, the model does not.

``aslip export`` stores each trial's object-relative track (``tracks/<k>.npy``, rows
``(audio file sample position, rx, ry, rz, ax, ay, az)``: samples, metres and radians,
grasp plane; ``a`` is the relative rotation accumulated since the first row, whose
derivative is the angular velocity) through :func:`relative_track` and
:func:`write_track`; :func:`frame_labels` turns a track into per-frame labels at any
smoother setting, so the smoother can be changed without exporting again. The planar label
is the velocity of the object's material point at the pad centre, ``v_c = dr/dt - w x r``,
and ``wy`` is ``w``'s component about the pad normal, as the window labels
(``data.labels``). Tracks of datasets exported before the rotation columns (``(N, 4)``)
give the planar velocity as before and ``wy`` NaN ("no angular label"). The chosen
setting (:data:`DEFAULT_SMOOTHER`) was compared against the scene's true velocity with
``python -m benchmarks.label_smoother`` (docs/streaming.md).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

from aslip_ros.slip import ANGULAR_AXIS, VELOCITY_AXES

TRACK_DIR = "tracks"


@dataclass(frozen=True)
class Smoother:
    """Savitzky-Golay velocity: a ``window_s`` polynomial fit of ``polyorder``."""

    window_s: float = 0.15
    polyorder: int = 2
    max_gap_s: float = 0.05
    #: The fit spreads a slip onset over half a window both ways, so the labelled slip
    #: starts ~50 ms before the true one (and ends ~50 ms after): slip flags this close
    #: after a labelled start or before a labelled end are left out of the detection loss.
    guard_s: float = 0.05

    def to_dict(self) -> dict:
        return asdict(self)


DEFAULT_SMOOTHER = Smoother()


#: Columns of a track: the sample position, the position r (3) and, in tracks written by
#: this version, the accumulated rotation a (3).
TRACK_COLUMNS = 7
OLD_TRACK_COLUMNS = 4


def accumulated_rotation(q: Rotation) -> np.ndarray:
    """``(N, 3)`` rad: the sum of the rotation vectors of ``q[k] q[k-1]^-1`` from the first
    sample (0) on, so its time derivative is the angular velocity in the reference frame;
    it does not wrap at pi."""
    if len(q) < 2:
        return np.zeros((len(q), 3))
    steps = (q[1:] * q[:-1].inv()).as_rotvec().reshape(-1, 3)
    return np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


def relative_track(source: str, track, calib: np.ndarray, obj=None) -> np.ndarray:
    """Object pose relative to the grasp plane at the pose stamps, ``(N, 7)``: t, r, a.

    ``source`` "mocap": ``r = R_G^T (p_O - p_G)``, orientation ``R_G^T R_O``, at the finger
    stamps (object interpolated); "robot": the world-fixed probe, ``r = -R_G^T p_G`` and
    orientation ``R_G^T``. ``a`` is the orientation's :func:`accumulated_rotation`.
    ``track``/``obj`` are ``data.labels.PoseTrack``; ``calib`` the grasp-plane pose7.
    """
    t = np.asarray(track.t, dtype=np.float64)
    rc = Rotation.from_quat(np.asarray(calib[3:], dtype=np.float64))
    rot = Rotation.from_quat(track.quat)
    p_g = track.pos + rot.apply(calib[:3])
    r_g = rot * rc
    if source == "mocap":
        if obj is None or len(obj) < 2:
            return np.zeros((0, TRACK_COLUMNS))
        inside = (t >= obj.t[0]) & (t <= obj.t[-1])
        t, p_g, r_g = t[inside], p_g[inside], r_g[inside]
        if t.size == 0:
            return np.zeros((0, TRACK_COLUMNS))
        p_o, r_o = obj.interpolate(t)
        rel, q = r_g.inv().apply(p_o - p_g), r_g.inv() * r_o
    else:
        rel, q = -r_g.inv().apply(p_g), r_g.inv()
    return np.column_stack([t, rel.reshape(-1, 3), accumulated_rotation(q)])


def export_track(source: str, track, calib: np.ndarray, obj, intercept: float, slope: float,
                 first_index: float) -> np.ndarray:
    """:func:`relative_track` with its times moved onto the trial's audio file sample axis
    (the export's clock fit: ``t = intercept + (stream index - first_index) * slope``)."""
    rel = relative_track(source, track, calib, obj)
    rel[:, 0] = (rel[:, 0] - intercept) / slope - first_index
    return rel


def write_track(root: str | Path, k: int, track: np.ndarray) -> None:
    """Store trial ``k``'s track (sample positions, r) in a dataset being written."""
    d = Path(root) / TRACK_DIR
    d.mkdir(exist_ok=True)
    np.save(d / f"{int(k)}.npy", np.asarray(track, dtype=np.float64))


def load_track(dataset_root: str | Path, k: int) -> np.ndarray:
    """Trial ``k``'s track, ``(N, 7)`` (``(N, 4)`` from an export without the rotation
    columns); ValueError naming the re-export when it is absent."""
    p = Path(dataset_root) / TRACK_DIR / f"{int(k)}.npy"
    if not p.is_file():
        raise ValueError(f"{dataset_root} has no {TRACK_DIR}/{k}.npy: the streaming labels "
                         f"need a dataset exported by this version of aslip export")
    a = np.load(p)
    if a.ndim != 2 or a.shape[1] not in (TRACK_COLUMNS, OLD_TRACK_COLUMNS) \
            or not np.isfinite(a).all():
        raise ValueError(f"{p}: expected a finite (N, {TRACK_COLUMNS}) or "
                         f"(N, {OLD_TRACK_COLUMNS}) track, got {a.shape}")
    return a


def _savgol_at(t: np.ndarray, r: np.ndarray, tq: np.ndarray, smoother: Smoother,
               deriv: int) -> tuple[np.ndarray, np.ndarray]:
    """The Savitzky-Golay fit (``deriv`` 0: the values, 1: the velocity) of positions
    ``r (N, D)`` at ``t`` (s), evaluated at ``tq``, and its validity mask.

    The track is put on a uniform grid at its median rate (linear interpolation across
    dropped frames), filtered and interpolated to ``tq``. Valid: ``tq`` inside the track and
    no gap longer than ``max_gap_s`` within half a smoother window of it.
    """
    t = np.asarray(t, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64).reshape(t.size, -1)
    tq = np.asarray(tq, dtype=np.float64)
    out = np.zeros((tq.size, r.shape[1]))
    if t.size < smoother.polyorder + 2:
        return out, np.zeros(tq.size, bool)
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
    n_win = max(smoother.polyorder + 2, int(round(smoother.window_s / dt)) | 1)
    n_win += 1 - n_win % 2
    if grid.size < n_win:
        return out, np.zeros(tq.size, bool)
    rg = np.column_stack([np.interp(grid, t, r[:, j]) for j in range(r.shape[1])])
    fg = savgol_filter(rg, n_win, smoother.polyorder, deriv=deriv, delta=dt, axis=0,
                       mode="interp")
    out = np.column_stack([np.interp(tq, grid, fg[:, j]) for j in range(r.shape[1])])
    half = 0.5 * n_win * dt
    valid = (tq >= t[0]) & (tq <= t[-1])
    gaps = np.flatnonzero(np.diff(t) > smoother.max_gap_s + 1e-9)
    for g in gaps:
        valid &= ~((tq > t[g] - half) & (tq < t[g + 1] + half))
    return out, valid


def smooth_velocity(t: np.ndarray, r: np.ndarray, tq: np.ndarray,
                    smoother: Smoother = DEFAULT_SMOOTHER) -> tuple[np.ndarray, np.ndarray]:
    """Velocity ``(M, D)`` of positions ``r (N, D)`` at ``t`` (s), evaluated at ``tq``, and
    its validity mask (:func:`_savgol_at`)."""
    return _savgol_at(t, r, tq, smoother, 1)


def smooth_positions(t: np.ndarray, r: np.ndarray, tq: np.ndarray,
                     smoother: Smoother = DEFAULT_SMOOTHER) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``r (N, D)`` at ``t`` (s) smoothed by the same fit and evaluated at ``tq``,
    with the validity mask (the window labels' ends, ``data.labels``)."""
    return _savgol_at(t, r, tq, smoother, 0)


def track_velocity(track: np.ndarray, tq: np.ndarray,
                   smoother: Smoother = DEFAULT_SMOOTHER
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed motion of a track (times in seconds in column 0) at times ``tq`` [s]:
    ``v`` (M, 3) the pad-centre velocity ``dr/dt - w x r`` [m/s], ``w`` (M, 3) the angular
    velocity [rad/s] (NaN for a track without rotation columns, whose ``v`` is then
    ``dr/dt``), and the validity mask of :func:`smooth_velocity`."""
    track = np.asarray(track, dtype=np.float64)
    tq = np.asarray(tq, dtype=np.float64)
    t = track[:, 0]
    has_rot = track.shape[1] >= TRACK_COLUMNS
    cols = track[:, 1:TRACK_COLUMNS] if has_rot else track[:, 1:OLD_TRACK_COLUMNS]
    d, valid = smooth_velocity(t, cols, tq, smoother)
    if not has_rot:
        return d, np.full((tq.size, 3), np.nan), valid
    v, w = d[:, :3], d[:, 3:]
    if t.size:
        r = np.column_stack([np.interp(tq, t, track[:, 1 + j]) for j in range(3)])
        v = v - np.cross(w, r)
    return v, w, valid


def frame_labels(track: np.ndarray, frame_end: np.ndarray, sample_rate: float,
                 epsilon: float, smoother: Smoother = DEFAULT_SMOOTHER) -> dict:
    """Per-frame labels at audio file positions ``frame_end`` (samples): ``v`` (M, 2) in m/s
    (grasp-plane x, z, the pad centre's velocity), ``wy`` (M,) in rad/s (NaN for a track
    without rotation columns), ``slip`` (planar speed > epsilon), ``valid``."""
    track = np.asarray(track, dtype=np.float64)
    tq = np.asarray(frame_end) / sample_rate
    timed = np.column_stack([track[:, 0] / sample_rate, track[:, 1:]])
    v, w, valid = track_velocity(timed, tq, smoother)
    v2 = v[:, list(VELOCITY_AXES)].astype(np.float32)
    slip = np.hypot(v2[:, 0], v2[:, 1]) > epsilon
    return {"v": v2, "wy": w[:, ANGULAR_AXIS].astype(np.float32), "slip": slip,
            "valid": valid, "ambiguous": guard_band(slip, tq, smoother.guard_s)}


def guard_band(slip: np.ndarray, t: np.ndarray, guard_s: float) -> np.ndarray:
    """Frames within ``guard_s`` after a rising or before a falling edge of ``slip``."""
    out = np.zeros(slip.size, bool)
    if guard_s <= 0 or slip.size < 2:
        return out
    for k in np.flatnonzero(slip[1:] & ~slip[:-1]) + 1:
        out[k:][t[k:] < t[k] + guard_s - 1e-9] = True
    for k in np.flatnonzero(~slip[1:] & slip[:-1]) + 1:
        out[:k][t[:k] > t[k] - guard_s - 1e-9] = True
    return out
