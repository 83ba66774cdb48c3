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
"""

from __future__ import annotations

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


#: The scene variants by name (``aslip simulate --variant``): each maps a scenario to its
#: variant. Every variant keeps the default scene's per-grasp coupling unless it widens it.
VARIANTS: dict[str, Callable[["Scenario"], "Scenario"]] = {
    "coupling": coupling_variant,
    "one_sided": one_sided_variant,
    "contact": contact_variant,
    "confounders": confounders_variant,
    "mocap": mocap_variant,
    "rate": rate_variant,
}
