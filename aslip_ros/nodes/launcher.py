"""The first code of every node executable: signals blocked before any thread exists.

``install/lib/aslip_ros/<node>`` (written by CMakeLists.txt) calls :func:`main` with the
node's module name before anything else is imported. SIGINT and SIGTERM are blocked here,
while the main thread is still the only thread, so every thread created later inherits the
mask: OpenBLAS's (``import numpy`` starts it), torch's, DDS's and rclpy's. Only the signal
thread of :func:`aslip_ros.nodes.common.run_node` then receives them (``sigwait``).

Blocking them later, in ``run_node``, left the thread that ``import numpy`` had already
started with an empty mask: the launch's SIGINT could land there, become a
KeyboardInterrupt in the main thread and skip the forced exit, and the node outlived its
launch until SIGKILL (``test_nodes_exit.py``).

Nothing but the standard library is imported here, and nothing that starts a thread.
"""

from __future__ import annotations

import importlib
import signal

#: The signals a node handles on its own signal thread (``common.run_node``).
SHUTDOWN_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})


def main(node: str) -> int:
    """Block :data:`SHUTDOWN_SIGNALS`, then import ``aslip_ros.nodes.<node>`` and run it."""
    signal.pthread_sigmask(signal.SIG_BLOCK, SHUTDOWN_SIGNALS)
    return importlib.import_module(f"aslip_ros.nodes.{node}").main()


if __name__ == "__main__":
    # ``python -m aslip_ros.nodes.launcher <node> [--ros-args ...]``: a node module that has
    # no installed executable yet, started the same way (a launch file's ExecuteProcess).
    import sys
    raise SystemExit(main(sys.argv[1]))
