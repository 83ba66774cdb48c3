"""`make setup` (scripts/setup.sh) rebuilds an install that no longer belongs to the checkout.

The colcon install is a tree of symlinks into ``.colcon/src`` (a link to the checkout).
After ``.colcon/`` is removed, or the checkout is moved, its build key still matches while
its links dangle or point at the old place; setup must notice and rebuild. Built in a
temporary copy of the checkout (sharing the venv, which setup leaves untouched there), so
the install other tests use is never touched.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import ROOT

pytestmark = [pytest.mark.slow, pytest.mark.ros, pytest.mark.install]


def _copy_checkout(dst: Path) -> None:
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                           capture_output=True, check=True).stdout.decode().split("\0")
    for rel in filter(None, files):
        src = ROOT / rel
        if not src.exists() and not src.is_symlink():
            continue                       # deleted in the working tree
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, target, follow_symlinks=False)
    (dst / ".venv").symlink_to(ROOT / ".venv")


def _env() -> dict:
    # ASLIP_DRIVER_MSGS too: the copy builds without the drivers' optional messages.
    drop = ("PYTHONPATH", "AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH", "COLCON_PREFIX_PATH",
            "ASLIP_DRIVER_MSGS")
    return {k: v for k, v in os.environ.items() if k not in drop}


def _setup(checkout: Path) -> str:
    out = subprocess.run(["bash", "scripts/setup.sh"], cwd=checkout, env=_env(),
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout + out.stderr
    return out.stdout


def _installed_package(checkout: Path) -> subprocess.CompletedProcess:
    """Import aslip_ros through the checkout's install, as `aslip` and the nodes do."""
    return subprocess.run(
        ["bash", "-c", "source install/setup.bash && cd / && .venv_py -c "
         "'import os, aslip_ros; from aslip_ros import __version__; "
         "print(os.path.realpath(aslip_ros.__file__))'".replace(
             ".venv_py", str(checkout / ".venv" / "bin" / "python"))],
        cwd=checkout, env=_env(), capture_output=True, text=True, timeout=120)


def test_setup_rebuilds_a_stale_install(tmp_path):
    first = tmp_path / "first"
    _copy_checkout(first)
    assert "building" in _setup(first)
    ok = _installed_package(first)
    own = str((first / "aslip_ros" / "__init__.py").resolve())
    assert ok.returncode == 0 and ok.stdout.strip() == own, ok.stdout + ok.stderr

    # .colcon/ cleaned and the build interrupted: the install's links dangle, its package
    # is gone (setup.bash left), and the checkout's package is no longer what imports.
    # (Without the package, setup used to exit 1 without a word, at its check of the
    # install.)
    shutil.rmtree(first / ".colcon")
    for package in (first / "install" / "lib").glob("python3*/site-packages/aslip_ros"):
        shutil.rmtree(package)
    assert (first / "install" / "setup.bash").is_file()
    gone = _installed_package(first)
    assert gone.returncode != 0 or gone.stdout.strip() != own, gone.stdout
    out = _setup(first)
    assert "stale" in out and "building" in out, out
    ok = _installed_package(first)
    assert ok.returncode == 0 and ok.stdout.strip() == own, ok.stdout + ok.stderr

    # The checkout moved: the links name the old place.
    moved = tmp_path / "moved"
    first.rename(moved)
    out = _setup(moved)
    assert "stale" in out and "building" in out, out
    ok = _installed_package(moved)
    assert ok.returncode == 0 and ok.stdout.strip() == \
        str((moved / "aslip_ros" / "__init__.py").resolve()), ok.stdout + ok.stderr

    # Nothing stale: setup does not rebuild.
    assert "building" not in _setup(moved)

    # The node table changed (CMake installs its executables from it): setup rebuilds.
    table = moved / "aslip_ros" / "node_table.py"
    table.write_text(table.read_text() + "\n# a row changed\n")
    assert "building" in _setup(moved)
