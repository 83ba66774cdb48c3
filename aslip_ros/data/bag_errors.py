"""The errors of bag reading and writing (shared by :mod:`.bags` and its decoders)."""

from __future__ import annotations


class BagError(ValueError):
    """A bag that cannot be read or written as the contract requires."""


class BagDamaged(BagError):
    """A bag whose file is truncated or corrupt (as opposed to well-formed but unsuitable)."""
