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
FLOOR = {"cli": 4, "nodes": 3, "runtime": 3, "launch_support": 3, "bringup": 3, "learn": 2,
         "hw": 2, "scene": 1, "node_table": 0,
         "cell": 0, "arm": 0, "motion": 0,
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


# --- floor 1 sideways (docs/design.md, Layers) ---------------------------------------------
#: Sideways arrows floor 1 forbids: control/ and scene/ import neither each other (the Arm
#: protocol and the sweeps they share are on floor 0: arm.py, motion.py), and data/ does not
#: import the scene (the scene records itself through data/: scene/simulate.py, presets.py).
FORBIDDEN_SIDEWAYS = {("control", "scene"), ("scene", "control"), ("data", "scene")}


def _package_of(mod: str) -> str:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "aslip_ros" else ""


def _sideways(path: Path, mod: str) -> list:
    """Every import in ``path`` (lazy ones too; ``from aslip_ros import scene`` counts as
    ``aslip_ros.scene``) that :data:`FORBIDDEN_SIDEWAYS` forbids, as ``file:line -> target``."""
    out = []
    for n in ast.walk(ast.parse(path.read_text())):
        if isinstance(n, ast.ImportFrom):
            target = next(t for t, _ in _imports_of(n, path, mod))
            targets = [target] if _package_of(target) else [f"{target}.{a.name}"
                                                            for a in n.names]
        elif isinstance(n, ast.Import):
            targets = [a.name for a in n.names]
        else:
            continue
        out += [f"{path.name}:{n.lineno} -> {t}" for t in targets
                if (_package_of(mod), _package_of(t)) in FORBIDDEN_SIDEWAYS]
    return out


def test_control_scene_and_data_do_not_import_each_other_sideways():
    found = [f"{p.relative_to(ROOT).parent}/{x}" for p, mod in _modules()
             for x in _sideways(p, mod)]
    assert not found, "\n".join(found)


def test_the_sideways_check_sees_lazy_relative_and_package_imports(tmp_path):
    p = tmp_path / "x.py"
    p.write_text("def f():\n    from aslip_ros.scene import World\n")
    assert _sideways(p, "aslip_ros.data.x") == ["x.py:2 -> aslip_ros.scene"]
    p.write_text("from ..control.arm import ArmError\n")
    assert _sideways(p, "aslip_ros.scene.x") == ["x.py:1 -> aslip_ros.control.arm"]
    p.write_text("from aslip_ros import scene\nimport aslip_ros.scene.scenarios as sc\n")
    assert _sideways(p, "aslip_ros.control.x") == [
        "x.py:1 -> aslip_ros.scene", "x.py:2 -> aslip_ros.scene.scenarios"]
    assert _sideways(p, "aslip_ros.nodes.x") == []          # floor 3 may import the scene
    p.write_text("from aslip_ros.data.bags import BagWriter\n")
    assert _sideways(p, "aslip_ros.scene.x") == []          # the scene records through data/


def test_the_arm_protocol_and_its_error_live_on_floor_0():
    """Every arm (hw/, the scene's) and every controller take ``Arm`` and ``ArmError`` from
    one floor-0 module; no other module defines a class of either name."""
    from aslip_ros import arm
    assert _floor(arm.Arm.__module__) == 0 and _floor(arm.ArmError.__module__) == 0
    defined = sorted(f"{p.relative_to(ROOT)}:{n.name}" for p, _ in _modules()
                     for n in ast.walk(ast.parse(p.read_text()))
                     if isinstance(n, ast.ClassDef) and n.name in ("Arm", "ArmError"))
    assert defined == ["aslip_ros/arm.py:Arm", "aslip_ros/arm.py:ArmError"], defined


# --- docs/design.md against the code ------------------------------------------------------
# The page's Layers block, learn/ table, Topics table and every module it names are read
# from the page itself (code blocks and markdown tables), so an edit to either side that
# the other lacks fails here with what to change.

DESIGN = ROOT / "docs" / "design.md"
#: FLOOR names that the Layers block does not list: generated messages and entry points.
NOT_IN_LAYERS = {"msg", "__init__", "__main__"}


def _design_section(title: str, text: str | None = None) -> str:
    """The body of the ``## <title>...`` section of docs/design.md (up to the next ``## ``)."""
    text = DESIGN.read_text() if text is None else text
    m = re.search(r"^## " + re.escape(title) + r".*?$(.*?)(?=^## |\Z)", text, re.M | re.S)
    assert m, f"docs/design.md has no section '## {title}': the checks below read it"
    return m.group(1)


def _code_blocks(text: str) -> list:
    """The contents of the fenced code blocks of ``text``, in order."""
    return re.findall(r"^```[^\n]*\n(.*?)^```", text, re.M | re.S)


def _layers(text: str | None = None) -> dict:
    """Name -> floor from the Layers block: ``floor N   name/ or name.py   what it holds``;
    a line whose name column is empty continues the description above it."""
    block = _code_blocks(_design_section("Layers", text))[0]
    out, floor = {}, None
    for line in block.splitlines():
        m = re.match(r"(?:floor (\d+))?(\s+)(\w+)(/|\.py)(?=\s|$)", line)
        if m and m.start(3) < 20:
            floor = int(m.group(1)) if m.group(1) else floor
            assert floor is not None, f"docs/design.md, Layers: {line!r} is on no floor"
            out[m.group(3)] = floor
    return out


def test_the_design_layers_are_the_floors_checked_here():
    """docs/design.md's Layers block and FLOOR (above) list the same names on the same
    floors: a module moved to another floor, or a new top-level module, changes both."""
    page, problems = _layers(), []
    for name, floor in sorted(FLOOR.items()):
        if name in NOT_IN_LAYERS:
            continue
        kind = "/" if (PKG / name).is_dir() else ".py"
        if name not in page:
            problems.append(f"docs/design.md, Layers: add `{name}{kind}` under floor {floor} "
                            f"(FLOOR in test/test_architecture.py has it)")
        elif page[name] != floor:
            problems.append(f"docs/design.md, Layers: `{name}{kind}` is on floor {page[name]} "
                            f"there and on floor {floor} in FLOOR: make them agree")
    problems += [f"docs/design.md, Layers: `{name}` is listed on floor {floor} but is not in "
                 f"FLOOR (test/test_architecture.py) or not under aslip_ros/: add it to FLOOR, "
                 f"or remove the line" for name, floor in sorted(page.items())
                 if name not in FLOOR or not ((PKG / name).is_dir()
                                              or (PKG / f"{name}.py").is_file())]
    assert not problems, "\n".join(problems)


def _learn_table(text: str | None = None) -> list:
    """The rows of the "`learn/` by role" block, bottom up: each a list of module names
    (``training.data``). A name with a folder (``training/data``) sets the folder of the
    bare names after it on its row; a row whose names end with a comma goes on below."""
    text = DESIGN.read_text() if text is None else text
    m = re.search(r"^`learn/` by role.*?\n```[^\n]*\n(.*?)^```", text, re.M | re.S)
    assert m, "docs/design.md: no \"`learn/` by role\" block after the Layers block"
    rows, more = [], False
    for line in m.group(1).splitlines():
        if not line.strip() or (line[0].isspace() and not more):
            continue                       # a description's continuation
        names = re.split(r"\s{2,}", line.strip())[0]
        if not more:
            rows.append([])
        folder = ""
        for name in filter(None, (n.strip() for n in names.split(","))):
            name = name.removesuffix(".py")
            if "/" in name:
                folder = name.rsplit("/", 1)[0] + "."
                rows[-1].append(name.replace("/", "."))
            else:
                rows[-1].append(folder + name)
        more = names.rstrip().endswith(",")
    return rows


def _learn_imports() -> dict:
    """learn module (``training.data``) -> the learn modules it imports, lazy ones too;
    packages' ``__init__`` files aside (they import nothing)."""
    prefix = "aslip_ros.learn."
    graph = _module_graph(PKG)
    return {m[len(prefix):]: {t[len(prefix):] for t in graph[m] if t.startswith(prefix)}
            for path, m in _modules(PKG / "learn")
            if m.startswith(prefix) and path.name != "__init__.py"}


def _learn_problems(rows: list, imports: dict) -> list:
    """What to change in the table (or the code), as the page writes names
    (``training/data``)."""
    row_of = {name: i for i, row in enumerate(rows) for name in row}
    page = {name: name.replace(".", "/") for name in set(row_of) | set(imports)}
    shown = {i: ", ".join(page[n] for n in r) for i, r in enumerate(rows)}
    where = "docs/design.md, `learn/` by role"
    problems = [f"{where}: `{page[name]}` is no module under aslip_ros/learn/: fix its name "
                f"or remove it" for name in row_of if name not in imports]
    for mod in sorted(set(imports) - set(row_of)):
        lowest = max((row_of[t] for t in imports[mod] if t in row_of), default=0)
        problems.append(f"{where}: add `{page[mod]}` on the row `{shown[lowest]}` or a later "
                        f"one (it imports {[page[t] for t in sorted(imports[mod])] or 'none'})")
    for mod in sorted(set(imports) & set(row_of)):
        for target in sorted(imports[mod]):
            if target in row_of and row_of[target] > row_of[mod]:
                problems.append(
                    f"{where}: `{page[mod]}` (row `{shown[row_of[mod]]}`) imports "
                    f"`{page[target]}` from the later row `{shown[row_of[target]]}`: move "
                    f"`{page[target]}` up or `{page[mod]}` down in the table, or drop the "
                    f"import")
    return problems


def test_each_learn_row_imports_only_the_rows_above_it():
    """docs/design.md, "`learn/` by role": every module of learn/ is on one row, and each
    imports only modules of its own row and the rows above it."""
    problems = _learn_problems(_learn_table(), _learn_imports())
    assert not problems, "\n".join(problems)


def test_the_learn_table_check_reads_rows_and_sees_an_arrow_up():
    page = ("`learn/` by role, bottom up:\n\n```\n"
            "features, stats                 what\n"
            "training/data, loop             more\n"
            "                                text\n"
            "evaluate, baselines,            lines\n"
            "synthetic                       go on\n```\n")
    rows = _learn_table(page)
    assert rows == [["features", "stats"], ["training.data", "training.loop"],
                    ["evaluate", "baselines", "synthetic"]]
    imports = {"features": set(), "stats": set(), "training.data": {"features"},
               "training.loop": {"evaluate"}, "evaluate": set(), "baselines": set(),
               "synthetic": set(), "selection": {"stats"}}
    problems = _learn_problems(rows, imports)
    assert len(problems) == 2
    assert any("add `selection` on the row `features, stats`" in p for p in problems)
    assert any("`training/loop`" in p and "imports `evaluate`" in p for p in problems)


def _topics() -> dict:
    """aslip_ros/topics.py's module constants: name -> topic."""
    tree = ast.parse((PKG / "topics.py").read_text())
    return {n.targets[0].id: n.value.value for n in tree.body
            if isinstance(n, ast.Assign) and isinstance(n.targets[0], ast.Name)
            and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)}


