"""The xArm's SDK as an :class:`~aslip_ros.arm.Arm`, without the motion limits
(:class:`aslip_ros.hw.xarm.XArmAdapter` adds them); docs in :mod:`aslip_ros.hw.xarm`."""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable, Optional, Sequence, Tuple

import numpy as np
from scipy.spatial.transform import Rotation

from aslip_ros.arm import ArmError
from aslip_ros.control.limits import checked_command
from aslip_ros.hw.xarm_codes import controller_error_text as _controller_error_text
from aslip_ros.hw.xarm_codes import controller_warn_text as _controller_warn_text
from aslip_ros.hw.xarm_codes import describe_code
from aslip_ros.hw.xarm_config import (MIN_FIRMWARE_FOR_DURATION, MODE_CARTESIAN_VELOCITY,
                                      STATE_MOTION, STATE_STOP, XArmConfig, XArmError)
from aslip_ros.hw.xarm_sdk import code_of as _code_of
from aslip_ros.hw.xarm_sdk import ConnectTimeout, connect_within, default_api_factory
from aslip_ros.hw.xarm_sdk import socket_default_timeout_restored as _timeout_restored

_LOG = logging.getLogger('aslip_ros.hw.xarm')


class XArmDriver:
    """The xArm's SDK as an :class:`~aslip_ros.arm.Arm`, without the motion limits
    (use :class:`XArmAdapter`, which adds them). Thread-safe.

    :param config: connection settings (its limits are :class:`XArmAdapter`'s).
    :param api_factory: ``ip -> XArmAPI-like`` object, created unconnected; tests inject a
        fake here. Default: :func:`default_api_factory`.
    :param clock: monotonic time source (report age, status period).
    :param sleep: used for the mode settle time.
    """

    def __init__(self, config: XArmConfig,
                 api_factory: Optional[Callable[[str], Any]] = None,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        """Create the adapter; nothing is contacted until :meth:`connect`."""
        self._cfg = config
        self._factory = api_factory or default_api_factory
        self._clock = clock
        self._sleep = sleep
        self._lock = threading.RLock()
        self._api: Any = None
        self._enabled = False
        self._last_status_t: Optional[float] = None
        # Newest report-stream pose: (pose7, clock time, wall ns); its own lock, so a report
        # never waits behind a command's round trip.
        self._report_lock = threading.Lock()
        self._report: Optional[Tuple[np.ndarray, float, int]] = None
        self._pose_listener: Optional[Callable[[np.ndarray, float, int], None]] = None
        self._streaming = False
        self.reports_rejected = 0
        self.commands_sent = 0

    # -- Arm protocol -----------------------------------------------------------------------

    def connect(self) -> None:
        """Connect within ``connect_timeout_s``; raise :class:`XArmError` if unreachable.

        Also refuses firmware that cannot honour ``duration`` and an arm that reports a
        controller error (clearing errors is left to a person who has looked at the arm).
        """
        with self._lock:
            if self._api is not None:
                return
            ip = self._cfg.ip
            try:
                api = self._factory(ip)
            except Exception as exc:  # noqa: BLE001 - any SDK failure means "no arm"
                raise XArmError(f'cannot create the xArm API for {ip}: {exc}') from exc
            try:
                connect_within(api, self._cfg.connect_timeout_s)
            except ConnectTimeout:
                raise XArmError(f'xArm at {ip} did not answer within '
                                f'{self._cfg.connect_timeout_s:g} s') from None
            except BaseException as exc:  # noqa: BLE001 - whatever the SDK raised
                raise XArmError(f'cannot connect to xArm at {ip}: {exc}') from exc
            if not getattr(api, 'connected', False):
                raise XArmError(f'cannot connect to xArm at {ip}: SDK reports no connection')
            self._api = api
            try:
                self._check_firmware()
                self._refuse_if_controller_error()
            except BaseException:
                self._disconnect_quietly()
                raise
            self._subscribe_reports(api)

    def enable_velocity_mode(self) -> None:
        """Enable motion, switch to Cartesian velocity mode (5) and the motion state (0)."""
        with self._lock:
            self._require_connected()
            self._call('motion_enable', enable=True)
            self._call('set_mode', MODE_CARTESIAN_VELOCITY)
            self._call('set_state', STATE_MOTION)
            # Mode and state calls report success even while the controller holds an
            # error (the SDK maps that code to 0 for non-motion calls), so ask explicitly.
            self._refuse_if_controller_error()
            # The controller applies a mode change asynchronously; a command sent at once
            # can be rejected or applied in the old mode.
            if self._cfg.mode_settle_s > 0.0:
                self._sleep(self._cfg.mode_settle_s)
            self._enabled = True
            self._last_status_t = self._clock()

    def send_velocity(self, v_xyz_m_s: np.ndarray, duration_s: float) -> None:
        """Command a TCP velocity [m/s, ``link_base``], valid for ``duration_s`` [s], as is.

        Raises :class:`XArmError` (after stopping the arm) on an invalid request, a
        controller error or warning, or any non-zero SDK code.
        """
        with self._lock:
            self._require_connected()
            if not self._enabled:
                raise XArmError('velocity mode is not enabled (after connect() or stop(), call '
                                'enable_velocity_mode())')
            try:
                # duration <= 0 means "never stop" to the SDK: never let it through.
                v, duration = checked_command(v_xyz_m_s, duration_s)
            except ValueError as exc:
                self._stop_quietly()
                raise XArmError(f'refused command: {exc}') from exc
            self._check_status_if_due()
            mm = v * 1000.0
            self._call('vc_set_cartesian_velocity',
                       [float(mm[0]), float(mm[1]), float(mm[2]), 0.0, 0.0, 0.0],
                       is_radian=True, is_tool_coord=False, duration=duration)
            self.commands_sent += 1

    def stop(self) -> None:
        """Stop now: zero velocity, then the stop state. Safe at any time.

        Velocity mode must be re-enabled before the next :meth:`send_velocity`. Raises
        :class:`XArmError` only if the arm is connected and neither way of stopping was
        accepted (an arm already halted by a controller error counts as stopped).
        """
        with self._lock:
            self._enabled = False
            api = self._api
            if api is None or not getattr(api, 'connected', False):
                return
            codes = []
            for name, args, kwargs in (
                    ('vc_set_cartesian_velocity', ([0.0] * 6,),
                     {'is_radian': True, 'is_tool_coord': False,
                      'duration': self._cfg.max_duration_s}),
                    ('set_state', (STATE_STOP,), {})):
                try:
                    codes.append(_code_of(getattr(api, name)(*args, **kwargs)))
                except Exception as exc:  # noqa: BLE001 - keep trying the other way
                    _LOG.warning('xArm %s during stop raised %s', name, exc)
                    codes.append(-3)
            # Code 1 (uncleared controller error): the controller has already halted.
            if not any(c in (0, 1) for c in codes):
                raise XArmError(f'xArm did not accept stop (codes {codes}: '
                                f'{", ".join(describe_code(c) for c in codes)})', code=codes[-1])

    def tcp_pose(self) -> np.ndarray:
        """TCP pose ``(x, y, z, qx, qy, qz, qw)`` in ``link_base`` [m].

        The report stream's newest pose when it is current (no round trip), else queried.
        """
        fresh = self._fresh_report()
        if fresh is not None:
            return fresh.copy()
        with self._lock:
            self._require_connected()
            _, pos = self._call_get('get_position', is_radian=True)
            return self._to_pose(pos)

    def set_pose_listener(self, listener: Optional[Callable[[np.ndarray, float, int], None]]
                          ) -> bool:
        """Call ``listener(pose7, clock_s, wall_ns)`` for every report-stream pose.

        The times are when the report arrived (when the pose was measured, to within the
        network delay), on the adapter's clock and the wall clock. Returns False when the
        SDK gives no report stream: the caller must then poll :meth:`tcp_pose`.
        """
        with self._report_lock:
            self._pose_listener = listener
        return self._streaming

    def close(self) -> None:
        """Stop and disconnect; safe to call more than once."""
        with self._lock:
            if self._api is None:
                return
            try:
                self.stop()
            except ArmError as exc:
                _LOG.warning('stop during close failed: %s', exc)
            self._disconnect_quietly()

    # -- extras -----------------------------------------------------------------------------

    @property
    def config(self) -> XArmConfig:
        """The adapter's configuration."""
        return self._cfg

    @property
    def connected(self) -> bool:
        """True after a successful :meth:`connect` while the SDK reports a connection."""
        with self._lock:
            return self._api is not None and bool(getattr(self._api, 'connected', False))

    @property
    def velocity_mode_enabled(self) -> bool:
        """True between :meth:`enable_velocity_mode` and the next stop or error."""
        with self._lock:
            return self._enabled

    def __enter__(self) -> 'XArmDriver':
        """Connect on entering a ``with`` block."""
        self.connect()
        return self

    def __exit__(self, *exc: Any) -> None:
        """Stop and disconnect on leaving it."""
        self.close()

    # -- internals --------------------------------------------------------------------------

    def _require_connected(self) -> None:
        if self._api is None:
            raise XArmError('not connected (call connect())', code=-1)

    def _refuse_if_controller_error(self, while_moving: bool = False) -> None:
        """Raise on a controller error; a warning raises too ``while_moving``.

        A warning means the controller ignored a command (cache full, a parameter out of
        range, no solution): while streaming velocities the arm is then not doing what was
        sent, so the adapter stops. Before motion a left-over warning is only logged and
        cleared, as it says nothing about the commands to come.
        """
        code, err_warn = self._call_get('get_err_warn_code')
        error = int(err_warn[0]) if err_warn else 0
        warning = int(err_warn[1]) if err_warn is not None and len(err_warn) > 1 else 0
        self._last_status_t = self._clock()
        if error != 0:
            self._stop_quietly()
            raise XArmError(f'xArm at {self._cfg.ip} reports controller error {error}: '
                            f'{_controller_error_text(error)}; clear it on the arm',
                            code=code, controller_error=error)
        if warning == 0:
            return
        text = f'xArm at {self._cfg.ip} reports controller warning {warning}: ' \
               f'{_controller_warn_text(warning)}'
        if while_moving:
            self._stop_quietly()
            raise XArmError(text + '; a command was not executed as sent, stopped',
                            code=code, controller_warning=warning)
        _LOG.warning('%s (left over from earlier commands; cleared)', text)
        clean = getattr(self._api, 'clean_warn', None)
        if clean is not None:
            self._call('clean_warn')

    def _check_status_if_due(self) -> None:
        last = self._last_status_t
        if last is None or self._clock() - last >= self._cfg.status_period_s:
            self._refuse_if_controller_error(while_moving=True)

    def _subscribe_reports(self, api: Any) -> None:
        register = getattr(api, 'register_report_location_callback', None)
        self._streaming = False
        if register is None:
            return
        try:
            ok = register(self._on_report, report_cartesian=True, report_joints=False)
        except Exception as exc:  # noqa: BLE001 - no stream: poses are queried instead
            _LOG.warning('xArm report stream unavailable (%s); polling the pose', exc)
            return
        self._streaming = ok is not False

    def _on_report(self, data: Any) -> None:
        """SDK report thread: keep the newest valid pose and hand it on."""
        t, wall = self._clock(), time.time_ns()
        try:
            values = np.asarray(data['cartesian'], dtype=np.float64).reshape(-1)
            if values.shape[0] < 6 or not np.all(np.isfinite(values[:6])):
                raise ValueError(f'invalid pose {values.tolist()}')
            pose = self._pose_from_sdk(values)
        except (KeyError, TypeError, ValueError):
            self.reports_rejected += 1
            return
        with self._report_lock:
            self._report = (pose, t, wall)
            listener = self._pose_listener
        if listener is not None:
            listener(pose.copy(), t, wall)

    def _fresh_report(self) -> Optional[np.ndarray]:
        with self._report_lock:
            report = self._report
        if report is None or self._clock() - report[1] > self._cfg.report_max_age_s:
            return None
        return report[0]

    def _check_firmware(self) -> None:
        version = tuple(getattr(self._api, 'version_number', ()) or ())
        if len(version) < 3 or tuple(int(x) for x in version[:3]) < MIN_FIRMWARE_FOR_DURATION:
            raise XArmError(f'xArm firmware {version} cannot honour the velocity command '
                            f'duration (needs >= {MIN_FIRMWARE_FOR_DURATION}); refusing')

    def _call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        """Call an SDK method and check its code; on failure stop and raise."""
        try:
            ret = getattr(self._api, name)(*args, **kwargs)
        except Exception as exc:  # noqa: BLE001 - the SDK should not raise; if it does, stop
            self._stop_quietly()
            raise XArmError(f'xArm {name} raised {exc!r}; stopped') from exc
        code = _code_of(ret)
        if code != 0:
            self._stop_quietly()
            message = f'xArm {name} failed with code {code} ({describe_code(code)})'
            controller_error = None
            if code == 1:
                controller_error = self._controller_error()
                if controller_error:
                    message += (f'; controller error {controller_error}: '
                                f'{_controller_error_text(controller_error)}')
            raise XArmError(message + '; stopped', code=code, controller_error=controller_error)
        return ret

    def _call_get(self, name: str, *args: Any, **kwargs: Any) -> Tuple[int, Any]:
        ret = self._call(name, *args, **kwargs)
        if not isinstance(ret, (tuple, list)) or len(ret) < 2:
            self._stop_quietly()
            raise XArmError(f'xArm {name} returned {ret!r}, expected (code, data)')
        return int(ret[0]), ret[1]

    def _controller_error(self) -> Optional[int]:
        try:
            ret = self._api.get_err_warn_code()
            if _code_of(ret) in (0, 1) and ret[1]:
                return int(ret[1][0])
        except Exception:  # noqa: BLE001 - only used to enrich an error message
            pass
        return None

    def _stop_quietly(self) -> None:
        try:
            self.stop()
        except Exception as exc:  # noqa: BLE001 - already reporting a worse error
            _LOG.error('xArm stop after an error failed too: %s', exc)

    def _disconnect_quietly(self) -> None:
        api, self._api = self._api, None
        self._enabled = False
        with self._report_lock:
            self._report = None
        if api is None:
            return
        if self._streaming:
            self._streaming = False
            try:
                api.release_report_location_callback(self._on_report)
            except Exception as exc:  # noqa: BLE001 - the connection goes anyway
                _LOG.debug('releasing the report callback raised %s', exc)
        try:
            with _timeout_restored():
                api.disconnect()
        except Exception as exc:  # noqa: BLE001 - nothing more can be done
            _LOG.warning('xArm disconnect raised %s', exc)

    def _to_pose(self, pos: Sequence[float]) -> np.ndarray:
        values = np.asarray(pos, dtype=np.float64).reshape(-1)
        if values.shape[0] < 6 or not np.all(np.isfinite(values[:6])):
            self._stop_quietly()
            raise XArmError(f'xArm returned an invalid pose {pos!r}; stopped')
        return self._pose_from_sdk(values)

    @staticmethod
    def _pose_from_sdk(values: np.ndarray) -> np.ndarray:
        # The SDK's roll/pitch/yaw are fixed-axis x-y-z angles, scipy's lowercase 'xyz'.
        quat = Rotation.from_euler('xyz', values[3:6]).as_quat()
        return np.concatenate([values[:3] / 1000.0, quat])
