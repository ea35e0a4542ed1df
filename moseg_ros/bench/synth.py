"""Time the synthetic street renderer (frames/s at a given size; the target is >= 20 at 1242x375)."""

from __future__ import annotations

import argparse
import json
import sys

from moseg_ros.synth.scenarios import bench_render
from moseg_ros.synth.street import KITTI_HEIGHT, KITTI_WIDTH


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg bench synth`."""
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--width", type=int, default=KITTI_WIDTH)
    parser.add_argument("--height", type=int, default=KITTI_HEIGHT)


def run(args: argparse.Namespace) -> int:
    """Print the rendering rate as JSON."""
    try:
        rate = bench_render(args.frames, args.width, args.height)
    except ValueError as error:  # fewer than one frame, an image under 16x16
        print(f"moseg bench synth: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps({"frames": args.frames, "width": args.width, "height": args.height,
                      "frames_per_second": rate}, indent=2))
    return 0