def _table_column(section: str, column: int = 0) -> list:
    """The cells of a markdown table's ``column`` (header and rule aside)."""
    rows = [line.strip().strip("|").split("|") for line in section.splitlines()
            if line.lstrip().startswith("|")]
    return [r[column].strip() for r in rows[2:]]


def test_the_topics_table_is_topics_py():
    """docs/design.md's Topics table has a row for every name of aslip_ros/topics.py, and
    no other."""
    table = {t for cell in _table_column(_design_section("Topics"))
             for t in re.findall(r"`(/[^`]*)`", cell)}
    names = _topics()
    problems = [f"docs/design.md, Topics: add a row for `{topic}` (topics.{name}): "
                f"| `{topic}` | type | QoS | content |"
                for name, topic in sorted(names.items()) if topic not in table]
    problems += [f"docs/design.md, Topics: `{topic}` is no name of aslip_ros/topics.py: add "
                 f"it there or remove the row" for topic in sorted(table - set(names.values()))]
    assert not problems, "\n".join(problems)


def test_the_qos_profiles_live_where_the_page_says():
    """The Topics section names the one module that builds the QoS profiles ("QoS in
    `path`"); no other module of the package builds a ``QoSProfile``."""
    m = re.search(r"QoS in `([\w/]+\.py)`", _design_section("Topics"))
    assert m, "docs/design.md, Topics: say where the QoS profiles live: \"QoS in `x/y.py`\""
    home = _resolve_path(m.group(1))
    assert home, f"docs/design.md, Topics: the QoS module {m.group(1)} does not exist"
    elsewhere = [f"{p.relative_to(ROOT)}:{n.lineno}" for p, _ in _modules() if p != home
                 for n in ast.walk(ast.parse(p.read_text()))
                 if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "QoSProfile"]
    assert not elsewhere, (f"these build a QoSProfile outside {home.relative_to(ROOT)}, "
                           f"where docs/design.md (Topics) says the QoS profiles live: move "
                           f"them there (or name their module on the page): {elsewhere}")


