"""xarm-python-sdk, contained: imported once without printing on stdout, its loggers routed
through :mod:`logging`, its process-wide socket timeout undone, its return codes read.
"""

from __future__ import annotations

import contextlib
import io
import logging
import socket
import threading
from typing import Any

_SDK_LOG = logging.getLogger('aslip_ros.hw.xarm.sdk')
_import_lock = threading.Lock()
_sdk_api_class: Any = None


class _ForwardToLogging(logging.Handler):
    """Re-emits the SDK's log records on this package's logger (stderr / the ROS logger)."""

    def emit(self, record: logging.LogRecord) -> None:
        """Forward one record."""
        try:
            _SDK_LOG.log(record.levelno, '%s', record.getMessage())
        except Exception:  # noqa: BLE001 - logging must never raise into the SDK
            self.handleError(record)


def _route_sdk_logging() -> None:
    """Send the SDK's loggers through :mod:`logging` instead of raw ``sys.stdout``.

    The SDK binds ``StreamHandler(sys.stdout)`` to two loggers at import; stdout may carry
    a protocol (a launch file, a piped tool) and must stay ours.
    """
    try:
        from xarm.core.utils import log as sdk_log
    except Exception:  # noqa: BLE001 - a layout change must not stop the arm from working
        return
    for sdk_logger in (getattr(sdk_log, 'logger', None), getattr(sdk_log, 'origin_logger', None)):
        if not isinstance(sdk_logger, logging.Logger):
            continue
        for handler in list(sdk_logger.handlers):
            if type(handler) is logging.StreamHandler:
                sdk_logger.removeHandler(handler)
        if not any(isinstance(h, _ForwardToLogging) for h in sdk_logger.handlers):
            sdk_logger.addHandler(_ForwardToLogging())
        sdk_logger.propagate = False


def _import_sdk() -> Any:
    """Import ``XArmAPI`` once, containing the import's side effects.

    Importing prints the SDK version to stdout (captured here and logged at debug level)
    and installs stdout log handlers (rerouted by :func:`_route_sdk_logging`). It also
    creates ``~/.UFACTORY/log``, which cannot be avoided.
    """
    global _sdk_api_class
    with _import_lock:
        if _sdk_api_class is None:
            captured = io.StringIO()
            with contextlib.redirect_stdout(captured):
                from xarm.wrapper import XArmAPI
            _route_sdk_logging()
            text = captured.getvalue().strip()
            if text:
                _SDK_LOG.debug('%s', text)
            _sdk_api_class = XArmAPI
        return _sdk_api_class


@contextlib.contextmanager
def socket_default_timeout_restored():
    """Undo the SDK's ``socket.setdefaulttimeout(1)``, which it calls for every connection.

    Left in place, every later socket in the process (DDS helpers, HTTP clients) would
    silently get a 1 s timeout.
    """
    saved = socket.getdefaulttimeout()
    try:
        yield
    finally:
        socket.setdefaulttimeout(saved)


def default_api_factory(ip: str) -> Any:
    """Create an unconnected ``XArmAPI`` (``do_not_open=True``; radians by default).

    ``report_type='real'`` asks for the controller's real-time report stream (port 30003),
    the fastest of the SDK's three; its location reports feed the adapter's pose.
    """
    api_class = _import_sdk()
    with socket_default_timeout_restored():
        return api_class(ip, is_radian=True, do_not_open=True, report_type='real')


def code_of(ret: Any) -> int:
    """The return code of an SDK call: an int, or the first item of ``(code, data)``."""
    if isinstance(ret, (tuple, list)):
        ret = ret[0]
    if ret is None:
        # Some SDK calls return None when they did nothing; treat it as success only if
        # the call is documented to do so, which none of the ones used here is.
        return -3
    return int(ret)


class ConnectTimeout(Exception):
    """The SDK's connect did not return in time (an SDK socket timeout is not this)."""


def connect_within(api: Any, timeout_s: float) -> None:
    """``api.connect()`` within ``timeout_s``: :class:`ConnectTimeout` after it, or what
    ``connect`` raised.

    The SDK's connect blocks on sockets and version queries; a daemon thread with a deadline
    turns "unreachable" into an error instead of a hung caller. A connection that succeeds
    after the caller gave up is closed again, never left behind.
    """
    outcome: dict = {}
    handover = threading.Lock()   # decides atomically who owns the connection

    def worker() -> None:
        try:
            with socket_default_timeout_restored():
                api.connect()
            ok = True
        except BaseException as exc:  # noqa: BLE001 - reported to the caller
            outcome['error'] = exc
            ok = False
        with handover:
            outcome['done'] = True
            abandoned = outcome.get('abandoned', False)
        if ok and abandoned:
            try:
                with socket_default_timeout_restored():
                    api.disconnect()
            except Exception:  # noqa: BLE001 - nobody left to report to
                pass

    t = threading.Thread(target=worker, name='xarm-connect', daemon=True)
    t.start()
    t.join(timeout_s)
    with handover:
        finished = outcome.get('done', False)
        if not finished:
            outcome['abandoned'] = True
    if not finished:
        raise ConnectTimeout(f'no answer within {timeout_s:g} s')
    if 'error' in outcome:
        raise outcome['error']
