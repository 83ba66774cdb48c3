"""The parameters a node executable declares, read without starting ROS.

Every node declares all its parameters in one ``common.declare_params(node, specs, ...)``
call from its constructor. :func:`declared_params` runs the constructor with the rclpy
node base classes and ``declare_params`` replaced by stand-ins, and returns the specs that
call received: no ``rclpy.init``, no context, nothing published. Tests use it to check a
launch file's parameters (names, types, validators) against what each node accepts.
"""

from __future__ import annotations

import importlib
from typing import Dict, List
from unittest import mock

from aslip_ros import node_table


class _Declared(Exception):
    def __init__(self, specs) -> None:
        super().__init__("declared")
        self.specs = list(specs)


def declared_params(executable: str) -> List:
    """The :class:`aslip_ros.nodes.params.Param` specs ``executable`` (a node of
    :mod:`aslip_ros.node_table`) declares."""
    from rclpy.lifecycle import LifecycleNode
    from rclpy.node import Node

    from aslip_ros.nodes import common
    row = node_table.spec(executable)
    cls = getattr(importlib.import_module(row.module), row.node_class)

    def capture(node, specs, *args, **kwargs):
        raise _Declared(specs)

    def no_init(self, *args, **kwargs) -> None:
        return None

    obj = cls.__new__(cls)
    with mock.patch.object(Node, "__init__", no_init), \
            mock.patch.object(LifecycleNode, "__init__", no_init), \
            mock.patch.object(common, "declare_params", capture):
        try:
            cls.__init__(obj)
        except _Declared as got:
            return got.specs
    raise RuntimeError(f"{executable} declared no parameters through declare_params")


def declared_by_name(executable: str) -> Dict[str, object]:
    """``{name: Param}`` of :func:`declared_params`."""
    return {p.name: p for p in declared_params(executable)}