#: Where a path the page names may start: the repository, the package, learn/.
PATH_BASES = (ROOT, PKG, PKG / "learn")


def _resolve_path(name: str):
    """The file or folder ``name`` (``nodes/common.py``, ``training/train.py``,
    ``benchmarks/``) names, or None."""
    for base in PATH_BASES:
        p = base / name
        if p.is_file() or (name.endswith("/") and p.is_dir()):
            return p
    return None


def _module_file(mod: str):
    rel = Path(*mod.split("."))
    for p in (ROOT / rel.with_suffix(".py"), ROOT / rel / "__init__.py"):
        if p.is_file():
            return p
    return None


def _top_level_names(path: Path) -> set:
    """The names a module defines or imports at its top level (and a package's modules)."""
    names = set()
    stack = list(ast.parse(path.read_text()).body)
    while stack:
        n = stack.pop()
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(n.name)
        elif isinstance(n, (ast.Assign, ast.AnnAssign)):
            for t in (n.targets if isinstance(n, ast.Assign) else [n.target]):
                names |= {e.id for e in ast.walk(t) if isinstance(e, ast.Name)}
        elif isinstance(n, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in n.names}
        elif isinstance(n, (ast.If, ast.Try)):
            stack += n.body + n.orelse + getattr(n, "finalbody", [])
            stack += [s for h in getattr(n, "handlers", []) for s in h.body]
    if path.name == "__init__.py":
        names |= {p.stem for p in path.parent.iterdir()
                  if p.suffix == ".py" or (p / "__init__.py").is_file()}
    return names


