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
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from moseg_ros.io.bags import BagDamagedError, BagWriter, Calibration, image_camera, read_images
from moseg_ros.io.frames import decode_frame
from moseg_ros.params import add_live_argument, add_settings_arguments, pipeline_config
from moseg_ros.pipeline import Pipeline, PipelineConfig
from moseg_ros.timing import Pacer
from moseg_ros.tools.fleet import LOCAL, is_bag, process_fleet, summary_table

OUTPUT_PREFIX = "/segmenter"


def process_bag(bag: str | Path, output: str | Path, *, image_topic: str | None = None,
                config: PipelineConfig = PipelineConfig(), progress: bool = False,
                overwrite: bool = False, live: float = 0.0) -> dict[str, Any]:
    """Segment every image of ``bag`` and write the three mask topics to ``output`` (rosbag2 MCAP).

    An existing ``output`` is refused (FileExistsError), or with ``overwrite`` replaced when it is a bag other
    than the input; nothing is removed before the input has proved usable. ``live``: a camera's rate (Hz) to run
    the pipeline at as the node does, refit on its worker and frames paced (the masks the node would publish;
    0: offline and deterministic).

    The frames get the K of the bag's camera_info beside the image topic (``<namespace>/camera_info``), the
    newest logged before each and for its size, as the node's would; without one the method runs uncalibrated.

    Returns:
        Counts: frames_in, masks_out, skipped (with the stamps and reasons), resets, timing,
        ``camera_info`` (its topic or None) and ``calibrated_frames``, and ``input_damage`` (None, or why the
        reading of a damaged input stopped).
    """
    counts: dict[str, Any] = {"frames_in": 0, "masks_out": 0, "skipped": [], "resets": 0, "statuses": {},
                              "input_damage": None}
    seconds: list[float] = []
    start = time.perf_counter()
    topic, calibration = image_camera(bag, image_topic)  # an unusable input fails before the output exists
    counts["camera_info"] = calibration.topic
    counts["calibrated_frames"] = 0
    if overwrite:
        _remove_output_bag(Path(output), Path(bag))
    pacer = Pacer(live)
    with Pipeline(config, live=live > 0) as pipeline, BagWriter(output) as writer:
        try:
            for image in read_images(bag, topic):
                pacer.wait()
                _process_image(pipeline, image, writer, counts, seconds, pacer.next_due, calibration)
                if progress:
                    print(f"\r{counts['frames_in']} frames, {seconds[-1] * 1e3 if seconds else 0:.0f} ms/frame",
                          end="", file=sys.stderr, flush=True)
        except BagDamagedError as error:
            counts["input_damage"] = str(error)
    if progress:
        print(file=sys.stderr)
    counts["resets"] = pipeline.resets
    counts["seconds_total"] = time.perf_counter() - start
    counts["ms_per_frame_mean"] = 1e3 * sum(seconds) / max(len(seconds), 1)
    return counts


def _remove_output_bag(output: Path, bag: Path) -> None:
    """Remove the earlier output bag at ``output`` (a folder or a file), refusing the input itself and
    anything that is not a bag."""
    if not output.exists():
        return
    if output.resolve() == bag.resolve():
        raise FileExistsError(f"the output is the input bag itself (not overwriting): {output}")
    if not is_bag(output):
        raise FileExistsError(f"the output exists and is not a bag (not overwriting): {output}")
    if output.is_dir():
        shutil.rmtree(output)
    else:
        output.unlink()


def _process_image(pipeline: Pipeline, image: Any, writer: BagWriter, counts: dict[str, Any],
                   seconds: list[float], next_frame_at: float | None = None,
                   calibration: Calibration | None = None) -> None:
    """Segment one bag image and write its three masks, or count it as skipped when it cannot be decoded
    (``next_frame_at``: when the next is due at a live pace, see Pipeline.process; ``calibration``: the bag's
    camera_info, whose K the frame gets as the node's would)."""
    counts["frames_in"] += 1
    try:
        frame = decode_frame(image.msg)
    except ValueError as error:
        counts["skipped"].append({"stamp_ns": image.stamp_ns, "reason": str(error)})
        return
    camera_matrix = None if calibration is None else calibration.at(image.log_time_ns, frame.shape)
    counts["calibrated_frames"] += camera_matrix is not None
    result = pipeline.process(frame, image.stamp_ns, camera_matrix=camera_matrix, next_frame_at=next_frame_at)
    status = result.status.split(":")[0]
    counts["statuses"][status] = counts["statuses"].get(status, 0) + 1
    seconds.append(result.seconds)
    for name, array, encoding in (("dynamic_mask", result.masks.dynamic, "mono8"),
                                  ("static_mask", result.masks.static, "mono8"),
                                  ("instance_labels", result.masks.instance_labels, "32SC1")):
        writer.write_image(f"{OUTPUT_PREFIX}/{name}", image.stamp_ns, image.frame_id, array, encoding,
                           log_time_ns=image.log_time_ns)
    counts["masks_out"] += 1


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
