"""Held-out scene variants: what a lab's recordings may differ in (docs/scene.md, "Variants").

Each variant maps a :class:`~aslip_ros.scene.scenario.Scenario` to a copy drawn from a wider
but physically sourced range than the default scene's; no model is trained or tuned on them
(``make transfer``). None adds a mechanism: each moves parameters the scene already has.

- ``coupling``: per-grasp microphone coupling of +-6 dB (the default scene has +-3 dB) and a
  hand-noise path of +-2 dB per microphone (default +-1 dB).
- ``one_sided``: 80 % of an agent's pushes within +-30 deg of one direction per grasp (the
  scene's own coupling included).
- ``contact``: the object seated off the pad centre: the contact centroid wanders 5 mm (std)
  around the centre, slowly enough (5 s) to stay put for most of a grasp.
- ``confounders``: more sound without slip: half the agent's touches do not slip, the hand's
  noise and clicks twice as loud and as frequent, the arm 6 dB louder.
- ``mocap``: a lab's motion capture (100 Hz, 0.3 mm, 2 % dropped frames, 15 ms latency).
- ``rate``: audio recorded at 44.1 kHz instead of 48 kHz.
- ``speed``: the slip noise's loudness against slip speed with another exponent per object
  (``Acoustics.speed_exponent``, 0.75 for every object in the default scene), drawn once per
  object in 0.45 to 1.05.
- ``path``: the background reaches the microphones by other paths: the hand's noise and the
  arm's noise each through their own +-6 dB per microphone and grasp (the default scene has
  +-1 dB each), so the background is no longer common mode and its mix moves each channel's
  level (what the per-grasp calibration's self-check is for, docs/model.md).
"""

from __future__ import annotations

import zlib
from dataclasses import replace
from typing import Callable

import numpy as np

from .scenario import Scenario

#: Per-grasp coupling range of the coupling variant [+-dB per microphone]: twice the default
#: scene's (``physics.Acoustics.gain_mismatch_db``); sources in docs/scene.md.
COUPLING_DB = 6.0
#: Per-grasp path difference of handling noise to each microphone in that variant [+-dB].
HANDLING_PATH_DB = 2.0
#: The contact variant: centroid offset (std) [m] and how slowly it moves [s].
CONTACT_OFFSET_M = 5.0e-3
CONTACT_TAU_S = 5.0
#: The confounders variant: share of touches without slip, and level factors of the hand's
#: noise, its click rate and the arm's noise against the default scene.
NO_SLIP_TOUCH_FRACTION = 0.5
CONFOUNDER_GAIN = 2.0
#: A lab's motion capture in the mocap variant: rate [Hz], per-axis marker noise [m], share
#: of dropped frames, latency [s].
LAB_MOCAP = {"mocap_rate_hz": 100.0, "mocap_noise_m": 3e-4, "mocap_drop_prob": 0.02,
             "mocap_latency_s": 0.015}


def coupling_variant(scn: "Scenario", gain_db: float = COUPLING_DB,
                     path_db: float = HANDLING_PATH_DB) -> "Scenario":
    """``scn`` with per-grasp microphone coupling: each channel's gain uniform in +-gain_db,
    and the hand's noise reaching each channel with its own +-path_db (not common mode)."""
    return scn.with_(acoustics=replace(scn.acoustics, gain_mismatch_db=float(gain_db),
                                       handling_path_db=float(path_db)))


def one_sided_variant(scn: "Scenario", fraction: float = 0.8,
                      spread_rad: float = np.pi / 6.0) -> "Scenario":
    """``scn`` where ``fraction`` of the pushes go within +-spread_rad of one direction."""
    return scn.with_(one_sided_fraction=float(fraction), one_sided_spread_rad=float(spread_rad))


def contact_variant(scn: "Scenario", offset_m: float = CONTACT_OFFSET_M,
                    tau_s: float = CONTACT_TAU_S) -> "Scenario":
    """``scn`` with the object seated off the pad centre: each pad's contact centroid
    wanders ``offset_m`` (std) around it with time constant ``tau_s``."""
    return scn.with_(acoustics=replace(scn.acoustics, contact_wander_m=float(offset_m),
                                       contact_wander_tau_s=float(tau_s)))


