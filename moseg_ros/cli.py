"""The `moseg` command: one sub-command per tool, each living in its own module.

Every tool module exposes ``add_arguments(parser)`` and ``run(args) -> int``; its docstring's first line is
the help text. Grouped commands (``moseg eval kt3dmoseg``) nest one level.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

COMMANDS: dict[str, str] = {
    "synth": "moseg_ros.synth.cli",
    "kitti2bag": "moseg_ros.io.kitti",
    "process": "moseg_ros.tools.process",
    "replay": "moseg_ros.tools.replay",
    "demo": "moseg_ros.tools.demo",
}

GROUPS: dict[str, tuple[str, dict[str, str]]] = {
    "eval": ("Benchmarks on a data folder of a known layout.", {
        "kt3dmoseg": "moseg_ros.eval.kt3dmoseg",
    }),
}


def _add_tool(subparsers: argparse._SubParsersAction, name: str, module_name: str) -> None:
    module = importlib.import_module(module_name)
    summary = (module.__doc__ or name).strip().splitlines()[0]
    parser = subparsers.add_parser(name, help=summary, description=module.__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    module.add_arguments(parser)
    parser.set_defaults(_run=module.run)


def build_parser() -> argparse.ArgumentParser:
    """Return the `moseg` argument parser with every registered tool."""
    parser = argparse.ArgumentParser(prog="moseg", description=__doc__.splitlines()[0])
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name, module_name in COMMANDS.items():
        _add_tool(subparsers, name, module_name)
    for group, (summary, tools) in GROUPS.items():
        group_parser = subparsers.add_parser(group, help=summary, description=summary)
        group_sub = group_parser.add_subparsers(dest="tool", required=True)
        for name, module_name in tools.items():
            _add_tool(group_sub, name, module_name)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `moseg` console script."""
    args = build_parser().parse_args(argv)
    return int(args._run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
