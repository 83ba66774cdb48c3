"""Stand-in for the ``xarm`` package of xarm-python-sdk (test helper, not the real SDK).

Put ``test/helpers/fake_xarm_sdk`` first on a node process's ``PYTHONPATH`` and
``from xarm.wrapper import XArmAPI`` loads :mod:`xarm.wrapper` from here, which forwards
every call to the fake controller of ``test/helpers/hw_rig.py`` over TCP (port from
``ASLIP_FAKE_XARM_PORT``), so the package's real adapter (aslip_ros/hw/xarm.py) runs
unmodified. There is deliberately no ``xarm.core`` (aslip_ros/hw/xarm_sdk.py and
xarm_codes.py tolerate its absence: no SDK log rerouting, generic error texts).
"""

__version__ = "0.0.0-fake"
