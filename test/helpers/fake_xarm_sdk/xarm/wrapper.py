"""Fake ``xarm.wrapper.XArmAPI``: the subset of xarm-python-sdk's API that
aslip_ros/hw/xarm_driver.py uses, each call forwarded as one JSON line to the fake
controller served by ``test/helpers/hw_rig.py`` (127.0.0.1, port ``ASLIP_FAKE_XARM_PORT``).

Stands in for: the SDK object, its TCP connection to the controller, its return-code
conventions (an int code, or ``(code, data)`` for getters; ``-1`` when not connected; never
an exception), ``connected``/``mode``/``state``/``version_number``, and the report stream
(``register_report_location_callback``: a thread calls the callback with
``{'cartesian': [x, y, z (mm), roll, pitch, yaw (rad)]}`` at the rig's TCP rate).

Does not model: the SDK's binary protocol, ports 502/30001-30003, ``socket.setdefaulttimeout``
side effect, its stdout logging, joint-space calls, degrees anywhere except
``get_position(is_radian=False)``, the command cache or any method not listed here (they
raise AttributeError, so an adapter that starts using one fails loudly).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import socket
import threading
from typing import Any, Callable, List, Optional

NOT_CONNECTED = -1
REPLY_TIMEOUT = 3


class _Link:
    """One JSON-lines TCP connection to the rig (request/answer, serialised)."""

    def __init__(self, host: str, port: int, timeout_s: float) -> None:
        self.sock = socket.create_connection((host, port), timeout=timeout_s)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.file = self.sock.makefile("rb")
        self.lock = threading.Lock()
        self.ids = itertools.count(1)

    def call(self, op: str, *args: Any, **kwargs: Any) -> Any:
        with self.lock:
            rid = next(self.ids)
            line = json.dumps({"id": rid, "op": op, "args": list(args), "kwargs": kwargs})
            self.sock.sendall(line.encode() + b"\n")
            answer = self.file.readline()
        if not answer:
            raise ConnectionError("fake xArm controller closed the connection")
        reply = json.loads(answer)
        if reply.get("id") != rid:
            raise ConnectionError(f"reply {reply.get('id')} to request {rid}")
        if "error" in reply:
            raise ConnectionError(reply["error"])
        return reply["ret"]

    def close(self) -> None:
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()


class XArmAPI:
    """Fake of the SDK's ``XArmAPI`` (see the module docstring for what it models)."""

    def __init__(self, port: Optional[str] = None, is_radian: bool = False,
                 do_not_open: bool = False, **kwargs: Any) -> None:
        self._ip = port
        self._is_radian = bool(is_radian)
        self._kwargs = kwargs
        self._link: Optional[_Link] = None
        self._version_number: tuple = ()
        self._mode = 0
        self._state = 4
        self._report_cbs: List[Callable] = []
        self._report_thread: Optional[threading.Thread] = None
        self._report_link: Optional[_Link] = None
        self._report_stop = threading.Event()
        self._cb_lock = threading.Lock()
        if not do_not_open:
            self.connect()

    # -- connection -------------------------------------------------------------------------

    @staticmethod
    def _port() -> Optional[int]:
        try:
            return int(os.environ["ASLIP_FAKE_XARM_PORT"])
        except (KeyError, ValueError):
            return None

    def connect(self, port: Optional[str] = None, **kwargs: Any) -> None:
        """Open the connection (the real SDK logs a failure and stays unconnected)."""
        if self._link is not None:
            return
        rig_port = self._port()
        if rig_port is None:
            return
        try:
            link = _Link("127.0.0.1", rig_port, 5.0)
            hello = link.call("connect", ip=port or self._ip, **self._kwargs)
        except (OSError, ValueError, ConnectionError):
            return
        self._version_number = tuple(hello.get("version_number", ()))
        self._mode, self._state = hello.get("mode", 0), hello.get("state", 4)
        self._link = link

    def disconnect(self) -> None:
        """Close the connection (and the report stream)."""
        self._stop_reports()
        link, self._link = self._link, None
        if link is not None:
            try:
                link.call("disconnect")
            except (OSError, ValueError, ConnectionError):
                pass
            link.close()

    @property
    def connected(self) -> bool:
        return self._link is not None

    @property
    def version_number(self) -> tuple:
        return self._version_number

    @property
    def version(self) -> str:
        return "v" + ".".join(str(x) for x in self._version_number)

    @property
    def mode(self) -> int:
        return self._mode

    @property
    def state(self) -> int:
        return self._state

    def _call(self, op: str, *args: Any, **kwargs: Any) -> Any:
        link = self._link
        if link is None:
            return NOT_CONNECTED
        try:
            out = link.call(op, *args, **kwargs)
        except (OSError, ValueError, ConnectionError):
            self._link = None
            return REPLY_TIMEOUT
        if isinstance(out, dict):
            self._mode, self._state = out.get("mode", self._mode), out.get("state", self._state)
            ret = out["ret"]
            return tuple(ret) if isinstance(ret, list) else ret
        return out

    def _get(self, op: str, *args: Any, **kwargs: Any) -> tuple:
        ret = self._call(op, *args, **kwargs)
        return ret if isinstance(ret, tuple) else (ret, None)

    # -- the calls the adapter makes ----------------------------------------------------------

    def motion_enable(self, enable: bool = True, servo_id: Optional[int] = None) -> int:
        return self._call("motion_enable", enable=bool(enable), servo_id=servo_id)

    def set_mode(self, mode: int = 0, detection_param: int = 0) -> int:
        return self._call("set_mode", int(mode), detection_param=detection_param)

    def set_state(self, state: int = 0) -> int:
        return self._call("set_state", int(state))

    def vc_set_cartesian_velocity(self, speeds, is_radian: Optional[bool] = None,
                                  is_tool_coord: bool = False, duration: float = -1,
                                  **kwargs: Any) -> int:
        return self._call("vc_set_cartesian_velocity", [float(s) for s in speeds],
                          is_radian=self._is_radian if is_radian is None else bool(is_radian),
                          is_tool_coord=bool(is_tool_coord), duration=float(duration))

    def get_position(self, is_radian: Optional[bool] = None) -> tuple:
        code, pos = self._get("get_position")
        radian = self._is_radian if is_radian is None else bool(is_radian)
        if pos is not None and not radian:
            pos = list(pos[:3]) + [math.degrees(a) for a in pos[3:6]]
        return code, pos

    def get_err_warn_code(self, show: bool = False, lang: str = "en") -> tuple:
        return self._get("get_err_warn_code")

    def clean_warn(self) -> int:
        return self._call("clean_warn")

    def clean_error(self) -> int:
        return self._call("clean_error")

    # -- report stream ----------------------------------------------------------------------

    def register_report_location_callback(self, callback: Optional[Callable] = None,
                                          report_cartesian: bool = True,
                                          report_joints: bool = True) -> bool:
        """Deliver ``{'cartesian': [...]}`` reports to ``callback`` on a report thread."""
        if callback is None or self._link is None:
            return False
        self._call("register_report_location_callback", report_cartesian=report_cartesian,
                   report_joints=report_joints)
        with self._cb_lock:
            if callback not in self._report_cbs:
                self._report_cbs.append(callback)
        if self._report_thread is None:
            try:
                self._report_link = _Link("127.0.0.1", self._port(), 5.0)
                self._report_link.sock.settimeout(None)
                self._report_link.call("subscribe_reports")
            except (OSError, ValueError, ConnectionError, TypeError):
                self._report_link = None
                return False
            self._report_stop.clear()
            self._report_thread = threading.Thread(target=self._reports, name="xarm-report",
                                                   daemon=True)
            self._report_thread.start()
        return True

    def release_report_location_callback(self, callback: Optional[Callable] = None) -> bool:
        with self._cb_lock:
            if callback is None:
                self._report_cbs.clear()
            elif callback in self._report_cbs:
                self._report_cbs.remove(callback)
            empty = not self._report_cbs
        self._call("release_report_location_callback")
        if empty:
            self._stop_reports()
        return True

    def _reports(self) -> None:
        link = self._report_link
        while link is not None and not self._report_stop.is_set():
            try:
                line = link.file.readline()
            except (OSError, ValueError):
                return
            if not line:
                return
            try:
                report = json.loads(line)["report"]
            except (ValueError, KeyError, TypeError):
                continue
            with self._cb_lock:
                cbs = list(self._report_cbs)
            for cb in cbs:
                try:
                    cb(dict(report))
                except Exception:  # noqa: BLE001 - the SDK swallows callback errors too
                    pass

    def _stop_reports(self) -> None:
        self._report_stop.set()
        link, self._report_link = self._report_link, None
        if link is not None:
            link.close()
        thread, self._report_thread = self._report_thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(2.0)
