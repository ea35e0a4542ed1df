"""The demo: a synthetic street bag replayed through the real segmenter node, scored and pictured.

Steps: render the demo bag (unless it exists), start ``segmenter`` as its own process on a private ROS
domain over loopback, replay the bag to it at 10 Hz, record every output, stop the node with SIGINT, then
write ``summary.json`` (frames in, masks out, latency, IoU against ground truth), a contact sheet PNG and
an MP4 of the overlays.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from moseg_ros.eval.masks import GT_DYNAMIC_TOPIC, masks_by_stamp, score_bags
from moseg_ros.io.bag_images import read_images
from moseg_ros.io.bags import list_topics
from moseg_ros.methods import DEFAULT_METHOD, METHODS
from moseg_ros.config import all_settings
from moseg_ros.synth.scenarios import build_scene, check_scene
from moseg_ros.synth.street import GT_TOPICS, KITTI_HEIGHT, KITTI_WIDTH, render_frames, write_frames
from moseg_ros.tools.dds import loopback_env
from moseg_ros.tools.replay import replay

MASK_TOPIC = "/segmenter/dynamic_mask"


def segmenter_command() -> list[str]:
    """The installed ``segmenter`` console script beside this interpreter, else ``python -m moseg_ros.node``."""
    script = Path(sys.executable).parent / "segmenter"
    if script.is_file():
        return [str(script)]
    found = shutil.which("segmenter")
    return [found] if found else [sys.executable, "-m", "moseg_ros.node"]


def every_frame_params(queue_size: int) -> list[str]:
    """Node parameters under which a queue of ``queue_size`` frames holds what comes and each frame waits for the
    worker as long as ``max_wait_ms`` allows at most: none is carried or dropped while the queue has room."""
    longest = next(entry.high for entry in all_settings() if entry.name == "max_wait_ms")
    return [f"queue_size:={queue_size}", f"max_wait_ms:={float(longest)}"]


def start_segmenter(domain_id: int, log_path: Path, params: list[str] = ()) -> subprocess.Popen:
    """Start the node on ``domain_id`` (loopback DDS) with image/camera_info remapped to /camera/*."""
    command = segmenter_command() + ["--ros-args", "-r", "image:=/camera/image_raw",
                                     "-r", "camera_info:=/camera/camera_info"]
    for param in params:
        command += ["-p", param]
    log = open(log_path, "w")
    return subprocess.Popen(command, env=loopback_env(domain_id), stdout=log, stderr=subprocess.STDOUT)


def stop_segmenter(process: subprocess.Popen, timeout: float = 10.0) -> int:
    """SIGINT the node and wait for a clean exit; returns its exit code (killed: negative)."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    return process.returncode


def _overlay(rgb: np.ndarray, predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Predicted moving pixels tinted red, ground-truth outlines in green."""
    out = rgb.copy()
    out[predicted] = (0.5 * out[predicted] + (127, 0, 0)).astype(np.uint8)
    outline = cv2.morphologyEx(truth.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    out[outline] = (0, 255, 0)
    return out


def write_pictures(bag: Path, masks_bag: Path, out_dir: Path, tiles: int = 8,
                   has_truth: bool = True) -> dict[str, str]:
    """Write ``overlay_sheet.png`` (``tiles`` frames, 2 columns) and ``overlay.mp4`` (every frame, 10 fps); the
    ground truth is drawn when ``has_truth`` (the bag holds /gt/dynamic_mask)."""
    import imageio.v2 as imageio

    predicted = masks_by_stamp(masks_bag, MASK_TOPIC)
    truth = masks_by_stamp(bag, GT_DYNAMIC_TOPIC) if has_truth else {}
    frames = []
    for image in read_images(bag):
        rgb = image.rgb()
        empty = np.zeros(rgb.shape[:2], dtype=bool)
        frames.append(_overlay(rgb, predicted.get(image.stamp_ns, empty), truth.get(image.stamp_ns, empty)))
    picks = np.linspace(1, len(frames) - 1, min(tiles, len(frames) - 1)).round().astype(int)
    small = [cv2.resize(frames[i], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA) for i in picks]
    if len(small) % 2:
        small.append(np.zeros_like(small[0]))
    sheet = np.vstack([np.hstack(small[i:i + 2]) for i in range(0, len(small), 2)])
    sheet_path, video_path = out_dir / "overlay_sheet.png", out_dir / "overlay.mp4"
    cv2.imwrite(str(sheet_path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    # H.264 needs even sizes: drop a last odd row/column rather than let the writer rescale every frame.
    even = [f[: f.shape[0] - f.shape[0] % 2, : f.shape[1] - f.shape[1] % 2] for f in frames]
    imageio.mimwrite(video_path, even, fps=10, macro_block_size=1, quality=7)
    return {"contact_sheet": str(sheet_path), "video": str(video_path)}


def make_demo_bag(path: Path, *, scenario: str, seed: int, frames: int) -> dict[str, int]:
    """Render the synthetic street scenario into ``path`` (rosbag2 MCAP), one frame at a time."""
    scene = build_scene(scenario, seed=seed, n_frames=frames)
    return write_frames(render_frames(scene), scene.K, scene.width, scene.height, path)


def run_demo(out_dir: Path, bag: Path, *, scenario: str = "default", seed: int = 0, frames: int = 60,
             domain_id: int = 42, regenerate: bool = False, rate: float = 1.0,
             method: str = DEFAULT_METHOD, instances: bool = False) -> dict[str, Any]:
    """Render (if needed), replay through the node, score and picture; returns the summary written.

    Any camera bag may stand in for the rendered street: without /gt/dynamic_mask its masks are not scored (the
    summary has no scores). With ``instances`` (always for method object_level) the node runs with
    use_instances:=true and the bag's exact instance maps (/gt/instances) stand in for an upstream instance
    segmenter.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    if regenerate or not bag.exists():
        shutil.rmtree(bag, ignore_errors=True)
        print(f"rendering {frames} frames of scenario {scenario!r} (seed {seed}) into {bag}")
        make_demo_bag(bag, scenario=scenario, seed=seed, frames=frames)
    masks_bag = out_dir / "masks"
    shutil.rmtree(masks_bag, ignore_errors=True)
    instances = instances or method == "object_level"
    # A replayed bag is offline work: the node's queue holds every frame and each waits for the worker however
    # long (none dropped or carried), so latency includes the wait whenever the method is slower than the bag.
    params = [f"method:={method}", *every_frame_params(min(max(frames, 4), 100))]
    params += ["use_instances:=true"] if instances else []
    node = start_segmenter(domain_id, out_dir / "segmenter.log", params)
    try:
        report = replay(bag, masks_bag, domain_id=domain_id, rate=rate,
                        instances_topic=GT_TOPICS["instances"] if instances else None)
    finally:
        exit_code = stop_segmenter(node)
    has_truth = GT_DYNAMIC_TOPIC in list_topics(bag)
    scores = score_bags(bag, masks_bag, MASK_TOPIC).summary() if has_truth else {}
    summary = {**report.summary(), **scores, "node_exit_code": exit_code, "bag": str(bag),
               "masks_bag": str(masks_bag), "scenario": scenario, "seed": seed, "replay_rate": rate,
               "method": method, "instances": instances}
    summary.update(write_pictures(bag, masks_bag, out_dir, has_truth=has_truth))
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def print_table(summary: dict[str, Any]) -> None:
    """The demo's summary as an aligned two-column table (scores as "no ground truth" without one)."""
    def score(key: str, digits: int) -> str:
        return "no ground truth" if key not in summary else f"{summary[key]:.{digits}f}"

    rows = [("frames in", summary["frames_in"]), ("masks out", summary["masks_out"]),
            ("frames without mask", summary["frames_without_mask"]),
            ("header mismatches", summary["header_mismatches"]),
            ("latency p50 (ms)", f"{summary['latency_ms_p50']:.1f}"),
            ("latency p95 (ms)", f"{summary['latency_ms_p95']:.1f}"),
            ("mask IoU, mean over frames with movers", score("iou_mean", 3)),
            ("moving-pixel recall, mean", score("recall_mean", 3)),
            ("static pixels flagged, mean", score("false_positive_rate_mean", 4)),
            ("node exit code", summary["node_exit_code"]),
            ("contact sheet", summary["contact_sheet"]), ("video", summary["video"])]
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        print(f"  {name:<{width}}  {value}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg demo`."""
    parser.add_argument("--out", type=Path, default=Path("out"), help="output folder (default: out/)")
    parser.add_argument("--bag", type=Path, default=Path("bags/demo_street"),
                        help="demo bag folder, rendered when missing; any camera bag works (scored only when it "
                             "has /gt/dynamic_mask)")
    parser.add_argument("--scenario", default="default", help="synthetic scenario (default: default)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--domain", type=int, default=int(os.environ.get("MOSEG_DEMO_DOMAIN", 42)),
                        help="ROS domain id of the demo (default 42, or $MOSEG_DEMO_DOMAIN)")
    parser.add_argument("--regenerate", action="store_true", help="render the bag even if it exists")
    parser.add_argument("--rate", type=float, default=1.0, help="replay speed factor (default 1.0 = 10 Hz)")
    parser.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                        help="the node's method (object_level always gets the instances)")
    parser.add_argument("--instances", action="store_true",
                        help="the node gets the bag's exact instance maps as upstream instances (use_instances)")


def run(args: argparse.Namespace) -> int:
    """Run the demo; exit 1 unless every frame got its mask and the node exited cleanly, 2 on bad arguments."""
    try:
        check_scene(args.scenario, args.frames, KITTI_WIDTH, KITTI_HEIGHT)
    except ValueError as error:
        print(f"moseg demo: error: {error}", file=sys.stderr)
        return 2
    try:
        summary = run_demo(args.out, args.bag, scenario=args.scenario, seed=args.seed, frames=args.frames,
                           domain_id=args.domain, regenerate=args.regenerate, rate=args.rate, method=args.method,
                           instances=args.instances)
    except (FileNotFoundError, ValueError) as error:  # a bag without a camera topic, or without /gt/instances
        print(f"moseg demo: error: {error}", file=sys.stderr)
        return 2
    print_table(summary)
    print(f"summary: {args.out / 'summary.json'}")
    ok = summary["frames_in"] == summary["masks_out"] and summary["node_exit_code"] == 0
    return 0 if ok else 1
