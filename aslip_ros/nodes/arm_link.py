"""Opening and closing an arm the way every node that drives one does (the controllers,
robot_sweeps): built by its kind, connected, every later call on an
:class:`~aslip_ros.control.arm_worker.ArmWorker` thread, its TCP measured by a report
stream where it has one, else polled at the control rate."""

from __future__ import annotations

import time
from typing import Any, Callable, Mapping, Optional, Tuple

from aslip_ros.arm import ArmError
from aslip_ros.control.arm_worker import ArmWorker

#: What building or connecting an arm may raise: the node stays unconfigured.
OPEN_ERRORS = (ArmError, ValueError, ImportError, OSError)


def open_arm(node, kind, params: Mapping[str, Any], on_pose: Callable,
             on_error: Callable, name: str,
             clock: Callable[[], float] = time.monotonic) -> Tuple[Any, ArmWorker]:
    """Build ``kind``'s arm for ``node``, connect it and start its worker thread.

    ``on_pose(pose, now, stamp_ns)`` gets every pose the arm measures; ``on_error(exc)`` a
    failed arm call; ``clock`` is the node's time source (the worker's stop times). Raises
    one of :data:`OPEN_ERRORS` (nothing is left open then)."""
    arm = kind.make(node, params)
    arm.connect()
    streams = kind.pose_from_topic
    listen = getattr(arm, "set_pose_listener", None)
    if listen is not None:
        streams = bool(listen(on_pose))
    poll = None if streams else 1.0 / params["control_rate_hz"]
    return arm, ArmWorker(arm, on_error, on_pose=on_pose, poll_period_s=poll, name=name,
                          clock=clock)


def close_arm(arm: Optional[Any], worker: Optional[ArmWorker], logger) -> None:
    """Stop the worker thread, detach the pose listener and close the arm (errors logged)."""
    if worker is not None:
        worker.close(2.0)
    if arm is None:
        return
    listen = getattr(arm, "set_pose_listener", None)
    if listen is not None:
        listen(None)
    try:
        arm.close()
    except Exception as exc:  # noqa: BLE001 - closing must go on
        logger.error(f"arm close failed: {exc}")
