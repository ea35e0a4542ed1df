"""An md5 of every frame's masks, to show that a change to the code left the published masks as they were.

``moseg fingerprint IN... -o FILE`` runs the pipeline offline (deterministic: every frame waits for its own
refit) over each input, a bag (with its camera_info, as ``moseg process``) or a folder of image frames
(uncalibrated), and writes ``{input: [md5 per frame]}`` as JSON; each digest covers the frame's status, dynamic
mask and instance labels. ``--against FILE`` compares with an earlier run and names the first frame of each
input that differs: exit 0 when every frame is the same, 1 otherwise.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path
from typing import Iterator

import numpy as np

from moseg_ros.io.bag_images import image_camera, read_images
from moseg_ros.io.bags import is_bag
from moseg_ros.io.files import image_files, read_frame
from moseg_ros.io.frames import decode_frame
from moseg_ros.config import add_settings_arguments, pipeline_config
from moseg_ros.pipeline import FrameResult, Pipeline, PipelineConfig

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm")
FRAME_PERIOD_NS = 100_000_000


def digest(result: FrameResult) -> str:
    """The md5 of a frame's status, dynamic mask and instance labels (shapes included)."""
    md5 = hashlib.md5(result.status.encode())
    for array in (result.masks.dynamic, result.masks.instance_labels):
        md5.update(str(array.shape).encode())
        md5.update(np.ascontiguousarray(array).tobytes())
    return md5.hexdigest()


def _frames(source: Path) -> Iterator[tuple[np.ndarray, int, np.ndarray | None]]:
    """(frame, stamp_ns, K or None) of every decodable frame of a bag or an image folder."""
    if is_bag(source):
        topic, calibration = image_camera(source)
        for image in read_images(source, topic):
            frame = decode_frame(image.msg)
            yield frame, image.stamp_ns, calibration.at(image.log_time_ns, frame.shape)
        return
    for index, path in enumerate(image_files(source, IMAGE_SUFFIXES)):
        yield read_frame(path), (index + 1) * FRAME_PERIOD_NS, None


def fingerprints(source: Path, config: PipelineConfig) -> list[str]:
    """The digest of every frame of ``source`` (a bag or a folder of images) through the pipeline, offline."""
    with Pipeline(config) as pipeline:
        return [digest(pipeline.process(frame, stamp, camera_matrix=K)) for frame, stamp, K in _frames(source)]


def first_differences(now: dict[str, list[str]], before: dict[str, list[str]]) -> dict[str, str]:
    """Per input of either run, why the two differ (the first differing frame, or the frame counts); {} when
    every input has the same digests."""
    differences = {}
    for name in sorted(set(now) | set(before)):
        ours, theirs = now.get(name), before.get(name)
        if ours is None or theirs is None:
            differences[name] = "only in " + ("the earlier run" if ours is None else "this run")
        elif len(ours) != len(theirs):
            differences[name] = f"{len(ours)} frames against {len(theirs)}"
        else:
            changed = [index for index, (a, b) in enumerate(zip(ours, theirs)) if a != b]
            if changed:
                differences[name] = f"{len(changed)} frames differ, the first frame {changed[0]}"
    return differences


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg fingerprint`."""
    parser.add_argument("inputs", type=Path, nargs="+", metavar="IN", help="bags or folders of image frames")
    parser.add_argument("-o", "--output", type=Path, help="write the digests here (JSON)")
    parser.add_argument("--against", type=Path, metavar="FILE", help="compare with an earlier run's JSON")
    add_settings_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Fingerprint every input; with ``--against``, exit 1 when a frame differs."""
    config = pipeline_config(args)
    missing = [str(path) for path in args.inputs if not path.exists()]
    if missing:
        print(f"moseg fingerprint: error: no such input: {', '.join(missing)}", file=sys.stderr)
        return 2
    now = {str(path): fingerprints(path, config) for path in args.inputs}
    for name, digests in now.items():
        print(f"{name}: {len(digests)} frames")
    if args.output is not None:
        args.output.write_text(json.dumps(now, indent=1) + "\n")
    if args.against is None:
        return 0
    differences = first_differences(now, json.loads(args.against.read_text()))
    for name, why in differences.items():
        print(f"differs: {name}: {why}")
    print("identical" if not differences else f"{len(differences)} of {len(now)} inputs differ")
    return 1 if differences else 0
