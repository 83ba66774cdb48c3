"""Parameter specs and validators that describe themselves (ROS message types only).

A :class:`Param` carries a validator; a :class:`Rule` is a validator that also says what it
accepts, so :func:`descriptor` derives the ParameterDescriptor (``floating_point_range``,
``integer_range``, ``additional_constraints``) from the same object that checks the value:
``ros2 param describe`` and rqt show the rule the node enforces. The node modules use these
through :mod:`aslip_ros.nodes.common` (``c.in_range(...)``).

A parameter that sets a field of a core config dataclass (``SlipTrackConfig``,
``ArmLimits``, ...) takes its default from that field (:func:`from_config`), and the node
builds the config from its parameter values by field name (:func:`config_kwargs`): each
default is written once, in the core (test/test_defaults_once.py).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Callable, Optional

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor


Validator = Callable[[Any], Optional[str]]


@dataclass(frozen=True)
class Param:
    """A parameter spec: name, default (its type is the parameter's type), validator."""

    name: str
    default: Any
    description: str
    check: Optional[Validator] = None
    read_only: bool = False


@dataclass(frozen=True)
class Rule:
    """A validator that also says what it accepts, so the ParameterDescriptor can show it.

    ``check(value)`` returns an error text or None. ``text`` becomes the descriptor's
    ``additional_constraints``; ``bounds`` (a closed ``(lo, hi)``) its
    ``floating_point_range`` or ``integer_range``, by the parameter's type. Bounds may be
    wider than the rule (e.g. "-1 or [0, 1]" declares [-1, 1]); ``check`` has the last word.
    """

    check: Validator
    text: str
    bounds: Optional[tuple] = None

    def __call__(self, v) -> Optional[str]:
        return self.check(v)


def config_default(config: type, field: str) -> Any:
    """The default of dataclass ``config``'s ``field`` as a parameter value (a tuple or an
    array becomes a list: ROS parameters have no tuples). ValueError without one."""
    for f in dataclasses.fields(config):
        if f.name != field:
            continue
        if f.default is not dataclasses.MISSING:
            value = f.default
        elif f.default_factory is not dataclasses.MISSING:
            value = f.default_factory()
        else:
            raise ValueError(f"{config.__name__}.{field} has no default")
        if isinstance(value, Sequence) and not isinstance(value, str) or \
                hasattr(value, "tolist"):
            return [x.item() if hasattr(x, "item") else x for x in value]
        return value
    raise ValueError(f"{config.__name__} has no field {field!r}")


def from_config(config: type, field: str, description: str,
                check: Optional[Validator] = None, read_only: bool = False,
                prefix: str = "") -> Param:
    """The :class:`Param` ``prefix + field`` whose default is the core config's
    (:func:`config_default`)."""
    return Param(prefix + field, config_default(config, field), description, check, read_only)


def config_kwargs(config: type, values: Mapping[str, Any], prefix: str = "") -> dict:
    """The keyword arguments of dataclass ``config`` that parameter ``values`` hold, each
    under the name ``prefix + field`` (lists and arrays become tuples)."""
    out = {}
    for f in dataclasses.fields(config):
        if prefix + f.name in values:
            value = values[prefix + f.name]
            if isinstance(value, Sequence) and not isinstance(value, str):
                value = tuple(value)
            out[f.name] = value
    return out


positive = Rule(lambda v: None if _finite(v) and v > 0 else f"must be finite and > 0, got {v!r}",
                "finite and > 0")
non_negative = Rule(
    lambda v: None if _finite(v) and v >= 0 else f"must be finite and >= 0, got {v!r}",
    "finite and >= 0")


def in_range(lo: float, hi: float) -> Rule:
    """Finite and within [lo, hi]."""
    def check(v):
        return None if _finite(v) and lo <= v <= hi else f"must lie in [{lo}, {hi}], got {v!r}"
    return Rule(check, f"in [{lo}, {hi}]", (lo, hi))


def int_range(lo: int, hi: int) -> Rule:
    """An integer within [lo, hi]."""
    def check(v):
        return None if _finite(v) and lo <= v <= hi else f"must be in [{lo}, {hi}]"
    return Rule(check, f"in [{lo}, {hi}]", (lo, hi))


def at_least(lo: float) -> Rule:
    """Finite and >= lo (no upper bound, so no declared range)."""
    def check(v):
        return None if _finite(v) and v >= lo else f"must be >= {lo:g}"
    return Rule(check, f">= {lo:g}")


def off_or(off: float, rule: Rule, meaning: str) -> Rule:
    """``off`` (which means ``meaning``) or a value ``rule`` accepts; the declared range
    spans both."""
    lo, hi = rule.bounds
    shown = f"{off:g} ({meaning}) or {rule.text}"

    def check(v):
        return None if v == off or rule(v) is None else f"must be {shown}, got {v!r}"
    return Rule(check, shown, (min(off, lo), max(off, hi)))


def one_of(*choices) -> Rule:
    """One of the given values."""
    def check(v):
        return None if v in choices else f"must be one of {list(choices)}, got {v!r}"
    return Rule(check, "one of: " + ", ".join(str(x) for x in choices))


non_empty = Rule(lambda v: None if isinstance(v, str) and v.strip()
                 else "must be a non-empty string", "a non-empty string")


def _pose7(v) -> Optional[str]:
    try:
        vals = [float(x) for x in v]
    except (TypeError, ValueError):
        return f"must be 7 numbers, got {v!r}"
    if len(vals) != 7 or not all(math.isfinite(x) for x in vals):
        return f"must be 7 finite numbers (x y z qx qy qz qw), got {vals}"
    # Here, not at the top: poses brings scipy.spatial (half a second of every node's start),
    # which the nodes that read no pose never need.
    from aslip_ros import poses
    if not poses.quat_ok(vals):
        return "has a zero quaternion"
    return None


#: Seven finite numbers with a non-zero quaternion.
pose7 = Rule(_pose7, "7 finite numbers x y z qx qy qz qw [m], quaternion not zero")


def vector3(allow_empty: bool = False) -> Rule:
    """Three finite numbers, not all zero (or empty when allowed)."""
    def check(v):
        vals = [float(x) for x in v]
        if allow_empty and not vals:
            return None
        if len(vals) != 3 or not all(math.isfinite(x) for x in vals):
            return f"must be 3 finite numbers{' or empty' if allow_empty else ''}, got {vals}"
        if math.sqrt(sum(x * x for x in vals)) < 1e-9:
            return "must not be the zero vector"
        return None
    return Rule(check, "3 finite numbers, not all zero" + (", or empty" if allow_empty else ""))


def descriptor(spec: Param, with_range: bool = True) -> ParameterDescriptor:
    """The ParameterDescriptor of ``spec``: description, read-only, and what its
    :class:`Rule` accepts (``ros2 param describe`` and rqt show it).

    Integer ranges have step 1, floating-point ranges step 0 (any value in the range).
    """
    d = ParameterDescriptor(description=spec.description, read_only=spec.read_only)
    rule = spec.check
    if not isinstance(rule, Rule):
        return d
    d.additional_constraints = rule.text
    if rule.bounds is None or not with_range or isinstance(spec.default, bool):
        return d
    lo, hi = rule.bounds
    if isinstance(spec.default, int):
        d.integer_range = [IntegerRange(from_value=math.ceil(lo), to_value=math.floor(hi),
                                        step=1)]
    elif isinstance(spec.default, float):
        d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi),
                                                     step=0.0)]
    return d


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
