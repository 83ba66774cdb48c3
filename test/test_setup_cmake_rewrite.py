"""scripts/fix_ros_wheel_cmake.py: the ROS message wheels' CMake exports, on any CPython.

`make setup` (and CI's stand-in for /opt/ros/jazzy) rewrites the wheel builder's include
directories in ``share/*/cmake/*Export.cmake``. It named CPython 3.11's paths only, so a venv
of Ubuntu 24.04's CPython 3.12 kept ``/opt/python/cp312-cp312/...`` and CMake refused to build
the package's messages. Here on a 3.12 layout (the files as the cp312 wheels ship them).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from conftest import ROOT

SCRIPT = ROOT / "scripts" / "fix_ros_wheel_cmake.py"

#: As in ros-std-msgs' cp312 wheel: the builder's numpy and Python headers, beside
#: include directories that must stay as they are.
EXPORT = """\
set_target_properties(std_msgs::std_msgs__rosidl_generator_py PROPERTIES
  INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp312-cp312/lib/python3.12/site-packages/\
numpy/_core/include;/opt/python/cp312-cp312/include/python3.12;${_IMPORT_PREFIX}/include/std_msgs"
)
"""


def _layout(prefix: Path) -> tuple:
    for pkg in ("std_msgs", "geometry_msgs"):
        cmake = prefix / "share" / pkg / "cmake"
        cmake.mkdir(parents=True)
        (cmake / f"export_{pkg}__rosidl_generator_pyExport.cmake").write_text(
            EXPORT.replace("std_msgs", pkg))
        (cmake / f"{pkg}Config.cmake").write_text("# not an export: left alone\n"
                                                  "# /opt/python/cp312-cp312/include/python3.12\n")
    py_inc = prefix / "include" / "python3.12"
    np_inc = prefix / "lib" / "python3.12" / "site-packages" / "numpy" / "_core" / "include"
    for folder in (py_inc, np_inc):
        folder.mkdir(parents=True)
    return str(py_inc), str(np_inc)


def _run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True,
                          text=True, timeout=60)


def test_a_cpython_312_layout_is_pointed_at_the_venvs_own_headers(tmp_path):
    py_inc, np_inc = _layout(tmp_path)
    out = _run(tmp_path, py_inc, np_inc)
    assert out.returncode == 0, out.stderr
    assert "2 CMake export file(s) rewritten" in out.stdout
    for pkg in ("std_msgs", "geometry_msgs"):
        text = next((tmp_path / "share" / pkg / "cmake").glob("*Export.cmake")).read_text()
        assert "/opt/python" not in text
        dirs = text.split('"')[1].split(";")
        assert dirs == [np_inc, py_inc, "${_IMPORT_PREFIX}/include/" + pkg]
        config = (tmp_path / "share" / pkg / "cmake" / f"{pkg}Config.cmake").read_text()
        assert "/opt/python/cp312-cp312" in config        # only the exports are rewritten


def test_the_rewrite_is_idempotent_and_names_no_version(tmp_path):
    py_inc, np_inc = _layout(tmp_path)
    assert _run(tmp_path, py_inc, np_inc).returncode == 0
    again = _run(tmp_path, py_inc, np_inc)
    assert again.returncode == 0 and "0 CMake export file(s) rewritten" in again.stdout
    # scripts/setup.sh has no version of its own in its rewrite: it calls this script.
    setup = (ROOT / "scripts" / "setup.sh").read_text()
    assert "cp311" not in setup and "fix_ros_wheel_cmake.py" in setup


def test_cpython_311_and_numpy_1_paths_too():
    from importlib.util import module_from_spec, spec_from_file_location

    spec = spec_from_file_location("fix_ros_wheel_cmake", SCRIPT)
    mod = module_from_spec(spec)
    spec.loader.exec_module(mod)
    text = ("/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/core/include;"
            "/opt/python/cp311-cp311/include/python3.11;/opt/python/cp313t-cp313t/include/"
            "python3.13t")
    assert mod.rewrite(text, "PY", "NP") == "NP;PY;PY"


def test_a_missing_include_directory_is_a_clear_error(tmp_path):
    out = _run(tmp_path, tmp_path / "nope", tmp_path)
    assert out.returncode == 1 and "no Python include directory" in out.stderr
