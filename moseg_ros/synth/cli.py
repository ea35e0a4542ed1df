"""Render a synthetic street scene with exact ground truth into a rosbag2 MCAP.

Writes /camera/image_raw (rgb8), /camera/camera_info and the ground truth /gt/instances (32SC1),
/gt/dynamic_mask (mono8, 255 = moving), /gt/depth (32FC1, metres) and /gt/pose (PoseStamped, camera-to-world),
all with identical stamps per frame at 10 Hz (or at --rate: the same scene and motion per second seen by a
faster or slower camera). Frames are rendered and written one at a time.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterable, Iterator

from moseg_ros.synth.scenarios import DEFAULT_FRAMES, PRESETS, build_scene
from moseg_ros.synth.street import FRAME_RATE_HZ, KITTI_HEIGHT, KITTI_WIDTH, SynthFrame, render_frames, write_frames


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg synth`."""
    parser.add_argument("-o", "--output", required=True, help="output rosbag2 folder (must not exist)")
    parser.add_argument("--scenario", default="default", choices=list(PRESETS),
                        help="scene preset (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of textures and offsets (default: 0)")
    parser.add_argument("--frames", type=int, default=None,
                        help="number of frames at 10 Hz (default: 40; the map scenario 120)")
    parser.add_argument("--width", type=int, default=KITTI_WIDTH, help=f"image width (default: {KITTI_WIDTH})")
    parser.add_argument("--height", type=int, default=KITTI_HEIGHT, help=f"image height (default: {KITTI_HEIGHT})")
    parser.add_argument("--rate", type=float, default=FRAME_RATE_HZ, metavar="HZ",
                        help="the camera's frame rate; the scene and its motion per second stay those of --frames at "
                             "10 Hz (default: 10)")
    parser.add_argument("--start-ns", type=int, default=None,
                        help="stamp of the first frame in nanoseconds (default: the generator's fixed epoch)")


class _Timed:
    """Wraps a frame iterator and accumulates the time spent producing frames (rendering only)."""

    def __init__(self, frames: Iterable[SynthFrame]) -> None:
        self._frames = iter(frames)
        self.seconds = 0.0
        self.count = 0

    def __iter__(self) -> Iterator[SynthFrame]:
        while True:
            start = time.perf_counter()
            try:
                frame = next(self._frames)
            except StopIteration:
                return
            self.seconds += time.perf_counter() - start
            self.count += 1
            yield frame


def run(args: argparse.Namespace) -> int:
    """Render the scene, write the bag, print per-topic counts, the objects and the rendering rate."""
    if args.frames is None:
        args.frames = DEFAULT_FRAMES.get(args.scenario, 40)
    try:
        if args.frames < 2:
            raise ValueError(f"--frames must be at least 2, got {args.frames}")
        scene = build_scene(args.scenario, seed=args.seed, n_frames=args.frames, width=args.width,
                            height=args.height, rate_hz=args.rate)
        frames = _Timed(render_frames(scene))
        start = time.perf_counter()
        counts = write_frames(frames, scene.K, scene.width, scene.height, args.output, start_ns=args.start_ns)
        total = time.perf_counter() - start
    except (ValueError, FileExistsError, FileNotFoundError) as error:
        print(f"moseg synth: error: {error}", file=sys.stderr)
        return 2
    moving = scene.dynamic_ids()
    print(f"wrote {args.output}: scenario {scene.name!r}, seed {args.seed}, {frames.count} frames "
          f"{scene.width}x{scene.height} at {args.rate:g} Hz")
    for topic, count in counts.items():
        print(f"  {topic:24s} {count:6d} messages")
    for box_id, name in scene.object_names().items():
        print(f"  object {box_id:3d} {name:16s} {'moving' if box_id in moving else 'static'}")
    print(f"rendered {frames.count / max(frames.seconds, 1e-9):.1f} frames/s "
          f"({frames.count / max(total, 1e-9):.1f} frames/s including bag writing)")
    return 0
