"""Time the pipeline per frame (what the node spends on each image) on synthetic street frames or a bag.

Prints mean, p50, p95 and max milliseconds per frame, p50 / p95 per stage (decode, prepare, tracks, flow,
regions, render ... as the method reports them), the refit's milliseconds on its worker and the age of the
decisions the frames applied (the node's ``refit`` auto: background), and the floor measured in the same run on
the same frames: KLT tracking at ``track_width`` plus the dense DIS flow back to the frame before at
``working_width`` with the method's preset and nothing else, the least any method of this design does per
frame. ``ratio`` is the pipeline's p95 over the floor's. The node keeps up with a camera when p95 stays under the
frame period. With ``--repeat N`` the whole run is done N times and each number is the median of the runs, with
its range beside it (``ranges``).
Frames come back to back, or with ``--rate HZ`` at a camera's pace: then the refit's worker gets the time the
frame path leaves between frames, as in the node, and the decisions' age says how often it refits.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from moseg_ros.io.bag_images import read_images
from moseg_ros.io.frames import decode_frame
from moseg_ros.io.image import to_gray
from moseg_ros.config import add_settings_arguments, pipeline_config
from moseg_ros.pipeline import Pipeline, PipelineConfig, opencv_threads
from moseg_ros.timing import Pacer


def _percentiles(ms: np.ndarray, prefix: str = "") -> dict[str, float]:
    return {f"{prefix}p50": float(np.percentile(ms, 50)), f"{prefix}p95": float(np.percentile(ms, 95))}


def floor_ms(frames: list[np.ndarray], config: PipelineConfig = PipelineConfig()) -> np.ndarray:
    """Milliseconds per frame (after the first) of KLT tracking plus the DIS flow back to the frame before and
    nothing else: what the front-end's frame path cannot do without, with the OpenCV threads the pipeline of
    ``config`` (its refit resolved) runs with.

    KLT: the front-end's tracker with ``max_tracks`` points on the frame at ``track_width``, guided by the
    dense flow and its backward check shared with it as the front-end does; flow: the DIS preset the method
    runs, from each frame back to the one before at ``working_width`` and ``working_pixels``.
    """
    from moseg_ros.frontend.flow import DenseFlow
    from moseg_ros.frontend.observe import resized_to_width
    from moseg_ros.frontend.tracks import PointTracker
    from moseg_ros.methods.moving_objects import front_end_config

    front_end = front_end_config(config)
    tracks = PointTracker(replace(front_end.tracks, max_points=front_end.max_tracks))
    flow = DenseFlow(config.dis_preset())
    grays = [to_gray(f, "mono8" if f.ndim == 2 else "rgb8") for f in frames]
    tracking = [resized_to_width(g, config.settings_of("moving_objects").track_width) for g in grays]
    dense = [resized_to_width(g, config.working_width, config.working_pixels) for g in grays]
    ms = []
    with opencv_threads(config.opencv_thread_count()):
        for i in range(len(frames)):
            start = time.perf_counter()
            tracks.update(tracking[i], flow(dense[i], dense[i - 1]) if i else None, dense[i])
            ms.append((time.perf_counter() - start) * 1e3)
    return np.array(ms[1:])


def bench_pipeline(frames: list[np.ndarray], config: PipelineConfig = PipelineConfig(),
                   instances: list[np.ndarray] | None = None,
                   decode_ms: list[float] | None = None, rate: float = 0.0) -> dict[str, Any]:
    """Run the pipeline over ``frames`` (10 Hz stamps; with an instance map per frame if given), then the floor
    on the same frames; per-frame timing in milliseconds, per stage and against the floor.

    The pipeline runs as in the node (``refit`` auto: background), frames back to back, or each at its time
    at ``rate`` frames a second (a frame that comes due while the one before still runs starts at once): the
    frame path's times are what a frame waits for, the refit's are on its worker.

    Returns:
        frames, width, height, ms_mean, ms_p50, ms_p95, ms_max, frames_per_second, stages ({stage: {p50,
        p95}}), floor_ms_p50, floor_ms_p95, ratio (ms_p95 / floor_ms_p95), refit (background or inline),
        refits, refit_ms_p50, refit_ms_p95 (each refit's fit and tests), refit_age_mean, refit_age_max,
        rate_hz (0: back to back).
    """
    maps = instances if instances is not None else [None] * len(frames)
    pacer = Pacer(rate)
    results = []
    with Pipeline(config, live=True) as pipeline:
        for i, (frame, labels) in enumerate(zip(frames, maps)):
            pacer.wait()
            results.append(pipeline.process(frame, i * 100_000_000, labels, next_frame_at=pacer.next_due))
    ms = np.array([r.seconds for r in results[1:]]) * 1e3  # the first frame only fills the window
    stages: dict[str, list[float]] = {}
    if decode_ms is not None:
        stages["decode"] = list(decode_ms[1:])
    for result in results[1:]:
        for name, seconds in result.stages.items():
            stages.setdefault(name, []).append(seconds * 1e3)
    floor = floor_ms(frames, pipeline.config)
    return {**_refit_numbers(results, pipeline.config.refit), **_fusion_numbers(results), "rate_hz": float(rate),
            "frames": len(ms), "width": int(frames[0].shape[1]), "height": int(frames[0].shape[0]),
            "ms_mean": float(ms.mean()), **_percentiles(ms, "ms_"), "ms_max": float(ms.max()),
            "frames_per_second": float(1e3 / ms.mean()),
            "stages": {name: _percentiles(np.array(v)) for name, v in stages.items() if len(v) == len(ms)},
            **_percentiles(floor, "floor_ms_"),
            "ratio": float(np.percentile(ms, 95) / np.percentile(floor, 95))}


def repeated(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One result from several ``bench_pipeline`` runs on the same frames: each number that varied is the
    median over the runs that have it (each stage's p50 and p95 too; ``ratio`` the median of the runs' ratios),
    with its smallest and largest value in ``ranges``; what all runs share (frames, size) stays as it is;
    ``repeats`` counts the runs. A number that only some runs have (one whose fused decision was not done within
    its frames has no ``fusion_*``) is the median of those, and ``partial`` says how many had it. A machine whose
    speed drifts between runs (a shared host: the same run varies by a third here) shows it in the ranges
    instead of in one run's luck."""
    if len(runs) == 1:
        return runs[0]
    keys = list(dict.fromkeys(key for run in runs for key in run))
    values = {key: [run[key] for run in runs if key in run] for key in keys}
    numbers = [key for key in keys if all(isinstance(value, (int, float)) for value in values[key])
               and (len(set(values[key])) > 1 or len(values[key]) < len(runs))]
    result: dict[str, Any] = {**{key: values[key][0] for key in keys}, "repeats": len(runs)}
    result.update({key: float(np.median(values[key])) for key in numbers})
    stages = [run.get("stages", {}) for run in runs]
    result["stages"] = {name: {p: float(np.median([stage[name][p] for stage in stages if name in stage]))
                               for p in percentiles}
                        for name, percentiles in {name: s[name] for s in reversed(stages) for name in s}.items()}
    result["ranges"] = {key: [float(min(values[key])), float(max(values[key]))] for key in numbers}
    partial = {key: len(values[key]) for key in keys if len(values[key]) < len(runs)}
    if partial:
        result["partial"] = partial
    return result


def _refit_numbers(results: list[Any], mode: str) -> dict[str, Any]:
    """Where the refits ran, how long each took and how old the decisions the frames applied were. A refit's
    track half can be applied before its dense half (moseg_ros/methods/moving_objects.py): each refit counts
    once, with all it did (the most its frames report; the frame a refit fitted is the frame's minus the age)."""
    per_refit: dict[int, float] = {}
    for i, result in enumerate(results):
        if result.refit_stages:
            fitted = i - result.telemetry["refit_age"]
            per_refit[fitted] = max(per_refit.get(fitted, 0.0), sum(result.refit_stages.values()) * 1e3)
    refit_ms = np.array(list(per_refit.values()))
    ages = np.array([r.telemetry["refit_age"] for r in results if "refit_age" in r.telemetry])
    numbers: dict[str, Any] = {"refit": mode, "refits": int(refit_ms.size)}
    if refit_ms.size:
        numbers.update(_percentiles(refit_ms, "refit_ms_"))
    if ages.size:
        numbers.update(refit_age_mean=float(ages.mean()), refit_age_max=int(ages.max()))
    return numbers


def _fusion_numbers(results: list[Any]) -> dict[str, Any]:
    """With ``object_fusion``: how long each fused decision took (on the fusion's worker with a background
    refit) and how old the decisions the frames applied were; nothing without it."""
    fusion_ms = np.array([r.telemetry["fusion_seconds"] * 1e3 for r in results
                          if "fusion_seconds" in r.telemetry])
    ages = np.array([r.telemetry["fusion_age"] for r in results if "fusion_age" in r.telemetry])
    numbers: dict[str, Any] = {"fusions": int(fusion_ms.size)} if fusion_ms.size else {}
    if fusion_ms.size:
        numbers.update(_percentiles(fusion_ms, "fusion_ms_"))
    if ages.size:
        numbers.update(fusion_age_mean=float(ages.mean()), fusion_age_max=int(ages.max()))
    return numbers


def _bag_frames(bag: Path, n: int, topic: str | None = None) -> tuple[list[np.ndarray], list[float]]:
    frames, decode_ms = [], []
    for image, _ in zip(read_images(bag, topic), range(n)):
        start = time.perf_counter()
        frames.append(decode_frame(image.msg))
        decode_ms.append((time.perf_counter() - start) * 1e3)
    return frames, decode_ms


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg bench pipeline`."""
    parser.add_argument("bag", type=Path, nargs="?", help="bag to read frames from (default: synthetic street)")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--rate", type=float, default=0.0, metavar="HZ",
                        help="feed the frames at a camera's rate (default 0: back to back)")
    parser.add_argument("--topic", help="image topic of the bag (default: its one camera image topic)")
    parser.add_argument("--repeat", type=int, default=1, metavar="N",
                        help="run N times on the same frames and report medians, with each number's range "
                             "(default 1)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="also write the result here")
    add_settings_arguments(parser)  # --method object_level runs on the synthetic street's ground-truth instances


def run(args: argparse.Namespace) -> int:
    """Print the timing as JSON."""
    config = pipeline_config(args)
    instances, decode_ms = None, None
    if args.bag is None:
        from moseg_ros.synth.scenarios import render_sequence

        sequence = render_sequence("default", n_frames=args.frames).frames
        frames = [f.rgb for f in sequence]
        if config.method == "object_level":
            instances = [f.instances for f in sequence]
    elif config.method == "object_level":
        return _error("--method object_level needs instance maps: run it without a bag")
    else:
        try:
            frames, decode_ms = _bag_frames(args.bag, args.frames, args.topic)
        except (FileNotFoundError, ValueError) as error:  # no bag, not a bag, damaged, no or several image topics
            return _error(str(error))
    if len(frames) < 3 or args.rate < 0 or args.repeat < 1:
        return _error(f"need at least 3 frames, a rate >= 0 and --repeat >= 1, got {len(frames)}, {args.rate} "
                      f"and {args.repeat}")
    with threadpool_limits(1):
        result = repeated([bench_pipeline(frames, config, instances, decode_ms, args.rate)
                           for _ in range(args.repeat)])
    text = json.dumps({"method": config.method, "flow_preset": config.dis_preset(), **result}, indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0


def _error(message: str) -> int:
    print(f"moseg bench pipeline: error: {message}", file=sys.stderr)
    return 2
