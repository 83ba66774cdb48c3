"""The arms a controller node can drive, by the name in its ``arm`` parameter.

An entry says how to build the arm from the node and its parameter values, and where the
TCP pose comes from:

- ``sim``: :class:`~aslip_ros.nodes.topic_arm.TopicArm`, commands on ``/aslip/arm/cmd_vel``
  for ``scene_sim``; the TCP arrives on ``/aslip/robot/tcp_pose`` and is handed to the arm
  (``pose_from_topic``). The scene limits its own arm.
- ``xarm``: :class:`~aslip_ros.hw.xarm.XArmAdapter` at ``xarm_ip``, within the ``arm_*``
  limits; the arm measures its TCP and the node republishes it.
- ``module.path:factory``: ``factory(node, params) -> Arm`` from any module on the Python
  path (:mod:`aslip_ros.plugin`), wrapped in :class:`~aslip_ros.control.limits.LimitedArm`
  with the speed and workspace limits of the ``arm_*`` parameters, so a new arm never
  moves unlimited. A factory that needs more (its TCP from the topic) is an
  :class:`ArmKind` instead of a bare callable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Dict, Mapping

from aslip_ros import plugin
from aslip_ros.control.limits import ArmLimits, LimitedArm
from aslip_ros.hw.xarm import XArmAdapter, XArmConfig
from aslip_ros.nodes.params import config_kwargs
from aslip_ros.nodes.topic_arm import TopicArm

ArmFactory = Callable[[Any, Mapping[str, Any]], Any]


@dataclass(frozen=True)
class ArmKind:
    """How a controller node builds and feeds one kind of arm.

    :ivar make: ``(node, params) -> Arm``; may raise ArmError, ValueError, ImportError or
        OSError (the node then stays unconfigured).
    :ivar pose_from_topic: the TCP comes from ``/aslip/robot/tcp_pose`` and is handed to
        ``arm.set_pose(pose7)``; otherwise the arm measures it (``set_pose_listener`` or
        polling ``tcp_pose``) and the node publishes it on that topic.
    :ivar describe: extra diagnostics values from the parameters.
    """

    make: ArmFactory
    pose_from_topic: bool = False
    describe: Callable[[Mapping[str, Any]], dict] = lambda p: {}


#: The limit parameters are the fields of :class:`~aslip_ros.control.limits.ArmLimits`
#: with this prefix, for any arm: ``arm_max_speed_m_s``, ``arm_workspace_min_m``, ...
LIMIT_PREFIX = "arm_"


def limits(p: Mapping[str, Any]) -> ArmLimits:
    """The :class:`~aslip_ros.control.limits.ArmLimits` of the limit parameters."""
    return ArmLimits(**config_kwargs(ArmLimits, p, LIMIT_PREFIX))


def _sim(node, p: Mapping[str, Any]):
    return TopicArm(node)


def _xarm(node, p: Mapping[str, Any]):
    cfg = XArmConfig(ip=p["xarm_ip"], connect_timeout_s=p["xarm_connect_timeout_s"],
                     **config_kwargs(ArmLimits, p, LIMIT_PREFIX))
    return XArmAdapter(cfg)


#: The built-in arms by name.
ARMS: Dict[str, ArmKind] = {
    "sim": ArmKind(_sim, pose_from_topic=True),
    "xarm": ArmKind(_xarm, describe=lambda p: {"xarm_ip": p["xarm_ip"]}),
}


def _limited(factory: ArmFactory) -> ArmFactory:
    def make(node, p: Mapping[str, Any]):
        return LimitedArm(factory(node, p), limits(p))
    return make


def resolve_arm(name: str) -> ArmKind:
    """The :class:`ArmKind` of ``name``: a key of :data:`ARMS` or ``module.path:attribute``.

    The attribute is an :class:`ArmKind` (used as it is) or a factory ``(node, params) ->
    Arm`` (its arm measures its own TCP and is wrapped in the configured limits). Raises
    ValueError with the choices otherwise.
    """
    if name in ARMS:
        return ARMS[name]
    found = plugin.load(name, f"one of {', '.join(ARMS)}",
                        accept=lambda obj: isinstance(obj, ArmKind) or callable(obj))
    return found if isinstance(found, ArmKind) else ArmKind(_limited(found))
