"""The `moseg` command: one sub-command per tool, each living in its own module.

Every tool module exposes ``add_arguments(parser)`` and ``run(args) -> int``. Only the module of the
command being run is imported, so one tool's heavy or optional imports never slow down or break another.
Grouped commands (``moseg eval kt3dmoseg``) nest one level. A tool's ``--json PATH`` is written when its run
ends, which may be many minutes later: a PATH whose folder does not exist is refused before the run starts.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from typing import Sequence

from moseg_ros.params import SettingsError

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "synth": ("moseg_ros.synth.cli", "render a synthetic street scene with ground truth into a bag"),
    "kitti2bag": ("moseg_ros.io.kitti", "convert a KITTI raw or odometry sequence into an MCAP bag"),
    "process": ("moseg_ros.tools.process", "run the pipeline in-process over every frame of a bag (or many, on Ray)"),
    "replay": ("moseg_ros.tools.replay", "replay a bag to a running segmenter and record its outputs"),
    "demo": ("moseg_ros.tools.demo", "the demo: synthetic bag -> real node over DDS -> scored masks"),
    "params": ("moseg_ros.tools.params", "the node's parameter file, every setting at its default"),
    "fingerprint": ("moseg_ros.tools.fingerprint", "an md5 of every frame's masks: show that a change kept them"),
    "synth-eval": ("moseg_ros.synth.evaluate", "per-object decisions of the pipeline on the synthetic presets"),
}

GROUPS: dict[str, tuple[str, dict[str, tuple[str, str]]]] = {
    "eval": ("benchmarks on a data folder of a known layout", {
        "kt3dmoseg": ("moseg_ros.eval.kt3dmoseg", "KT3DMoSeg trajectory-level motion segmentation benchmark"),
        "kt3dmoseg-masks": ("moseg_ros.eval.kt3dmoseg_masks",
                            "the node's dynamic masks on real KT3DMoSeg frames, scored at labelled points"),
        "davis": ("moseg_ros.eval.davis",
                  "the node's dynamic masks on DAVIS-2016 clips: J, pixel precision and recall"),
        "map": ("moseg_ros.eval.map", "COLMAP maps and trajectories with no mask, our masks and ground-truth masks"),
    }),
    "bench": ("speed benchmarks that print numbers", {
        "pipeline": ("moseg_ros.bench.pipeline", "milliseconds per frame of the pipeline"),
        "synth": ("moseg_ros.bench.synth", "frames per second of the synthetic street renderer"),
        "soak": ("moseg_ros.bench.soak", "the real node fed a bag's frames looped at a camera rate: masks, "
                 "latency, drops, memory, CPU"),
        "fleet": ("moseg_ros.bench.fleet", "bags per second of `moseg process` over many bags, sequential and on Ray"),
    }),
}


def _add_tool(subparsers: argparse._SubParsersAction, name: str, module_name: str, summary: str,
              selected: bool) -> None:
    parser = subparsers.add_parser(name, help=summary, description=summary)
    if selected:
        module = importlib.import_module(module_name)
        parser.description = module.__doc__
        parser.formatter_class = argparse.RawDescriptionHelpFormatter
        module.add_arguments(parser)
        parser.set_defaults(_run=module.run)


def build_parser(argv: Sequence[str] = ()) -> argparse.ArgumentParser:
    """The `moseg` parser; the tool named in ``argv`` (if any) gets its full options."""
    words = [word for word in argv if not word.startswith("-")]
    parser = argparse.ArgumentParser(prog="moseg", description=__doc__.splitlines()[0])
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name, (module_name, summary) in COMMANDS.items():
        _add_tool(subparsers, name, module_name, summary, words[:1] == [name])
    for group, (summary, tools) in GROUPS.items():
        group_parser = subparsers.add_parser(group, help=summary, description=summary)
        group_sub = group_parser.add_subparsers(dest="tool", required=True)
        for name, (module_name, tool_summary) in tools.items():
            _add_tool(group_sub, name, module_name, tool_summary, words[:2] == [group, name])
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `moseg` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser(argv).parse_args(argv)
    report = getattr(args, "json", None)
    if report is not None and not Path(report).parent.is_dir():
        command = " ".join(word for word in (args.command, getattr(args, "tool", None)) if word)
        print(f"moseg {command}: error: --json {report}: its folder does not exist", file=sys.stderr)
        return 2
    try:
        return int(args._run(args) or 0)
    except SettingsError as error:
        print(f"moseg: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
