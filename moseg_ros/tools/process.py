"""Run the pipeline in-process over every frame of a bag and write the masks with the inputs' stamps.

``moseg process IN -o OUT`` writes the output bag OUT. With several inputs, a folder of bags, or ``--ray``,
OUT is a folder that gets one output bag per input (``OUT/<input name>/``) and ``summary.json``; the bags
run one after another, or as Ray tasks with ``--ray`` (tools/fleet.py).

Deterministic and DDS-free: the same frames always give the same masks. With ``--live HZ`` (one bag) the
pipeline runs as the node does instead, refit on its worker and frames paced at HZ: the masks the node would
publish at that camera rate. Output topics are named as the
node's (``/segmenter/dynamic_mask`` ...), so every consumer reads both kinds of output bag alike.
A frame that cannot be decoded is skipped, counted and listed; nothing is dropped silently. A damaged
input bag is processed up to the damage: the output holds the masks of every frame before it and the
counts say where and why the reading stopped.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from moseg_ros.io.bags import is_bag
from moseg_ros.config import add_live_argument, add_settings_arguments, pipeline_config
from moseg_ros.tools.bag_masks import process_bag
from moseg_ros.tools.fleet import LOCAL, process_fleet, summary_table

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg process`."""
    parser.add_argument("bags", type=Path, nargs="+", metavar="IN",
                        help="input bag(s): rosbag2 folder, .mcap file or ROS 1 .bag, or a folder of bags")
    parser.add_argument("-o", "--output", type=Path, required=True,
                        help="output rosbag2 MCAP folder; with several bags, the folder of one output bag per input")
    parser.add_argument("--topic", help="image topic (default: the bag's one camera image topic)")
    parser.add_argument("--no-progress", action="store_true", help="do not print progress")
    parser.add_argument("--ray", nargs="?", const=LOCAL, metavar="ADDRESS",
                        help="one Ray task per bag: alone, a local Ray on this machine's cores; with an address "
                             "('auto', 'ray://host:10001') that cluster")
    parser.add_argument("--workers", type=int, metavar="N", help="at most N bags at a time with --ray")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing output bag; with several bags, redo those whose output is "
                             "complete (skipped otherwise)")
    add_settings_arguments(parser)
    add_live_argument(parser)


def _is_fleet(args: argparse.Namespace) -> bool:
    return len(args.bags) > 1 or args.ray is not None or not is_bag(args.bags[0])


def run_fleet(args: argparse.Namespace) -> int:
    """Process every bag into the output folder and print the table; exit 1 when a bag failed or was damaged."""
    if args.workers is not None and args.workers < 1:
        print(f"moseg process: error: --workers must be >= 1, got {args.workers}", file=sys.stderr)
        return 2
    try:
        summary = process_fleet(args.bags, args.output, pipeline_config(args), image_topic=args.topic,
                                ray_address=args.ray, workers=args.workers, overwrite=args.overwrite,
                                progress=not args.no_progress)
    except (FileNotFoundError, ValueError) as error:
        print(f"moseg process: error: {error}", file=sys.stderr)
        return 2
    print(summary_table(summary))
    totals = summary["totals"]
    return 1 if totals["failed"] or totals["damaged"] else 0


def run(args: argparse.Namespace) -> int:
    """Process the bag and print the counts; exit 1 when a frame was skipped or the input is damaged (its
    readable part is processed), 2 when the bag cannot be used at all."""
    if _is_fleet(args):
        if args.live > 0:
            print("moseg process: error: --live takes one bag (a camera's pace is one stream's)", file=sys.stderr)
            return 2
        return run_fleet(args)
    try:
        counts = process_bag(args.bags[0], args.output, image_topic=args.topic, config=pipeline_config(args),
                             progress=not args.no_progress, overwrite=args.overwrite, live=args.live)
    except FileExistsError as error:
        hint = "" if args.overwrite else "; --overwrite replaces an earlier output bag"
        print(f"moseg process: error: {error}{hint}", file=sys.stderr)
        return 2
    except (FileNotFoundError, ValueError) as error:
        print(f"moseg process: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(counts, indent=2))
    if counts["input_damage"]:
        print(f"moseg process: warning: {counts['input_damage']}; wrote the masks of the {counts['masks_out']} "
              "frames before it", file=sys.stderr)
    return 1 if counts["skipped"] or counts["input_damage"] else 0
