"""``aslip check arm``: connect to the arm, read the TCP, and move it 1 cm at 1 cm/s and back
with velocity commands, inside the workspace and speed limits.

Nothing moves unless the TCP is inside the workspace box, the test move stays inside it
(with :data:`MARGIN_M` to spare), the speed is within the arm's limit and the person
confirmed. The arm is stopped in a ``finally`` (also on Ctrl-C and on any error). The
measured displacement of each leg must be the commanded distance within
:data:`TOLERANCE_M`.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Optional, Sequence, Tuple

import numpy as np

from aslip_ros.arm import ArmError
from aslip_ros.bringup.verdict import Verdict

#: The test move must end at least this far inside the workspace box.
MARGIN_M = 0.005
#: The measured displacement may differ from the commanded one by this much.
TOLERANCE_M = 0.003
#: Command period and each command's controller-side duration: the arm stops by itself
#: within ``COMMAND_DURATION_S`` if the commands stop.
COMMAND_PERIOD_S = 0.02
COMMAND_DURATION_S = 0.1
#: After a stop, wait this long before reading where the TCP came to rest.
SETTLE_S = 0.5

AXES = {'+x': (1, 0, 0), '-x': (-1, 0, 0), '+y': (0, 1, 0), '-y': (0, -1, 0),
        '+z': (0, 0, 1), '-z': (0, 0, -1)}
#: The order in which an axis with room is looked for: up first (away from the table).
AXIS_PREFERENCE = ('+z', '-z', '+x', '-x', '+y', '-y')


def inside(p: np.ndarray, lo: Sequence[float], hi: Sequence[float], margin: float = 0.0
           ) -> bool:
    """Whether ``p`` lies in the box shrunk by ``margin``."""
    return bool(np.all(p >= np.asarray(lo) + margin) and np.all(p <= np.asarray(hi) - margin))


def choose_axis(p: np.ndarray, distance: float, lo: Sequence[float], hi: Sequence[float],
                axis: Optional[str] = None) -> Optional[str]:
    """The axis (``'+z'``...) whose test move stays inside the box, or None.

    With ``axis`` given only that one is tried; else :data:`AXIS_PREFERENCE` in order.
    """
    for name in ([axis] if axis else AXIS_PREFERENCE):
        if inside(p + distance * np.asarray(AXES[name], dtype=float), lo, hi, MARGIN_M):
            return name
    return None


class ArmCheck:
    """The test move on a connected :class:`~aslip_ros.arm.Arm` (a ``LimitedArm``).

    :param arm: the arm, with ``limits`` (the adapter's :class:`ArmLimits`).
    :param clock: monotonic time; ``sleep``: used between commands.
    :param out: where the progress goes.
    """

    def __init__(self, arm: Any, out, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.arm = arm
        self.out = out
        self._clock = clock
        self._sleep = sleep

    def position(self) -> np.ndarray:
        """The TCP position [m]."""
        return np.asarray(self.arm.tcp_pose(), dtype=np.float64)[:3]

    def plan(self, speed: float, distance: float, axis: Optional[str],
             verdict: Verdict) -> Optional[Tuple[np.ndarray, str]]:
        """(start position, axis) when the move is allowed; else None with the reason."""
        lim = self.arm.limits
        p = self.position()
        print(f'TCP at {np.round(p, 4).tolist()} m; workspace {list(lim.workspace_min_m)} .. '
              f'{list(lim.workspace_max_m)} m; speed limit {lim.max_speed_m_s:g} m/s',
              file=self.out)
        if speed > lim.max_speed_m_s:
            verdict.fail(f'--speed {speed:g} m/s is above the arm\'s limit '
                         f'{lim.max_speed_m_s:g} m/s; nothing moved')
            return None
        if not inside(p, lim.workspace_min_m, lim.workspace_max_m):
            verdict.fail(f'the TCP {np.round(p, 4).tolist()} m is outside the workspace: jog '
                         'it inside (or fix the workspace box); nothing moved')
            return None
        chosen = choose_axis(p, distance, lim.workspace_min_m, lim.workspace_max_m, axis)
        if chosen is None:
            verdict.fail(f'a {distance * 100:g} cm move along {axis or "any axis"} would leave '
                         f'the workspace (with {MARGIN_M * 1e3:g} mm to spare): jog the TCP '
                         'towards the middle of the box; nothing moved')
            return None
        return p, chosen

    def leg(self, direction: np.ndarray, speed: float, distance: float) -> float:
        """Move ``distance`` along ``direction`` at ``speed``, stop, settle; return the
        measured displacement along ``direction`` [m]."""
        start = self.position()
        self.arm.enable_velocity_mode()
        v = direction * speed
        t_end = self._clock() + distance / speed
        while True:
            now = self._clock()
            if now >= t_end:
                break
            # The last command lasts only as long as the move has left.
            self.arm.send_velocity(v, min(COMMAND_DURATION_S, max(t_end - now, 1e-3)))
            self._sleep(min(COMMAND_PERIOD_S, max(t_end - self._clock(), 0.0)))
        self.arm.stop()
        self._sleep(SETTLE_S)
        moved = self.position() - start
        return float(np.dot(moved, direction))

    def run(self, speed: float, distance: float, axis: Optional[str],
            confirm: Callable[[str], bool]) -> Verdict:
        """Plan, confirm, move out and back; the verdict (the arm is stopped after)."""
        verdict = Verdict()
        try:
            planned = self.plan(speed, distance, axis, verdict)
            if planned is None:
                return verdict
            _, name = planned
            question = (f'move the TCP {distance * 100:g} cm along {name} at '
                        f'{speed * 100:g} cm/s and back?')
            if not confirm(question):
                return verdict.fail('not confirmed; nothing moved')
            direction = np.asarray(AXES[name], dtype=float)
            for label, sign in (('out', 1.0), ('back', -1.0)):
                moved = self.leg(sign * direction, speed, distance)
                print(f'{label}: moved {moved * 1e3:.1f} mm along '
                      f'{name if sign > 0 else name.translate(str.maketrans("+-", "-+"))} '
                      f'(commanded {distance * 1e3:.1f} mm)', file=self.out)
                if abs(moved - distance) > TOLERANCE_M:
                    verdict.fail(f'the {label} move measured {moved * 1e3:.1f} mm, not '
                                 f'{distance * 1e3:.1f} +- {TOLERANCE_M * 1e3:g} mm: check the '
                                 'arm\'s mode, its speed override and the TCP offset')
                    break
        except ArmError as exc:
            verdict.fail(f'the arm refused: {exc}')
        finally:
            try:
                self.arm.stop()
            except ArmError as exc:
                verdict.fail(f'stopping the arm failed: {exc}: use the emergency stop')
        return verdict


def arm_config(ip: str, max_speed_m_s: Optional[float] = None,
               workspace_min_m: Optional[Sequence[float]] = None,
               workspace_max_m: Optional[Sequence[float]] = None):
    """The adapter's :class:`~aslip_ros.hw.xarm_config.XArmConfig`: what is given, the
    config's own defaults (the one definition) for the rest."""
    from aslip_ros.hw.xarm_config import XArmConfig
    given = dict(max_speed_m_s=max_speed_m_s, workspace_min_m=workspace_min_m,
                 workspace_max_m=workspace_max_m)
    return XArmConfig(ip=ip, **{k: v for k, v in given.items() if v is not None})


def check_arm(config: Any, speed: float, distance: float, axis: Optional[str], out,
              confirm: Callable[[str], bool], api_factory: Optional[Callable] = None,
              clock: Callable[[], float] = time.monotonic,
              sleep: Callable[[float], None] = time.sleep) -> int:
    """Connect an :class:`~aslip_ros.hw.xarm.XArmAdapter` with ``config``, run the test
    move, print the verdict; return the exit code. The arm is closed (stopped) after."""
    from aslip_ros.hw.xarm import XArmAdapter
    if not (0.0 < speed and 0.0 < distance):
        raise ValueError(f'--speed and --distance must be > 0, got {speed:g}, {distance:g}')
    arm = XArmAdapter(config, api_factory=api_factory, clock=clock, sleep=sleep)
    try:
        try:
            arm.connect()
        except ArmError as exc:
            return Verdict().fail(f'cannot connect: {exc}; nothing moved').report(out)
        verdict = ArmCheck(arm, out, clock=clock, sleep=sleep).run(speed, distance, axis,
                                                                   confirm)
    finally:
        arm.close()
    return verdict.report(out)
