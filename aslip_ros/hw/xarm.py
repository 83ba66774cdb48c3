"""xArm adapter: :class:`~aslip_ros.arm.Arm` over xarm-python-sdk (``XArmAPI``).

The SDK reports failures as integer return codes, never as exceptions, so a caller that
forgets one check keeps driving an arm that has already refused. This adapter checks every
code: a non-zero code stops the arm (best effort) and raises :class:`XArmError`, a subclass
of :class:`~aslip_ros.arm.ArmError` carrying the code and its meaning.

Safety properties:

- every velocity command carries the controller-side ``duration`` (the arm stops by itself
  if the commands stop), and firmware too old to honour it is refused at connect;
- the speed, acceleration, rate and workspace limits are those of every arm
  (:class:`~aslip_ros.control.limits.LimitedArm`): :class:`XArmAdapter` is a ``LimitedArm``
  around :class:`XArmDriver`, which only talks to the SDK; the rate limit is at most 250 Hz
  (the controller drops faster commands);
- while streaming, the controller's error and warning codes are checked, and a warning
  (a command not executed as sent) stops the arm;
- connecting happens in a worker thread with a deadline, so an unreachable arm raises
  instead of hanging the caller.

SI units at the interface; millimetres appear only in the SDK calls.

The pose comes from the SDK's report stream when it is current, so a command costs one
round trip, not three. Modules: :mod:`.xarm_config` (settings, errors, constants),
:mod:`.xarm_driver` (the SDK calls), :mod:`.xarm_sdk` (the SDK's import, logging, socket
timeout and connect deadline contained), :mod:`.xarm_codes` (its return codes explained).
"""

from __future__ import annotations

import time
from typing import Any, Callable, Optional

from aslip_ros.control.limits import LimitedArm
from aslip_ros.hw.xarm_codes import describe_code  # noqa: F401 - part of this API
from aslip_ros.hw.xarm_config import (CONTROLLER_MAX_RATE_HZ,  # noqa: F401 - this API
                                      MIN_FIRMWARE_FOR_DURATION, MODE_CARTESIAN_VELOCITY,
                                      STATE_MOTION, STATE_STOP, XArmConfig, XArmError)
from aslip_ros.hw.xarm_driver import XArmDriver
# Looked up here at each adapter's creation, so a test can replace it on this module.
from aslip_ros.hw.xarm_sdk import default_api_factory


class XArmAdapter(LimitedArm):
    """An xArm as an :class:`~aslip_ros.arm.Arm`: :class:`XArmDriver` behind the
    configured limits (:class:`~aslip_ros.control.limits.LimitedArm`). Thread-safe.

    The driver's extras (``connected``, ``velocity_mode_enabled``, ``config``,
    ``set_pose_listener``, counters) are this object's too.

    :param config: connection and limits.
    :param api_factory: ``ip -> XArmAPI-like`` object, created unconnected; tests inject a
        fake here. Default: :func:`default_api_factory`.
    :param clock: monotonic time source for the limits and the driver.
    :param sleep: used by the rate limit and the mode settle time.
    """

    def __init__(self, config: XArmConfig,
                 api_factory: Optional[Callable[[str], Any]] = None,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        """Create the adapter; nothing is contacted until :meth:`connect`."""
        driver = XArmDriver(config, api_factory or default_api_factory, clock, sleep)
        super().__init__(driver, config.limits, clock=clock, sleep=sleep, error=XArmError)

    def __enter__(self) -> 'XArmAdapter':
        """Connect on entering a ``with`` block."""
        self.connect()
        return self

    def __exit__(self, *exc: Any) -> None:
        """Stop and disconnect on leaving it."""
        self.close()
