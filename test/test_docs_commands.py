"""The commands the documentation names exist as written.

Every ``ros2 launch aslip_ros <file> name:=value`` in the README, docs/ and the launch files'
own docstrings may only give arguments the launch file declares (an undeclared one is
silently ignored by ``ros2 launch``: a documented ``arm:=`` that is none ran the default
arm), every ``aslip <command> --option`` only options that command has, and every benchmark
command (``python -m benchmarks.<name> --option``, ``make <target> ARGS="--option"``) only
options that benchmark has.
"""

from __future__ import annotations

import argparse
import importlib
import re
import runpy

import pytest

from conftest import ROOT

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
        *sorted((ROOT / "launch").glob("*.launch.py"))]


def _commands(pattern: str):
    """(file, command text) for each command matching ``pattern``, continuation lines
    joined."""
    out = []
    for path in DOCS:
        text = path.read_text().replace("\\\n", " ")
        for line in text.splitlines():
            for m in re.finditer(pattern, line):
                out.append((path.name, m.group(0)))
    return out


LAUNCHES = _commands(r"ros2 launch aslip_ros \S+\.launch\.py[^`|#]*")
ASLIPS = _commands(r"(?<![\w/.-])aslip (simulate|export|train|evaluate|check)\b[^`|#;]*")
#: make target -> the benchmark it runs (the Makefile's `$(BENCHMARK) benchmarks.<name>`).
TARGETS = dict(re.findall(r"^([\w-]+): setup\n\t\$\(BENCHMARK\) benchmarks\.(\w+)",
                          (ROOT / "Makefile").read_text(), re.M))
BENCHMARKS = _commands(r"python (?:-P )?-m benchmarks\.\w+[^`|#;]*")
MAKE_ARGS = _commands(r"make [\w-]+ ARGS=(?:\"[^\"]*\"|[^\s`]+)")


def test_the_documentation_names_commands():
    assert len(LAUNCHES) >= 10 and len(ASLIPS) >= 10
    assert len(BENCHMARKS) >= 10 and len(MAKE_ARGS) >= 5
    assert {"demo", "ablation", "bench", "stability", "transfer", "magnitude"} <= set(TARGETS)
    # The benchmarks left the `aslip` command (make targets, benchmarks/).
    assert not _commands(r"(?<![\w/.-])aslip (ablation|bench|stability|demo)\b[^`|#;]*")


def _declared(launch_file: str) -> set:
    from launch.actions import DeclareLaunchArgument
    desc = runpy.run_path(str(ROOT / "launch" / launch_file))["generate_launch_description"]()
    return {e.name for e in desc.entities if isinstance(e, DeclareLaunchArgument)}


@pytest.mark.ros
def test_every_documented_launch_argument_is_declared():
    # launch.actions, not launch: the repository's launch/ folder alone imports as "launch".
    pytest.importorskip("launch.actions", reason="needs the ROS 2 launch stack")
    problems = []
    for doc, cmd in LAUNCHES:
        launch_file = cmd.split()[3]
        if not (ROOT / "launch" / launch_file).is_file():
            problems.append(f"{doc}: {launch_file} does not exist ({cmd})")
            continue
        declared = _declared(launch_file)
        for name in re.findall(r"(?:^|\s)([A-Za-z_]\w*):=", cmd):
            if name not in declared:
                problems.append(f"{doc}: {launch_file} has no argument {name!r}: {cmd}")
    assert not problems, "\n".join(problems)


def _parser(command: str) -> argparse.ArgumentParser:
    from aslip_ros import cli
    parser = argparse.ArgumentParser(prog=f"aslip {command}")
    importlib.import_module(cli.SUBCOMMANDS[command][0]).add_arguments(parser)
    return parser


def _options(parser: argparse.ArgumentParser, tokens: list) -> list:
    """The option strings of ``tokens`` that ``parser`` (or the sub-parser a positional
    token chooses) does not have."""
    unknown = []
    for i, tok in enumerate(tokens):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction) and tok in action.choices:
                return unknown + _options(action.choices[tok], tokens[i + 1:])
        if tok.startswith("--"):
            name = tok.split("=")[0]
            if name not in parser._option_string_actions:
                unknown.append(name)
    return unknown


def test_every_documented_aslip_option_exists():
    problems = []
    for doc, cmd in ASLIPS:
        name = re.match(r"aslip (\w+)", cmd).group(1)
        unknown = _options(_parser(name), cmd.split()[2:])
        problems += [f"{doc}: aslip {name} has no option {u}: {cmd}" for u in unknown]
    assert not problems, "\n".join(problems)


def _benchmark_parser(name: str) -> argparse.ArgumentParser | None:
    """The parser of ``benchmarks.<name>``; None for one that builds its parser in ``main``."""
    module = importlib.import_module(f"benchmarks.{name}")
    if not hasattr(module, "add_arguments"):
        return None
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks.{name}")
    module.add_arguments(parser)
    return parser


def test_every_documented_benchmark_option_exists():
    problems = []
    documented = [(doc, re.search(r"benchmarks\.(\w+)", cmd).group(1),
                   cmd.split("benchmarks.", 1)[1].split()[1:]) for doc, cmd in BENCHMARKS]
    for doc, cmd in MAKE_ARGS:
        target, args = re.match(r"make ([\w-]+) ARGS=(.*)", cmd).groups()
        if target not in TARGETS:
            continue                       # flake-hunt takes ARGS too (pytest's)
        documented.append((doc, TARGETS[target], args.strip('"').split()))
    for doc, name, tokens in documented:
        if not (ROOT / "benchmarks" / f"{name}.py").is_file():
            problems.append(f"{doc}: no benchmark {name}")
            continue
        parser = _benchmark_parser(name)
        unknown = _options(parser, tokens) if parser else []
        problems += [f"{doc}: benchmarks.{name} has no option {u}" for u in unknown]
    assert not problems, "\n".join(problems)


def test_the_check_fails_on_an_undeclared_argument(monkeypatch):
    """The check itself: a command with an option the command lacks is reported."""
    assert _options(_parser("export"), ["bags", "--no-such-option"]) == ["--no-such-option"]
    assert _options(_parser("export"), ["bags", "-o", "ds", "--overwrite"]) == []


def test_every_document_a_file_cites_exists():
    """A path under docs/ named by the README, a document, a config file or a launch file
    exists (the config files cited a docs/nodes.md that never did)."""
    sources = DOCS + sorted((ROOT / "config").glob("*.yaml"))
    missing = []
    for path in sources:
        for cited in set(re.findall(r"(?<![\w/.])docs/[\w.-]+\.md\b", path.read_text())):
            if not (ROOT / cited).is_file():
                missing.append(f"{path.name}: {cited}")
    assert not missing, missing
