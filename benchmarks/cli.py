"""``python -m benchmarks.<name> [options]``: one benchmark, run from a checkout.

The benchmarks are not part of the installed package. ``make demo``, ``make ablation``,
``make bench``, ``make stability``... run them from the repository root with the colcon
install first on ``sys.path`` (its ``aslip_ros`` has the generated messages) and the root
after it (``python -P``: the working directory is not put first). A benchmark with
``add_arguments(parser)`` and ``run(args) -> int`` (ablation, bench, stability, demo) runs
through the parser and exit codes of the ``aslip`` subcommands
(:func:`aslip_ros.cli.run_module`): 1 and one line on stderr for a refused input, 2 for a
wrong command line, 130 when interrupted.
"""

from __future__ import annotations

import importlib
import sys

from aslip_ros.cli import run_module


def main(name: str, argv: list[str] | None = None) -> int:
    """Run ``benchmarks.<name>`` with ``argv`` (default: the command line)."""
    module = importlib.import_module(f"benchmarks.{name}")
    description = (module.__doc__ or "").strip().split("\n\n")[0]
    return run_module(module, list(sys.argv[1:] if argv is None else argv),
                      prog=f"python -m benchmarks.{name}", description=description)
