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
FLOOR = {"cli": 4, "nodes": 3, "bringup": 3, "learn": 2, "hw": 2, "scene": 1,
         "cell": 0,
         "data": 1, "control": 1, "util": 0, "frames": 0, "poses": 0, "topics": 0,
         "audio_frame": 0, "rigid_bodies": 0, "lag": 0, "plugin": 0, "slip": 0, "msg": 0,
         "__init__": 0,
         "__main__": 4}
ROS_FLOOR = 3


def _modules(*roots: Path):
    for p in sorted(q for r in (roots or (PKG,)) for q in r.rglob("*.py")):
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


def test_the_package_never_depends_on_the_benchmarks():
    """benchmarks/ (top level, docs/design.md) imports the package, never the reverse, and is
    not inside it: what a user-facing command needs moves into the package."""
    found = [f"{path.relative_to(ROOT)}:{line} imports {target}"
             for path, mod in _modules() for target, line in _imports(path, mod)
             if target.split(".")[0] == "benchmarks"]
    # ... nor by name (importlib, a subcommand table).
    found += [f"{path.relative_to(ROOT)}:{n.lineno} names {n.value!r}"
              for path, _ in _modules() for n in ast.walk(ast.parse(path.read_text()))
              if isinstance(n, ast.Constant) and isinstance(n.value, str)
              and re.match(r"benchmarks(\.|$)", n.value)]
    assert not found, found
    assert (ROOT / "benchmarks" / "__init__.py").is_file()
    assert not [p for p in PKG.rglob("*") if p.name in ("benchmarks", "experiments")]


def test_rclpy_only_on_the_ros_floor():
    found = [f"{path.relative_to(ROOT)}:{line}"
             for path, mod in _modules() if _floor(mod) < ROS_FLOOR
             for target, line in _imports(path, mod) if target.split(".")[0] == "rclpy"]
    assert not found, found


#: Topic and frame names: as a Python string literal, and as a YAML value (quoted or not;
#: a name inside another, like a driver's ``/vrpn/aslip_finger/pose``, is not one).
NAMES = {
    "topics.py": (r'"/(aslip|tf|tf_static|diagnostics)\b[^"]*"',
                  r'(?<![\w/])/(aslip|tf|tf_static|diagnostics)\b'),
    "frames.py": (r'"(world|link_base|aslip_(tcp|finger|object|grasp_plane|gripper))"',
                  r'(?<![\w/])(world|link_base|aslip_(tcp|finger|object|grasp_plane|gripper))'
                  r'(?![\w/])'),
}


def _name_sources(home: str) -> list:
    """(file, pattern) for every file that must take the names from ``home``: the package's
    modules, the launch files and the config files (comments aside)."""
    py, yml = (re.compile(x) for x in NAMES[home])
    return ([(p, py) for p, _ in _modules() if p.name != home]
            + [(p, py) for p in sorted((ROOT / "launch").glob("*.py"))]
            + [(p, yml) for p in sorted((ROOT / "config").glob("*.yaml"))])


@pytest.mark.parametrize("home", sorted(NAMES))
def test_a_name_contract_is_written_once(home):
    elsewhere = [f"{p.relative_to(ROOT)}:{i}" for p, rx in _name_sources(home)
                 for i, line in enumerate(p.read_text().splitlines(), 1)
                 if rx.search(line.split("#")[0])]
    assert not elsewhere, elsewhere


def test_the_name_check_reads_yaml_values():
    """The check itself on config lines: a name as a value is found, quoted or not; one in
    a comment or inside a driver's own topic is not."""
    topic, frame = (re.compile(NAMES[h][1]) for h in ("topics.py", "frames.py"))
    assert topic.search("    slip_topic: /aslip/slip") and topic.search('  t: "/tf_static"')
    assert frame.search("    frame_id: aslip_gripper") and frame.search("  f: 'world'")
    assert not topic.search("  finger_topic: /vrpn_mocap/aslip_finger/pose")
    assert not frame.search("  finger_topic: /vrpn_mocap/aslip_finger/pose")
    assert not frame.search("  recalibrate_service: /slip_inference/recalibrate")
    assert not topic.search("    window_s: 0.2  # /aslip/slip".split("#")[0])


