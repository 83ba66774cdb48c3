"""The first code of every node executable: signals blocked before any thread exists.

``install/lib/aslip_ros/<node>`` (written by CMakeLists.txt, one per row of
:mod:`aslip_ros.node_table`) calls :func:`main` with the node's name before anything else is
imported; ``python -m aslip_ros.runtime.launcher <name or module>`` does the same for a node
that has no installed executable (a registered one, docs/design.md "A new controller").
SIGINT and SIGTERM are blocked here, while the main thread is still the only thread, so every
thread created later inherits the mask: OpenBLAS's (``import numpy`` starts it), torch's,
DDS's and rclpy's. Only the signal thread of :func:`aslip_ros.runtime.process.run_node`
then receives them (``sigwait``).

Blocking them later, in ``run_node``, left the thread that ``import numpy`` had already
started with an empty mask: the launch's SIGINT could land there, become a
KeyboardInterrupt in the main thread and skip the forced exit, and the node outlived its
launch until SIGKILL (``test_nodes_exit.py``).

Nothing but the standard library (and the node table, pure data) is imported here, and
nothing that starts a thread.
"""

from __future__ import annotations

import importlib
import signal

#: The signals a node handles on its own signal thread (``process.run_node``).
SHUTDOWN_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})


def main(node: str) -> int:
    """Block :data:`SHUTDOWN_SIGNALS`, then import the module of ``node`` (a name of the node
    table, or a module path) and run its ``main()``."""
    signal.pthread_sigmask(signal.SIG_BLOCK, SHUTDOWN_SIGNALS)
    from aslip_ros import node_table
    known = node_table.nodes().get(node)
    return importlib.import_module(known.module if known else node).main()


if __name__ == "__main__":
    # ``python -m aslip_ros.runtime.launcher <node> [--ros-args ...]``: a node that has no
    # installed executable, started the same way (a launch file's Node or ExecuteProcess).
    import sys
    raise SystemExit(main(sys.argv[1]))
