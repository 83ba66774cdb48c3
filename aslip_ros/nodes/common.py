"""What every aslip node shares: validated parameters, diagnostics, the topic names.

Parameters are declared from a list of :class:`Param` specs. Each spec carries its own
validator, applied once at start (an invalid value stops the node with a clear message and
exit code 2) and again whenever the parameter is set at run time (the set is refused with
``SetParametersResult(successful=False, reason=...)``).

Diagnostics: ``diagnostic_updater`` is not available everywhere, so nodes publish
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics`` directly when ``diagnostic_msgs``
is importable, and always mirror the same status as JSON (``std_msgs/String``) on
``/aslip/diagnostics`` so tools and tests without ``diagnostic_msgs`` can read it.

How a node runs as a process (``run_node``, ``ready``) is :mod:`aslip_ros.runtime.process`;
the QoS profiles are :mod:`aslip_ros.runtime.qos`.
"""

from __future__ import annotations

import json
import math
import time
from typing import Callable, Optional, Sequence

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidParameterValueException
from std_msgs.msg import String

from aslip_ros import topics
# Parameter specs and validators live in params.py; the nodes use them as c.<name>.
from aslip_ros.nodes.params import (Param, Rule, Validator, at_least,  # noqa: F401
                                    config_default, config_kwargs, descriptor, from_config,
                                    in_range, int_range, non_empty, non_negative, off_or,
                                    one_of, pose7, positive, vector3)
from aslip_ros.runtime.process import ConfigError
from aslip_ros.runtime.qos import RELIABLE_QOS

# --------------------------------------------------------------------------------- topics
# The names are defined in aslip_ros/topics.py; the nodes use them as c.<NAME>_TOPIC.
AUDIO_TOPIC = topics.AUDIO
FINGER_TOPIC = topics.FINGER
OBJECT_TOPIC = topics.OBJECT
RIGID_BODIES_TOPIC = topics.RIGID_BODIES
TCP_TOPIC = topics.TCP
METADATA_TOPIC = topics.METADATA
SLIP_TOPIC = topics.SLIP
SLIP_TRUTH_TOPIC = topics.SLIP_TRUTH
MARKER_TOPIC = topics.MARKER
CMD_VEL_TOPIC = topics.CMD_VEL
DIAG_TOPIC = topics.DIAGNOSTICS
DIAG_JSON_TOPIC = topics.DIAGNOSTICS_JSON


# --------------------------------------------------------------------------------- params

def declare_params(node, specs: Sequence[Param],
                   on_change: Optional[Callable[[dict], None]] = None,
                   cross_check: Optional[Callable[[dict], Optional[str]]] = None) -> dict:
    """Declare ``specs`` on ``node``, validate the start values, install the on-set check.

    Returns ``{name: value}``. ``on_change`` is called with the accepted changes after a
    successful run-time set. ``cross_check(all_values)`` validates combinations (e.g. by
    building the core's config object) and returns an error text or None. Raises
    :class:`aslip_ros.runtime.process.ConfigError` listing every invalid value (the node
    then exits with ``EXIT_CONFIG``).
    """
    by_name = {s.name: s for s in specs}
    for s in specs:
        try:
            node.declare_parameter(s.name, s.default, descriptor(s))
        except InvalidParameterValueException:
            # A start value outside the declared range: declared without the range, so the
            # check below refuses it in the same words as every other invalid value.
            node.declare_parameter(s.name, s.default, descriptor(s, with_range=False))
    values = {s.name: node.get_parameter(s.name).value for s in specs}
    checked = ((n, check_value(by_name[n], v)) for n, v in values.items())
    problems = [f"{n}: {err}" for n, err in checked if err]
    if not problems and cross_check is not None:
        err = cross_check(dict(values))
        if err:
            problems.append(err)
    if problems:
        raise ConfigError("invalid parameters: " + "; ".join(problems))

    def on_set(params) -> SetParametersResult:
        errors = []
        for p in params:
            spec = by_name.get(p.name)
            if spec is None:
                continue
            err = check_value(spec, p.value)
            if err:
                errors.append(f"{p.name}: {err}")
        if not errors and cross_check is not None:
            merged = {s.name: node.get_parameter(s.name).value for s in specs}
            merged.update({p.name: p.value for p in params if p.name in by_name})
            err = cross_check(merged)
            if err:
                errors.append(err)
        if errors:
            return SetParametersResult(successful=False, reason="; ".join(errors))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    if on_change is not None:
        # Post-set callbacks run only after every on-set check accepted the change.
        node.add_post_set_parameters_callback(
            lambda params: on_change({p.name: p.value for p in params if p.name in by_name}))
    return values


def check_value(spec: Param, value) -> Optional[str]:
    """The error text of ``value`` for ``spec`` (its validator), or None."""
    if spec.check is None:
        return None
    try:
        return spec.check(value)
    except (TypeError, ValueError) as exc:
        return f"invalid value {value!r} ({exc})"


# --------------------------------------------------------------------------------- diag

class Diagnostics:
    """Publishes one node's status on ``/diagnostics`` and as JSON on ``/aslip/diagnostics``.

    Levels follow diagnostic_msgs: 0 OK, 1 WARN, 2 ERROR, 3 STALE.
    """

    OK, WARN, ERROR, STALE = 0, 1, 2, 3

    def __init__(self, node, name: str, hardware_id: str = "") -> None:
        self._node = node
        self.name = name
        self.hardware_id = hardware_id
        self._json_pub = node.create_publisher(String, DIAG_JSON_TOPIC, RELIABLE_QOS)
        try:
            from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        except ImportError:
            self._types = None
            self._pub = None
        else:
            self._types = (DiagnosticArray, DiagnosticStatus, KeyValue)
            self._pub = node.create_publisher(DiagnosticArray, DIAG_TOPIC, RELIABLE_QOS)

    def publish(self, level: int, message: str, values: Optional[dict] = None) -> None:
        """Publish one status (never raises: diagnostics must not take a node down)."""
        values = {k: _plain(v) for k, v in (values or {}).items()}
        try:
            doc = {"name": self.name, "hardware_id": self.hardware_id, "level": int(level),
                   "message": message, "stamp": time.time(), "values": values}
            self._json_pub.publish(String(data=json.dumps(doc, allow_nan=False)))
            if self._pub is not None:
                arr_t, status_t, kv_t = self._types
                arr = arr_t()
                arr.header.stamp = self._node.get_clock().now().to_msg()
                arr.status = [status_t(level=bytes([int(level)]), name=self.name,
                                       message=message, hardware_id=self.hardware_id,
                                       values=[kv_t(key=k, value=str(v))
                                               for k, v in values.items()])]
                self._pub.publish(arr)
        except Exception as exc:  # noqa: BLE001 - e.g. the context is shutting down
            self._node.get_logger().debug(f"diagnostics not published: {exc}")


def _plain(v):
    """JSON-safe value: non-finite floats become strings, other objects their str()."""
    if isinstance(v, bool) or v is None or isinstance(v, (int, str)):
        return v
    if isinstance(v, float):
        return v if math.isfinite(v) else str(v)
    try:
        f = float(v)
        return f if math.isfinite(f) else str(f)
    except (TypeError, ValueError):
        return str(v)
