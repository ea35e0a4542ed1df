"""Time the pipeline per frame (what the node spends on each image) on synthetic street frames or a bag.

Prints mean, p50, p95 and max milliseconds per frame and the frames/s that implies; the node keeps up with a
camera when p95 stays under the frame period (100 ms at 10 Hz).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from moseg_ros.io.bags import read_images
from moseg_ros.io.frames import decode_frame
from moseg_ros.params import add_settings_arguments, pipeline_config
from moseg_ros.pipeline import Pipeline, PipelineConfig


def bench_pipeline(frames: list[np.ndarray], config: PipelineConfig = PipelineConfig(),
                   instances: list[np.ndarray] | None = None) -> dict[str, float]:
    """Run the pipeline over ``frames`` (10 Hz stamps; with an instance map per frame if given) and return
    per-frame timing in milliseconds."""
    pipeline = Pipeline(config)
    maps = instances if instances is not None else [None] * len(frames)
    seconds = [pipeline.process(frame, i * 100_000_000, labels).seconds
               for i, (frame, labels) in enumerate(zip(frames, maps))]
    ms = np.array(seconds[1:]) * 1e3  # the first frame only fills the window
    return {"frames": len(ms), "width": int(frames[0].shape[1]), "height": int(frames[0].shape[0]),
            "ms_mean": float(ms.mean()), "ms_p50": float(np.percentile(ms, 50)),
            "ms_p95": float(np.percentile(ms, 95)), "ms_max": float(ms.max()),
            "frames_per_second": float(1e3 / ms.mean())}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg bench pipeline`."""
    parser.add_argument("bag", type=Path, nargs="?", help="bag to read frames from (default: synthetic street)")
    parser.add_argument("--frames", type=int, default=30)
    add_settings_arguments(parser)  # --method object_level runs on the synthetic street's ground-truth instances


def run(args: argparse.Namespace) -> int:
    """Print the timing as JSON."""
    config = pipeline_config(args)
    instances = None
    if args.bag is None:
        from moseg_ros.synth.scenarios import render_sequence

        sequence = render_sequence("default", n_frames=args.frames).frames
        frames = [f.rgb for f in sequence]
        if config.method == "object_level":
            instances = [f.instances for f in sequence]
    elif config.method == "object_level":
        print("moseg bench pipeline: --method object_level needs instance maps: run it without a bag")
        return 2
    else:
        frames = [decode_frame(image.msg) for image, _ in zip(read_images(args.bag), range(args.frames))]
    with threadpool_limits(1):
        result = bench_pipeline(frames, config, instances)
    print(json.dumps({"method": config.method, "flow_preset": config.dis_preset(), **result}, indent=2))
    return 0
