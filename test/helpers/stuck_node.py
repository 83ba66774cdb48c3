"""A node whose shutdown hangs inside a C call that holds the GIL (test_nodes_exit.py).

Started like the installed executables (``aslip_ros.runtime.launcher``): the signals are
blocked before any import. After SIGINT its ``before_shutdown`` calls libc ``sleep``
through ``ctypes.PyDLL``, which keeps the GIL: no Python thread (the forced-exit timer
included) can run again, so only an exit armed in C ends the process.
"""

import sys


def main() -> int:
    import ctypes

    from rclpy.node import Node

    from aslip_ros.runtime.process import ready, run_node

    class StuckNode(Node):
        def __init__(self) -> None:
            super().__init__("stuck_node")
            ready(self, "stuck on shutdown")

        def before_shutdown(self) -> None:
            print("before_shutdown: sleeping with the GIL held", flush=True)
            ctypes.PyDLL(None).sleep(120)

    return run_node(StuckNode)


if __name__ == "__main__":
    from aslip_ros.runtime import launcher
    sys.modules["stuck_node"] = sys.modules[__name__]     # the module path it imports
    sys.exit(launcher.main("stuck_node"))
