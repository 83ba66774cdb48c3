"""The commands the documentation names exist as written.

Every ``ros2 launch aslip_ros <file> name:=value`` in the README, docs/ and the launch files'
own docstrings may only give arguments the launch file declares (an undeclared one is
silently ignored by ``ros2 launch``: a documented ``arm:=`` that is none ran the default
arm), and every ``aslip <command> --option`` only options that command has.
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
ASLIPS = _commands(r"(?<![\w/.-])aslip (simulate|export|train|evaluate|ablation|bench|"
                   r"stability|demo|check)\b[^`|#;]*")


def test_the_documentation_names_commands():
    assert len(LAUNCHES) >= 10 and len(ASLIPS) >= 10


def _declared(launch_file: str) -> set:
    from launch.actions import DeclareLaunchArgument
    desc = runpy.run_path(str(ROOT / "launch" / launch_file))["generate_launch_description"]()
    return {e.name for e in desc.entities if isinstance(e, DeclareLaunchArgument)}


@pytest.mark.ros
def test_every_documented_launch_argument_is_declared():
    pytest.importorskip("launch", reason="needs the ROS 2 launch stack")
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
