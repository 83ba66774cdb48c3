"""Shared pytest fixtures.

ROS tests are isolated: every test that touches DDS gets its own ROS_DOMAIN_ID, reserved
through ``domain_coordinator`` so parallel test runs and other ROS processes on this
machine cannot make a test pass or fail, and discovery stays on localhost.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
HELPERS = HERE / "helpers"

# The benchmarks (benchmarks/, not installed) import from the checkout: its root goes LAST on
# sys.path, so `aslip_ros` still resolves to the colcon install (with the generated messages)
# and never to the source tree at the root.
if str(ROOT) not in sys.path:
    sys.path.append(str(ROOT))

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

# A suite started in the background of a non-interactive shell (`make test &`, nohup, some
# CI runners) inherits SIGINT and SIGQUIT ignored, and so would every process it starts.
# `ros2 launch` installs no SIGINT handler of its own (it relies on Python's, which Python
# does not install over an inherited SIG_IGN): a launch started that way never hears the
# SIGINT a test sends it and runs until killed. The suite's children start as from a
# terminal instead (exec resets a handled signal to its default).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
if signal.getsignal(signal.SIGQUIT) is signal.SIG_IGN:
    signal.signal(signal.SIGQUIT, signal.SIG_DFL)
os.environ.setdefault("OMP_NUM_THREADS", "1")


def _ros_available() -> str | None:
    """Return None when rclpy and the built messages import, else the reason."""
    try:
        if importlib.util.find_spec("rclpy") is None:
            return "rclpy is not installed"
        import aslip_ros.msg  # noqa: F401
    except Exception as exc:  # noqa: BLE001 - any import failure means "not built"
        return f"aslip_ros messages are not built/sourced ({exc})"
    return None


#: Words in a test module's source that mean its tests start processes.
STARTS_PROCESSES = ("NodeProcess", "subprocess", "Popen", "multiprocessing")


def starts_processes(item, _seen: dict = {}) -> bool:  # noqa: B006 - a per-session cache
    """Whether ``item`` starts processes: a launch test, a test with the child-process
    environment (``ros_env``), or a test in a module whose code starts processes."""
    if type(item).__name__ in ("LaunchTestItem", "LaunchROSTestItem") or \
            "ros_env" in getattr(item, "fixturenames", ()):
        return True
    path = Path(str(item.path))
    if path not in _seen:
        try:
            text = path.read_text()
        except OSError:
            text = ""
        _seen[path] = any(word in text for word in STARTS_PROCESSES)
    return _seen[path]


def pytest_collection_modifyitems(config, items):
    # The `processes` tier (pytest -m processes; scripts/flake_hunt.py runs it under load):
    # marked here, from what the tests do, so no test that starts a process is left out.
    for item in items:
        if starts_processes(item):
            item.add_marker(pytest.mark.processes)
    _launch_case().skip_unlaunched(config, items)
    reason = _ros_available()
    if reason is None:
        return
    if os.environ.get("ASLIP_REQUIRE_ROS") == "1":
        raise pytest.UsageError(f"ROS tests required but unavailable: {reason}")
    skip = pytest.mark.skip(reason=reason + "; run `make test`")
    for item in items:
        if "ros" in item.keywords:
            item.add_marker(skip)


def _launch_case():
    """test/launch/launch_case.py (it decides how launch tests are skipped)."""
    name = "launch_case"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, HERE / "launch" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


@pytest.fixture
def ros_domain():
    """A ROS_DOMAIN_ID reserved for this test alone."""
    from domain_coordinator import domain_id

    with domain_id() as did:
        yield did


@pytest.fixture
def ros_env(ros_domain):
    """Environment for child node processes: the full parent environment (the ROS wheels'
    bootstrap needs it), an isolated domain, localhost-only discovery, unbuffered output."""
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(ros_domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join(
        [str(HELPERS)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    return env


@pytest.fixture
def rclpy_context(ros_domain):
    """An rclpy context of its own on the test's isolated domain."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


def json_lines(path: Path, event: str | None = None) -> list[dict]:
    """The documents of a JSON-lines file a stand-in writes (the rig's calls log and status
    file), those whose ``event`` is ``event`` where given; none while it does not exist."""
    if not path.exists():
        return []
    docs = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    return [d for d in docs if event is None or d.get("event") == event]


@pytest.fixture
def python_exe() -> str:
    return sys.executable