def _dotted_problem(ref: str) -> str | None:
    """Why ``ref`` (``learn.models.registry.ModelBackend``, ``aslip_ros.scene``) names
    nothing in the package, or None."""
    parts = ref.split(".")
    parts = parts if parts[0] == "aslip_ros" else ["aslip_ros"] + parts
    if parts[1] == "msg":
        return None                        # generated by rosidl at build time
    for k in range(len(parts), 1, -1):
        path = _module_file(".".join(parts[:k]))
        if path:
            rest = parts[k:]
            if rest and rest[0] not in _top_level_names(path):
                return f"{path.relative_to(ROOT)} has no `{rest[0]}`"
            return None
    return "no such module"


def _named_paths(text: str) -> tuple:
    """(file and folder paths, dotted module references) named in ``text``: ``x/y.py``,
    ``x/`` (lower case, not inside a longer path) and ``learn.models.registry.X`` (first
    name a package module or ``aslip_ros``)."""
    files = set(re.findall(r"(?<![\w/.-])((?:[\w-]+/)*[\w-]+\.py)\b", text))
    folders = set(re.findall(r"(?<![\w/.:-])([a-z_]+(?:/[a-z_]+)*/)(?![\w.])", text))
    heads = "|".join(sorted(set(FLOOR) - NOT_IN_LAYERS | {"aslip_ros"}, key=len, reverse=True))
    dotted = {m for m in re.findall(r"(?<![\w./:-])((?:%s)(?:\.\w+)+)" % heads, text)
              if not m.endswith((".py", ".md", ".msg"))}
    return files | folders, dotted


def _string_constants() -> set:
    return {n.value for p, _ in _modules() for n in ast.walk(ast.parse(p.read_text()))
            if isinstance(n, ast.Constant) and isinstance(n.value, str)}


def test_every_module_the_design_page_names_exists():
    """Every file (``nodes/convert.py``), folder (``learn/``) and dotted name
    (``learn.models.registry.ModelBackend``) on docs/design.md names something that exists;
    a dotted name may also be a string the package uses (an entry-point group)."""
    paths, dotted = _named_paths(DESIGN.read_text())
    problems = [f"docs/design.md names {p}, which is no file or folder (looked under the "
                f"repository, aslip_ros/ and aslip_ros/learn/): write its current path"
                for p in sorted(paths) if not _resolve_path(p)]
    strings = _string_constants() if dotted else set()
    for ref in sorted(dotted):
        why = _dotted_problem(ref)
        if why and ref not in strings:
            problems.append(f"docs/design.md names `{ref}`: {why}; write where it is now")
    assert not problems, "\n".join(problems)


def test_the_path_check_sees_a_moved_module():
    paths, dotted = _named_paths("QoS in `nodes/nowhere.py`; `learn.models.registry.Nope`, "
                                 "`control/` and `hw.audio.WavReplay`, 2 m/s, util.py")
    assert paths == {"nodes/nowhere.py", "control/", "util.py"}
    assert dotted == {"learn.models.registry.Nope", "hw.audio.WavReplay"}
    assert _resolve_path("nodes/nowhere.py") is None and _resolve_path("util.py")
    assert _resolve_path("training/train.py") and _resolve_path("control/")
    assert "has no `Nope`" in _dotted_problem("learn.models.registry.Nope")
    assert _dotted_problem("learn.models.registry.ModelBackend") is None
    assert _dotted_problem("aslip_ros.scene") is None


