"""Time `moseg process` over a fleet of bags: N copies of one bag, sequentially and on Ray, in one run.

Three runs on the same copies: one after another in this process, on Ray with one worker, and on Ray with
every core. Prints bags/s of each, the speed-up of all cores over the sequential run, and Ray's overhead per
bag (one worker against the sequential run), plus Ray's start-up apart (starting Ray and one warm worker
per core). Every run uses one thread per bag. ``parallel_ceiling`` is what the machine itself gives: the
throughput of a fixed pure-Python loop in as many processes as workers against one process (a machine
whose cores share a physical core or a CPU quota gives less than the number of cores).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from moseg_ros.config import add_settings_arguments, pipeline_config
from moseg_ros.pipeline import PipelineConfig
from moseg_ros.io.bags import is_bag
from moseg_ros.tools.fleet import LOCAL, process_fleet, start_ray, warm_up_ray


def _copies(bag: Path, folder: Path, n: int) -> Path:
    """A folder of n symbolic links to ``bag``, named copy_00, copy_01, ..."""
    inputs = folder / "in"
    inputs.mkdir()
    suffix = bag.suffix if bag.is_file() else ""
    for i in range(n):
        (inputs / f"copy_{i:02d}{suffix}").symlink_to(bag.resolve(), target_is_directory=bag.is_dir())
    return inputs


def _demo_bag(folder: Path, frames: int) -> Path:
    from moseg_ros.synth.scenarios import render_sequence
    from moseg_ros.synth.street import write_bag

    write_bag(render_sequence("default", n_frames=frames), folder / "street")
    return folder / "street"


def _spin(n: int) -> int:
    return sum(range(n))


def parallel_ceiling(processes: int, n: int = 60_000_000) -> float:
    """Throughput of ``processes`` processes each summing range(n), against one process doing it once."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(processes) as pool:
        list(pool.map(_spin, [1000] * processes))  # start the processes before timing
        start = time.perf_counter()
        pool.submit(_spin, n).result()
        alone = time.perf_counter() - start
        start = time.perf_counter()
        list(pool.map(_spin, [n] * processes))
        together = time.perf_counter() - start
    return processes * alone / together


def bench_fleet(bag: Path, copies: int, config: PipelineConfig = PipelineConfig(),
                workers: int | None = None) -> dict[str, Any]:
    """Process ``copies`` copies of ``bag`` three ways and return the timings (seconds, bags/s, speed-up,
    Ray's start-up and overhead per bag, the machine's parallel ceiling)."""
    import ray

    workers = workers or os.cpu_count() or 1
    with tempfile.TemporaryDirectory(prefix="moseg-fleet-") as tmp:
        inputs = _copies(Path(bag), Path(tmp), copies)
        sequential = process_fleet([inputs], Path(tmp) / "sequential", config)
        start = time.perf_counter()
        started = start_ray(LOCAL, workers)
        warm_up_ray(workers)
        startup = time.perf_counter() - start
        try:
            one = process_fleet([inputs], Path(tmp) / "ray_1", config, ray_address=LOCAL, workers=1)
            every = process_fleet([inputs], Path(tmp) / f"ray_{workers}", config, ray_address=LOCAL,
                                  workers=workers)
        finally:
            if started:
                ray.shutdown()
    runs = {"sequential": sequential, "ray_1_worker": one, f"ray_{workers}_workers": every}
    frames = sequential["totals"]["frames_in"]
    result: dict[str, Any] = {"bags": copies, "frames_per_bag": frames // max(copies, 1), "workers": workers,
                              "ray_startup_seconds": startup}
    for name, run in runs.items():
        failed = run["totals"]["failed"] + run["totals"]["damaged"]
        if failed:
            raise RuntimeError(f"{failed} bag(s) failed in the {name} run: {run['bags']}")
        result[name] = {"seconds": run["seconds"], "bags_per_second": copies / run["seconds"]}
    result["speedup"] = sequential["seconds"] / every["seconds"]
    result["parallel_ceiling"] = parallel_ceiling(workers)
    result["ray_overhead_seconds_per_bag"] = (one["seconds"] - sequential["seconds"]) / copies
    return result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg bench fleet`."""
    parser.add_argument("bag", type=Path, nargs="?", help="the bag to copy (default: a synthetic street bag)")
    parser.add_argument("--copies", type=int, default=4, help="bags in the fleet (default 4)")
    parser.add_argument("--frames", type=int, default=30, help="frames of the synthetic bag (default 30)")
    parser.add_argument("--workers", type=int, help="Ray workers of the parallel run (default: every core)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="also write the result here")
    add_settings_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Print the timings as JSON."""
    if args.copies < 1:
        print(f"moseg bench fleet: error: --copies must be >= 1, got {args.copies}", file=sys.stderr)
        return 2
    if args.bag is not None and not is_bag(args.bag):
        print(f"moseg bench fleet: error: not a bag (rosbag2 folder, .mcap or .bag): {args.bag}", file=sys.stderr)
        return 2
    config = pipeline_config(args)
    with tempfile.TemporaryDirectory(prefix="moseg-fleet-bag-") as tmp:
        bag = args.bag if args.bag is not None else _demo_bag(Path(tmp), args.frames)
        result = {"method": config.method, **bench_fleet(bag, args.copies, config, args.workers)}
    text = json.dumps(result, indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0
