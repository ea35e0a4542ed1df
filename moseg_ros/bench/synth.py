"""Time the synthetic street renderer (frames/s at a given size; the target is >= 20 at 1242x375)."""

from __future__ import annotations

import argparse
import json

from moseg_ros.synth.scenarios import bench_render
from moseg_ros.synth.street import KITTI_HEIGHT, KITTI_WIDTH


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg bench synth`."""
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--width", type=int, default=KITTI_WIDTH)
    parser.add_argument("--height", type=int, default=KITTI_HEIGHT)


def run(args: argparse.Namespace) -> int:
    """Print the rendering rate as JSON."""
    rate = bench_render(args.frames, args.width, args.height)
    print(json.dumps({"frames": args.frames, "width": args.width, "height": args.height,
                      "frames_per_second": rate}, indent=2))
    return 0