def _code_references(text: str):
    """(line, name) for every ``aslip_ros.x.y`` in ``text``, a Sphinx role's name broken
    over two lines (``:class:`~aslip_ros.hw.audio.\\n WavReplay```) joined."""
    for m in re.finditer(r"(?<![\w.])aslip_ros(?:\.\w+)+", text):
        yield text.count("\n", 0, m.start()) + 1, m.group(0)
    for m in re.finditer(r":\w+:`~?(aslip_ros(?:\.\w+)*)\.\n[ \t]*(\w+(?:\.\w+)*)`", text):
        yield text.count("\n", 0, m.start()) + 1, f"{m.group(1)}.{m.group(2)}"


def test_every_package_name_the_code_writes_exists():
    """A module moved or renamed leaves no stale ``aslip_ros.x.y`` behind in a docstring,
    comment or string of the package, the benchmarks or the launch files (an entry-point
    group or other string the package itself uses is one)."""
    files = ([p for p, _ in _modules(PKG, ROOT / "benchmarks")]
             + sorted((ROOT / "launch").glob("*.py")))
    strings = _string_constants()
    stale = [f"{p.relative_to(ROOT)}:{line} names `{ref}`: {why}; write where it is now"
             for p in files for line, ref in _code_references(p.read_text())
             for why in [_dotted_problem(ref)] if why and ref not in strings]
    assert not stale, "\n".join(stale)


def test_the_code_reference_check_joins_a_broken_role():
    text = "x (:class:`~aslip_ros.hw.audio.\n  WavReplay`), aslip_ros.topics.AUDIO.\n"
    refs = list(_code_references(text))
    assert (1, "aslip_ros.hw.audio.WavReplay") in refs and (2, "aslip_ros.topics.AUDIO") in refs
    assert "has no `WavReplay`" in _dotted_problem("aslip_ros.hw.audio.WavReplay")
    assert _dotted_problem("aslip_ros.msg.AudioFrame") is None


# ----------------------------------------------------------------- the node table (#35 item 1)

def _node_names() -> set:
    """The package's node executables, read from aslip_ros/node_table.py's source."""
    tree = ast.parse((PKG / "node_table.py").read_text())
    return {n.args[0].value for n in ast.walk(tree)
            if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "_builtin"}


def _node_lists(source: str, names: set) -> list:
    """Line numbers of every literal collection (tuple, list, set, dict keys) in ``source``
    that holds two or more node names: a node list written out again."""
    found = []
    for n in ast.walk(ast.parse(source)):
        items = n.keys if isinstance(n, ast.Dict) else getattr(n, "elts", None) \
            if isinstance(n, (ast.Tuple, ast.List, ast.Set)) else None
        if items is None:
            continue
        hits = {i.value for i in items if isinstance(i, ast.Constant) and i.value in names}
        if len(hits) >= 2:
            found.append(n.lineno)
    return found


def test_every_node_list_is_the_node_tables():
    """CMake's executables, introspect's, the cell's arm nodes and the launch files' models
    come from aslip_ros/node_table.py: no module or launch file writes a list of nodes, and
    CMakeLists.txt names no node."""
    names = _node_names()
    assert {"slip_stop", "slip_track", "robot_sweeps"} <= names, names
    sources = [p for p, _ in _modules() if p.name != "node_table.py"] + \
        sorted((ROOT / "launch").glob("*.py"))
    written = [f"{p.relative_to(ROOT)}:{line}" for p in sources
               for line in _node_lists(p.read_text(), names)]
    assert not written, f"node lists written again (derive them from node_table): {written}"
    cmake = [line for line in (ROOT / "CMakeLists.txt").read_text().splitlines()
             if not line.lstrip().startswith("#") and
             len(names & set(re.findall(r"\w+", line))) >= 2]
    assert not cmake, f"CMakeLists.txt lists nodes (read node_table.py instead): {cmake}"


def test_the_node_list_check_sees_a_list_and_a_models_dict():
    names = {"slip_stop", "slip_track", "robot_sweeps"}
    assert _node_lists('ARM = ("slip_stop", "slip_track", "robot_sweeps")\n', names) == [1]
    assert _node_lists('M = {"slip_stop": "a.pt", "slip_track": "b.pt"}\n', names) == [1]
    assert _node_lists('x = ("slip_stop", "other")\ny = f("slip_track")\n', names) == []
