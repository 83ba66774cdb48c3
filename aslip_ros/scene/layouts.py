"""Gripper geometry: pads, microphone layouts and the named objects.

Coordinates are in the ``aslip_grasp_plane`` frame (docs/design.md): origin midway between
the pads, +x along the fingers towards the fingertips, +z up, +y from the left finger to the
right one. A microphone sits behind its pad, so its in-plane position is ``(x, z)`` and its
``y`` is half the grasp width (negative on the left finger). SI units throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Offset of a corner microphone from the pad centre along x and along z [m]. Gives a
#: diagonal spacing of about 25 mm within a pad (scene-physics.md: "about 25 mm").
CORNER_OFFSET_M = 9.0e-3
#: Offset of a same-finger microphone from the pad centre along x [m] (25 mm spacing).
AXIAL_OFFSET_M = 12.5e-3


@dataclass(frozen=True)
class Mic:
    """One microphone: channel name, finger (``"left"``/``"right"``), in-plane position [m]."""

    name: str
    finger: str
    x: float
    z: float


@dataclass(frozen=True)
class Layout:
    """A named set of microphones; channel order is the order of ``mics``."""

    name: str
    mics: tuple[Mic, ...]

    @property
    def channel_names(self) -> list[str]:
        """Channel names in stream order."""
        return [m.name for m in self.mics]

    @property
    def n_channels(self) -> int:
        """Number of audio channels."""
        return len(self.mics)

    def positions_xz(self) -> np.ndarray:
        """In-plane microphone positions, shape ``(n_channels, 2)`` [m]."""
        return np.array([[m.x, m.z] for m in self.mics], dtype=float)

    def finger_index(self) -> np.ndarray:
        """0 for a microphone on the left finger, 1 for the right one."""
        return np.array([0 if m.finger == "left" else 1 for m in self.mics], dtype=int)

    def positions(self, grasp_width_m: float) -> np.ndarray:
        """3-D microphone positions in the grasp-plane frame, shape ``(n_channels, 3)`` [m]."""
        if not grasp_width_m > 0.0:
            raise ValueError(f"grasp_width_m must be positive, got {grasp_width_m!r}")
        half = 0.5 * grasp_width_m
        return np.array([[m.x, -half if m.finger == "left" else half, m.z] for m in self.mics])


_C = CORNER_OFFSET_M
_A = AXIAL_OFFSET_M
LAYOUTS: dict[str, Layout] = {
    # Single-microphone baseline of the paper's Table I.
    "1mic": Layout("1mic", (Mic("left_center", "left", 0.0, 0.0),)),
    # One microphone per finger at the pad centre: no in-plane baseline at all.
    "2mic_centered": Layout("2mic_centered", (
        Mic("left_center", "left", 0.0, 0.0),
        Mic("right_center", "right", 0.0, 0.0))),
    # Opposite corners across the fingers: one diagonal baseline touching both axes.
    "2mic_corners": Layout("2mic_corners", (
        Mic("left_front_top", "left", _C, _C),
        Mic("right_rear_bottom", "right", -_C, -_C))),
    # Both on the left finger along the finger axis: a baseline along x only.
    "2mic_same_finger": Layout("2mic_same_finger", (
        Mic("left_front", "left", _A, 0.0),
        Mic("left_rear", "left", -_A, 0.0))),
    # Two per finger on crossing diagonals: both axes observable on both fingers.
    "4mic": Layout("4mic", (
        Mic("left_front_top", "left", _C, _C),
        Mic("left_rear_bottom", "left", -_C, -_C),
        Mic("right_front_bottom", "right", _C, -_C),
        Mic("right_rear_top", "right", -_C, _C))),
}

#: The layout of the paper, the scene's default and that of the shipped models.
DEFAULT_LAYOUT = "4mic"
#: The layouts of the paper's Table I, in its order (every layout above).
PAPER_LAYOUTS = ("4mic", "2mic_centered", "2mic_corners", "2mic_same_finger", "1mic")


@dataclass(frozen=True)
class ObjectSpec:
    """A grasped object.

    ``roughness`` scales the broadband friction noise relative to PLA (1.0); ``brightness``
    shifts that noise to higher frequencies; ``friction`` is the pad-object Coulomb
    coefficient used by the closed-loop wall push; ``length_m`` is the extent along the
    default push direction (+x) beyond the grasp centre, used to place the wall contact.
    """

    name: str
    width_m: float
    mass_kg: float
    roughness: float
    brightness: float
    friction: float
    length_m: float


# Sizes and masses approximate the YCB items (Calli et al. 2015); the PLA rod is a printed
# 20 mm rod. Roughness and friction are assumptions ordered by surface: cardboard > printed
# PLA layers > paper label > smooth moulded plastic.
OBJECTS: dict[str, ObjectSpec] = {
    "pla_rod": ObjectSpec("pla_rod", 0.020, 0.05, 1.0, 0.6, 0.50, 0.10),
    "glass_cleaner": ObjectSpec("glass_cleaner", 0.065, 0.55, 0.5, 0.4, 0.40, 0.12),
    "chips_can": ObjectSpec("chips_can", 0.075, 0.20, 0.7, 0.5, 0.60, 0.12),
    "mustard_container": ObjectSpec("mustard_container", 0.058, 0.60, 0.45, 0.35, 0.45, 0.10),
    "cracker_box": ObjectSpec("cracker_box", 0.060, 0.41, 1.6, 0.7, 0.55, 0.11),
}


@dataclass(frozen=True)
class PadSpec:
    """A pad surface. ``textured`` pads carry two ridge families (normals x and z)."""

    name: str
    textured: bool


PADS: dict[str, PadSpec] = {
    "textured": PadSpec("textured", True),
    "smooth": PadSpec("smooth", False),
}


def _lookup(table: dict, kind: str, name: str):
    if not isinstance(name, str) or name not in table:
        raise ValueError(f"unknown {kind} {name!r}; choose one of {sorted(table)}")
    return table[name]


def get_layout(name: str) -> Layout:
    """The microphone layout called ``name``; ValueError lists the known ones."""
    return _lookup(LAYOUTS, "layout", name)


def get_object(name: str) -> ObjectSpec:
    """The object called ``name``; ValueError lists the known ones."""
    return _lookup(OBJECTS, "object", name)


def get_pad(name: str) -> PadSpec:
    """The pad called ``name``; ValueError lists the known ones."""
    return _lookup(PADS, "pad", name)


def yaw_rotation(yaw_rad: float) -> np.ndarray:
    """Rotation matrix of the grasp plane in ``world`` for a level gripper turned by ``yaw``.

    Columns are the grasp-plane axes x, y, z expressed in ``world``.
    """
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_quaternion(yaw_rad: float) -> np.ndarray:
    """Quaternion ``(qx, qy, qz, qw)`` of :func:`yaw_rotation`."""
    return np.array([0.0, 0.0, np.sin(0.5 * yaw_rad), np.cos(0.5 * yaw_rad)])
