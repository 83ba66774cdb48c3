"""The layers of docs/design.md, checked on the import graph: every import of a package
module points down (or sideways on its floor), and rclpy stays on the ROS floor. Each
contract is defined once: topic and frame names appear as literals only in their module."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "aslip_ros"
#: The floors of docs/design.md, "Layers", by first name below aslip_ros.
FLOOR = {"cli": 4, "nodes": 3, "experiments": 3, "bringup": 3, "learn": 2, "hw": 2, "scene": 1,
         "cell": 0,
         "data": 1, "control": 1, "util": 0, "frames": 0, "poses": 0, "topics": 0,
         "audio_frame": 0, "plugin": 0, "slip": 0, "msg": 0, "__init__": 0, "__main__": 4}
ROS_FLOOR = 3


def _modules():
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(ROOT).with_suffix("").parts
        yield p, ".".join(rel[:-1] if rel[-1] == "__init__" else rel)


def _imports(path: Path, mod: str):
    """(imported module, line) for every import in ``path``, at any depth (lazy ones too)."""
    pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    for n in ast.walk(ast.parse(path.read_text())):
        if isinstance(n, ast.ImportFrom):
            if n.level:
                base = pkg.split(".")[:len(pkg.split(".")) - (n.level - 1)]
                target = ".".join(base + ([n.module] if n.module else []))
            else:
                target = n.module or ""
            yield target, n.lineno
        elif isinstance(n, ast.Import):
            for a in n.names:
                yield a.name, n.lineno


def _floor(mod: str) -> int:
    parts = mod.split(".")
    name = parts[1] if len(parts) > 1 else "__init__"
    assert name in FLOOR, f"{mod}: not on any floor of docs/design.md; add it there and here"
    return FLOOR[name]


def test_every_import_points_down():
    up = []
    for path, mod in _modules():
        for target, line in _imports(path, mod):
            if target.startswith("aslip_ros.") and _floor(target) > _floor(mod):
                up.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert not up, "\n".join(up)


def test_rclpy_only_on_the_ros_floor():
    found = [f"{path.relative_to(ROOT)}:{line}"
             for path, mod in _modules() if _floor(mod) < ROS_FLOOR
             for target, line in _imports(path, mod) if target.split(".")[0] == "rclpy"]
    assert not found, found


@pytest.mark.parametrize("home,pattern", [
    ("topics.py", r'"/(aslip|tf|tf_static|diagnostics)\b[^"]*"'),
    ("frames.py", r'"(world|link_base|aslip_(tcp|finger|object|grasp_plane|gripper))"'),
])
def test_a_name_contract_is_written_once(home, pattern):
    rx = re.compile(pattern)
    elsewhere = [f"{p.relative_to(ROOT)}:{i}" for p, _ in _modules() if p.name != home
                 for i, line in enumerate(p.read_text().splitlines(), 1)
                 if rx.search(line.split("#")[0])]
    assert not elsewhere, elsewhere


def test_the_check_sees_an_upward_import(tmp_path):
    """The graph check itself: a data module importing learn would be reported."""
    p = tmp_path / "x.py"
    p.write_text("def f():\n    from aslip_ros.learn import train\n")
    targets = [t for t, _ in _imports(p, "aslip_ros.data.x")]
    assert targets == ["aslip_ros.learn"]
    assert _floor(targets[0]) > _floor("aslip_ros.data.x")


#: Size limits of a module and a function [lines]; beyond them the docstring must say why
#: (and use the word "lines" when it does).
MAX_FILE_LINES, MAX_FUNCTION_LINES = 450, 80


def _oversized(path: Path, name: str) -> list:
    src = path.read_text()
    tree = ast.parse(src)
    out = []
    n_lines = src.count("\n")
    if n_lines > MAX_FILE_LINES and "lines" not in (ast.get_docstring(tree) or ""):
        out.append(f"{name}: {n_lines} lines")
    for n in ast.walk(tree):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = n.end_lineno - n.lineno + 1
            if length > MAX_FUNCTION_LINES and "lines" not in (ast.get_docstring(n) or ""):
                out.append(f"{name}:{n.lineno} {n.name}: {length} lines")
    return out


def test_modules_and_functions_a_reader_can_hold_in_their_head():
    found = [x for p, _ in _modules() for x in _oversized(p, str(p.relative_to(ROOT)))]
    assert not found, found


def test_the_size_check_sees_a_long_function_unless_it_says_why(tmp_path):
    p = tmp_path / "long.py"
    body = "    x = 1\n" * 90
    p.write_text("def f():\n" + body)
    assert _oversized(p, "long.py") == ["long.py:1 f: 91 lines"]
    p.write_text('def f():\n    """One table of 90 lines: kept whole."""\n' + body)
    assert _oversized(p, "long.py") == []