def test_the_check_sees_an_upward_import(tmp_path):
    """The graph check itself: a data module importing learn would be reported."""
    p = tmp_path / "x.py"
    p.write_text("def f():\n    from aslip_ros.learn import train\n")
    targets = [t for t, _ in _imports(p, "aslip_ros.data.x")]
    assert targets == ["aslip_ros.learn"]
    assert _floor(targets[0]) > _floor("aslip_ros.data.x")


def _module_graph(*roots: Path) -> dict:
    """Module -> the modules it imports (lazy imports too) among those under ``roots`` (the
    package by default); ``from pkg import x`` counts as importing ``pkg.x`` where that is a
    module, else ``pkg``."""
    names = {mod for _, mod in _modules(*roots)}
    graph = {}
    for path, mod in _modules(*roots):
        edges = set()
        tree = ast.parse(path.read_text())
        for n in ast.walk(tree):
            if isinstance(n, ast.ImportFrom):
                target = next(t for t, line in _imports_of(n, path, mod))
                subs = {f"{target}.{a.name}" for a in n.names} & names
                edges |= subs or ({target} & names)
            elif isinstance(n, ast.Import):
                edges |= {a.name for a in n.names} & names
        graph[mod] = edges - {mod}
    return graph


def _imports_of(node, path: Path, mod: str):
    pkg = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    if node.level:
        base = pkg.split(".")[:len(pkg.split(".")) - (node.level - 1)]
        yield ".".join(base + ([node.module] if node.module else [])), node.lineno
    else:
        yield node.module or "", node.lineno


def _circles(graph: dict) -> list:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_two_modules_import_each_other_even_through_others():
    """No import circle anywhere in the package, lazy imports included: a circle is two
    files that cannot be read, tested or replaced apart. Files are split by what belongs
    together; long files are fine, circles are not. The benchmarks are held to it too."""
    assert _circles(_module_graph(PKG, ROOT / "benchmarks")) == []


def test_the_circle_check_sees_a_circle_through_a_third_module():
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _circles({"a": {"b"}, "b": set()}) == []


def test_no_module_level_getattr_shims():
    """A module ``__getattr__`` hides where a name lives (and was used to paper over a
    circle): names are imported from the module that defines them, or re-exported from
    one below."""
    found = [str(p.relative_to(ROOT)) for p, _ in _modules()
             for n in ast.parse(p.read_text()).body
             if isinstance(n, ast.FunctionDef) and n.name == "__getattr__"]
    assert not found, found


#: Size limit of a function [lines]; beyond it the docstring must say why (and use the word
#: "lines" when it does). Modules have no size limit: they are split by cohesion.
MAX_FUNCTION_LINES = 80


def _oversized(path: Path, name: str) -> list:
    tree = ast.parse(path.read_text())
    out = []
    for n in ast.walk(tree):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = n.end_lineno - n.lineno + 1
            if length > MAX_FUNCTION_LINES and "lines" not in (ast.get_docstring(n) or ""):
                out.append(f"{name}:{n.lineno} {n.name}: {length} lines")
    return out


def test_functions_a_reader_can_hold_in_their_head():
    found = [x for p, _ in _modules() for x in _oversized(p, str(p.relative_to(ROOT)))]
    assert not found, found


def test_the_size_check_sees_a_long_function_unless_it_says_why(tmp_path):
    p = tmp_path / "long.py"
    body = "    x = 1\n" * 90
    p.write_text("def f():\n" + body)
    assert _oversized(p, "long.py") == ["long.py:1 f: 91 lines"]
    p.write_text('def f():\n    """One table of 90 lines: kept whole."""\n' + body)
    assert _oversized(p, "long.py") == []
