"""A node whose shutdown hangs inside a C call that holds the GIL (test_nodes_exit.py).

Started like the installed executables (``aslip_ros.runtime.launcher``): the signals are
blocked before any import. After SIGINT it calls libc ``sleep`` through ``ctypes.PyDLL``,
which keeps the GIL: no Python thread (the forced-exit timer included) can run again, so
only an exit armed in C ends the process.

``stuck_node.py [where [code]]``: ``where`` is ``before_shutdown`` (default: the node's own
shutdown work hangs) or ``teardown`` (its work is done, then ``destroy_node`` hangs, as the
middleware's node teardown once did in CI); ``teardown_waits``: ``destroy_node`` hangs with
the GIL free (``time.sleep``); ``teardown_slow``: it takes 1.5 s, then goes on. ``code`` is
the node's ``exit_code``.
"""

import sys


def main() -> int:
    import ctypes

    from rclpy.node import Node

    from aslip_ros.runtime.process import ready, run_node

    where = sys.argv[1] if len(sys.argv) > 1 else "before_shutdown"
    code = int(sys.argv[2]) if len(sys.argv) > 2 else 0

    def stick(step: str) -> None:
        import time
        if step == where:
            print(f"{step}: sleeping with the GIL held", flush=True)
            ctypes.PyDLL(None).sleep(120)
        elif step == "teardown" and where in ("teardown_waits", "teardown_slow"):
            print(f"{where}: sleeping with the GIL free", flush=True)
            time.sleep(120 if where == "teardown_waits" else 1.5)

    class StuckNode(Node):
        def __init__(self) -> None:
            super().__init__("stuck_node")
            self.exit_code = code
            ready(self, "stuck on shutdown")

        def before_shutdown(self) -> None:
            print("before_shutdown: done" if where != "before_shutdown" else "", flush=True)
            stick("before_shutdown")

        def destroy_node(self) -> None:
            stick("teardown")
            super().destroy_node()

    return run_node(StuckNode)


if __name__ == "__main__":
    from aslip_ros.runtime import launcher
    sys.modules["stuck_node"] = sys.modules[__name__]     # the module path it imports
    sys.exit(launcher.main("stuck_node"))
