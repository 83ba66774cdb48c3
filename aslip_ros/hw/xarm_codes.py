"""The xArm SDK's return codes and the controller's error and warning numbers, explained.

The SDK reports failures as integer return codes (``xarm/x3/code.py``, ``APIState``); the
meanings below are written in this project's own words. Controller error and warning
numbers are looked up in the SDK's own tables when it is importable.
"""

from __future__ import annotations

# SDK return codes (xarm/x3/code.py, APIState), described in our own words.
_CODE_MEANING = {
    -1: 'not connected',
    -2: 'not ready (motion not enabled or state not set)',
    -3: 'API exception, possibly an invalid parameter',
    -4: 'command does not exist',
    -6: 'Cartesian limit reached',
    -7: 'joint limit reached',
    -8: 'out of range',
    -9: 'emergency stop',
    1: 'controller has an uncleared error',
    2: 'controller has an uncleared warning',
    3: 'reply timeout',
    4: 'reply length error',
    5: 'reply sequence number error',
    6: 'protocol flag error',
    7: 'reply does not match the command',
    8: 'send failed',
    9: 'not ready to move',
    10: 'result invalid or execution failed',
    11: 'other error',
    12: 'parameter error',
    -10: 'no joint with this servo ID',
    -11: 'a Blockly program could not be converted',
    -12: 'a Blockly app failed while running',
    20: 'wrong host ID (end-effector IO or linear track)',
    21: 'Modbus baud rate not supported',
    22: 'end-effector Modbus baud rate is wrong',
    23: 'Modbus reply has the wrong length',
    31: 'trajectory could not be loaded or saved',
    32: 'loading or saving a trajectory timed out',
    33: 'trajectory playback timed out',
    34: 'trajectory playback failed',
    41: 'timed out waiting for the suction cup',
    51: 'wrong mode',
    100: 'timed out waiting for an operation to finish',
    101: 'too many failed state checks while waiting for an operation',
    102: 'the end effector reports an error',
    103: 'the end effector is not enabled',
}


def describe_code(code: int) -> str:
    """A human-readable meaning for an SDK return code."""
    return _CODE_MEANING.get(int(code), 'unknown code')


def controller_error_text(error_code: int) -> str:
    """The SDK's own title for a controller error number, if the SDK is importable."""
    try:
        from xarm.core.config.x_code import ControllerErrorCodeMap
        return ControllerErrorCodeMap[int(error_code)]['en']['title']
    except Exception:  # noqa: BLE001 - a missing description must not mask the error
        return 'see the xArm controller error table'


def controller_warn_text(warn_code: int) -> str:
    """The SDK's own title for a controller warning number, if the SDK is importable."""
    try:
        from xarm.core.config.x_code import ControllerWarnCodeMap
        return ControllerWarnCodeMap[int(warn_code)]['en']['title']
    except Exception:  # noqa: BLE001 - a missing description must not mask the warning
        return 'see the xArm controller warning table'