def confounders_variant(scn: "Scenario", no_slip_fraction: float = NO_SLIP_TOUCH_FRACTION,
                        gain: float = CONFOUNDER_GAIN) -> "Scenario":
    """``scn`` with more sound that is not slip: ``no_slip_fraction`` of the agent's touches
    do not slip; handling noise, handling clicks and robot noise ``gain`` times the scene's."""
    ac = scn.acoustics
    return scn.with_(no_slip_touch_fraction=float(no_slip_fraction),
                     acoustics=replace(ac, handling_level=ac.handling_level * gain,
                                       click_rate_touch=ac.click_rate_touch * gain,
                                       robot_level=ac.robot_level * gain))


#: The rate variant's audio rate [Hz] (the scene records at 48 kHz).
LAB_RATE_HZ = 44100.0


def rate_variant(scn: "Scenario", rate_hz: float = LAB_RATE_HZ) -> "Scenario":
    """``scn`` recorded by a sound card at ``rate_hz``."""
    return scn.with_(sample_rate=float(rate_hz))


def mocap_variant(scn: "Scenario") -> "Scenario":
    """``scn`` seen by a lab's motion capture: slower, noisier, with more dropped frames and
    latency than the scene's default (``LAB_MOCAP``)."""
    return scn.with_(**LAB_MOCAP)


#: The speed variant: range of each object's amplitude speed exponent (slip noise RMS grows
#: as ``speed ** exponent``). The default scene's 0.75 for every object is the exponent
#: reported for roughness noise (Ben Abdelounis et al. 2010; shared/docs/scene-physics.md,
#: item 2); no source gives its spread over surface pairs, so +-0.3 around it is an
#: assumption (sources in docs/scene.md).
SPEED_EXPONENT_RANGE = (0.45, 1.05)


def object_speed_exponent(obj: str, low: float = SPEED_EXPONENT_RANGE[0],
                          high: float = SPEED_EXPONENT_RANGE[1], seed: int = 0) -> float:
    """The speed variant's exponent of object ``obj``: uniform in [low, high], drawn from the
    object's name (and ``seed``), so one object keeps it in every grasp and every scenario."""
    if not 0.0 <= low <= high or not np.isfinite(high):
        raise ValueError(f"speed exponent range must satisfy 0 <= low <= high, got "
                         f"({low}, {high})")
    rng = np.random.default_rng([int(seed), 0x5BEED, zlib.crc32(str(obj).encode())])
    return float(rng.uniform(low, high))


def speed_variant(scn: "Scenario", low: float = SPEED_EXPONENT_RANGE[0],
                  high: float = SPEED_EXPONENT_RANGE[1], seed: int = 0) -> "Scenario":
    """``scn`` whose object's slip noise grows with speed by its own exponent
    (:func:`object_speed_exponent`) instead of the scene's 0.75; the level at
    ``Acoustics.speed_ref_m_s`` is kept."""
    ex = object_speed_exponent(scn.object, low, high, seed)
    return scn.with_(acoustics=replace(scn.acoustics, speed_exponent=ex))


#: The path variant: per-grasp path difference of the hand's and of the arm's noise to each
#: microphone [+-dB], against +-1 dB each in the default scene. A source's level falls as
#: ``1 / (1 + r / falloff_m)`` with its distance (``physics.Acoustics.falloff_m``, 10 mm):
#: a hand 3 cm from one pad and 10 cm from the other is 9 dB louder at the first, so +-6 dB
#: is within the scene's own law (sources in docs/scene.md).
PATH_DB = 6.0


def path_variant(scn: "Scenario", handling_db: float = PATH_DB,
                 robot_db: float = PATH_DB) -> "Scenario":
    """``scn`` whose background is not common mode: the hand's noise reaches each channel
    with its own +-handling_db and the arm's with its own +-robot_db, per grasp."""
    return scn.with_(acoustics=replace(scn.acoustics, handling_path_db=float(handling_db),
                                       robot_path_db=float(robot_db)))


#: The scene variants by name (``aslip simulate --variant``): each maps a scenario to its
#: variant. Every variant keeps the default scene's per-grasp coupling unless it widens it.
VARIANTS: dict[str, Callable[["Scenario"], "Scenario"]] = {
    "coupling": coupling_variant,
    "one_sided": one_sided_variant,
    "contact": contact_variant,
    "confounders": confounders_variant,
    "mocap": mocap_variant,
    "rate": rate_variant,
    "speed": speed_variant,
    "path": path_variant,
}
