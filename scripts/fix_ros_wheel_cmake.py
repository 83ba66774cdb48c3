"""Point the ROS message wheels' CMake exports at this Python's own include directories.

The ROS 2 message wheels on PyPI are built in manylinux containers, and their
``share/<pkg>/cmake/*Export.cmake`` files keep that container's include directories, e.g.
``/opt/python/cp311-cp311/include/python3.11`` and
``/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include`` (``cp312`` and
``python3.12`` for the 3.12 wheels). CMake then refuses any package whose messages depend on
them ("includes non-existent path"). This rewrites every such path, whatever the CPython
version in it, to the given prefix's Python and numpy include directories. Idempotent: a
rewritten file has no container path left.

usage: python fix_ros_wheel_cmake.py PREFIX PYTHON_INCLUDE NUMPY_INCLUDE
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

#: The wheel builder's interpreter root: /opt/python/cp312-cp312 (also cp313t-cp313t).
_BUILDER = r"/opt/python/cp3\d+[a-z]*-cp3\d+[a-z]*"
#: numpy's headers inside the builder's site-packages (numpy 2: _core; numpy 1: core).
NUMPY = re.compile(_BUILDER + r"/lib/python3\.\d+[a-z]*/site-packages/numpy/_?core/include")
#: The builder's Python headers.
PYTHON = re.compile(_BUILDER + r"/include/python3\.\d+[a-z]*")


def rewrite(text: str, python_include: str, numpy_include: str) -> str:
    """``text`` with the builder's numpy and Python include directories replaced."""
    text = NUMPY.sub(lambda _: numpy_include, text)     # first: it contains no PYTHON match,
    return PYTHON.sub(lambda _: python_include, text)   # but keep the order explicit


def fix(prefix: Path, python_include: str, numpy_include: str) -> list:
    """Rewrite every ``PREFIX/share/*/cmake/*Export.cmake`` that names the builder's paths;
    return the files changed."""
    changed = []
    for path in sorted(prefix.glob("share/*/cmake/*Export.cmake")):
        text = path.read_text()
        new = rewrite(text, python_include, numpy_include)
        if new != text:
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(new)
            tmp.replace(path)
            changed.append(path)
    return changed


def main(argv: list) -> int:
    if len(argv) != 3:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    prefix, python_include, numpy_include = argv
    for name, folder in (("Python", python_include), ("numpy", numpy_include)):
        if not Path(folder).is_dir():
            print(f"fix_ros_wheel_cmake: no {name} include directory {folder}", file=sys.stderr)
            return 1
    changed = fix(Path(prefix), python_include, numpy_include)
    print(f"fix_ros_wheel_cmake: {len(changed)} CMake export file(s) rewritten in {prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
