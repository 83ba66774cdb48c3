"""The ``aslip`` command.

Each subcommand lives in the module that owns the work; that module provides
``add_arguments(parser)`` and ``run(args) -> int``. Modules are imported lazily so that
``aslip --help`` stays fast and a subcommand's heavy dependencies load only when used.

Exit codes, the same for every subcommand:

- 0: done;
- 1: the command refused its input or could not finish (a damaged bag or checkpoint, a
  parameter out of range, a full disk...), reported as one line ``aslip <command>: error:
  ...`` on stderr;
- 2: the command line itself is wrong (argparse's usage errors, unknown names);
- 130: interrupted (Ctrl-C).

Set ``ASLIP_DEBUG=1`` to get the traceback of a refused input instead of its one line.

The benchmarks of the paper (ablation, bench, stability, demo...) are not subcommands: they
live in the checkout's top-level ``benchmarks/`` and run from it (``make demo``, ``make
ablation``...; ``python -m benchmarks.<name>``) through :func:`run_module` below.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

# name -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("aslip_ros.scene.simulate", "record simulated scenarios to rosbag2 (mcap) files"),
    "export": ("aslip_ros.data.export", "turn rosbags into a windowed training dataset"),
    "train": ("aslip_ros.learn.training.cli",
              "train a slip model (chosen on your data, or by name)"),
    "evaluate": ("aslip_ros.learn.evaluate", "evaluate a checkpoint on a dataset (JSON metrics)"),
    "hybrid": ("aslip_ros.learn.models.aslip_hybrid",
               "run a streaming and a window checkpoint as one (slip_inference)"),
    "check": ("aslip_ros.bringup.check",
              "bring-up checks of a new cell: audio, taps, mocap, grasp plane, arm, "
              "real-time headroom"),
}


def _load(module: str):
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and module.startswith(exc.name):
            return None
        raise


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="aslip",
        description="A-SLIP acoustic slip sensing: simulate, export, train, evaluate.")
    from aslip_ros import __version__
    parser.add_argument("--version", action="version", version=f"aslip_ros {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="<command>")
    for name, (module, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        if "--help" in sys.argv or "-h" in sys.argv:
            # Only the chosen subcommand needs its full argument list.
            if name in sys.argv:
                mod = _load(module)
                if mod is not None:
                    mod.add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if not argv:
        parser.print_help()
        return 0
    name = argv[0]
    if name not in SUBCOMMANDS:
        parser.parse_args(argv)  # prints --help / --version / the usage error
        return 0
    module = _load(SUBCOMMANDS[name][0])
    if module is None:
        print(f"aslip {name}: not available in this version yet", file=sys.stderr)
        return EXIT_USAGE
    return run_module(module, argv[1:], prog=f"aslip {name}", description=SUBCOMMANDS[name][1])


def run_module(module, argv: list[str], prog: str, description: str) -> int:
    """Parse ``argv`` with ``module.add_arguments`` and call ``module.run``, with the exit
    codes above (the benchmarks of the checkout run through this too: benchmarks/cli.py)."""
    # Every option's default shows in --help (a help text that states it keeps its own).
    p = argparse.ArgumentParser(prog=prog, description=description,
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    module.add_arguments(p)
    args = p.parse_args(argv)
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, OSError) as exc:
        # Subcommands report what they expect; this catches what reaches the top anyway
        # (an unwritable --out, a refused file found late) as the same one line.
        if os.environ.get("ASLIP_DEBUG"):
            raise
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
