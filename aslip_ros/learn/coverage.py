"""Which slip directions a recording holds, and how well a model does in each.

A direction estimate is learned from the directions the training trials slip in; where they
hardly ever slip, the model extrapolates. Measured (docs/results.md, "A one-sided recording
chosen on folds"): on `make transfer`'s `one_sided` scene a draw of training trials none of
whose preferred directions pointed backwards tested at 29 deg on the test trials slipping
the ways it had heard and 66 deg on the five slipping backwards, and no choice of model or
average of models closed that gap; only recordings that slip that way would. So
``aslip train`` reports the training slip per direction sector and names the sparse ones,
and ``aslip evaluate`` scores each sector apart (``per_direction``).

Directions are grasp-plane angles of the slip velocity ``(vx, vz)`` (slip.py), ``atan2(vz,
vx)`` in degrees; sector ``k`` of ``SECTORS`` is centred on ``k * 360 / SECTORS``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Direction sectors around the grasp plane (45 degrees each).
SECTORS = 8
#: A sector holding less than this fraction of an even share (1 / SECTORS) of the slip is
#: sparse: with 8 sectors, under 1/16 of the slip time. The demo's 100 trials of pushes in
#: every direction hold 10.7-13.7 % per sector; the one-sided draw above 2.2-4.5 % in the
#: three backward sectors.
SPARSE_SHARE = 0.5
#: The group name of windows without slip in ``direction_groups``.
NO_SLIP = "no slip"


def sector_of(velocity: np.ndarray, sectors: int = SECTORS) -> np.ndarray:
    """Each velocity's sector index, 0..sectors-1 (-1 where the velocity is zero)."""
    v = np.asarray(velocity, dtype=np.float64).reshape(-1, 2)
    width = 360.0 / sectors
    ang = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    k = np.floor(((ang + width / 2.0) % 360.0) / width).astype(int) % sectors
    return np.where(np.linalg.norm(v, axis=1) > 0.0, k, -1)


def sector_name(k: int, sectors: int = SECTORS) -> str:
    """A sector's name: its centre angle, e.g. ``+90 deg``."""
    centre = k * 360.0 / sectors
    centre = centre - 360.0 if centre > 180.0 else centre
    return f"{centre:+.0f} deg"


def direction_groups(velocity: np.ndarray, slip: np.ndarray,
                     sectors: int = SECTORS) -> np.ndarray:
    """Per window, its sector's name, or ``NO_SLIP`` for a window without slip (the groups
    of ``metrics.grouped_metrics``)."""
    k = sector_of(velocity, sectors)
    names = np.array([sector_name(i, sectors) for i in range(sectors)] + [NO_SLIP],
                     dtype=object)
    return names[np.where(np.asarray(slip, dtype=bool) & (k >= 0), k, sectors)]


def direction_coverage(velocity: np.ndarray, slip: np.ndarray, hop_s: float,
                       sectors: int = SECTORS) -> dict[str, Any]:
    """Seconds and share of slip per direction sector over windows ``hop_s`` apart, and the
    sparse sectors (under ``SPARSE_SHARE`` of an even share)."""
    k = sector_of(velocity, sectors)
    k = k[np.asarray(slip, dtype=bool).reshape(-1) & (k >= 0)]
    counts = np.bincount(k, minlength=sectors)
    total = int(counts.sum())
    share = counts / total if total else np.zeros(sectors)
    rows = [{"sector": sector_name(i, sectors), "slip_s": round(float(counts[i] * hop_s), 2),
             "share": round(float(share[i]), 4)} for i in range(sectors)]
    limit = SPARSE_SHARE / sectors
    return {"sectors": rows, "slip_s": round(float(total * hop_s), 2),
            "sparse_below_share": limit,
            "sparse": [r["sector"] for r, s in zip(rows, share) if total and s < limit]}


def of_windows(ds: Any, idx: np.ndarray) -> dict[str, Any]:
    """``direction_coverage`` of a dataset's (``learn.data_io.WindowSet``) windows ``idx``."""
    return direction_coverage(ds.velocity(idx), ds.slip(idx), ds.hop_s)


def warns(cov: dict[str, Any]) -> bool:
    """Whether ``cov`` is worth a warning: a sparse sector, or no slip at all."""
    return bool(cov["sparse"]) or not cov["slip_s"]


def warning(cov: dict[str, Any]) -> str | None:
    """The warning ``aslip train`` prints for ``cov``, or None when it does not warn."""
    return "warning: " + coverage_text(cov) if warns(cov) else None


def coverage_text(cov: dict[str, Any]) -> str:
    """One sentence on ``direction_coverage``: the sparse sectors, or that none is."""
    if not cov.get("slip_s"):
        return "Slip directions: the training windows hold no slip."
    if not cov["sparse"]:
        return (f"Slip directions: every {360 // len(cov['sectors'])}-degree sector holds at "
                f"least {cov['sparse_below_share']:.1%} of the {cov['slip_s']:.0f} s of "
                "training slip.")
    held = ", ".join(f"{r['sector']} {r['share']:.1%}" for r in cov["sectors"]
                     if r["sector"] in cov["sparse"])
    return (f"Slip directions: the training trials hardly slip towards {held} of "
            f"{cov['slip_s']:.0f} s of slip (a sector is sparse under "
            f"{cov['sparse_below_share']:.1%}); direction estimates there are "
            "extrapolations, and no validation on these trials can measure them: record "
            "slips in those directions (docs/hardware-quickstart.md, step 3).")
