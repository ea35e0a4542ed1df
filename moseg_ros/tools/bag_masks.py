"""One bag in, its masks out: every frame through the pipeline, the three mask topics written with the inputs' stamps.

Deterministic and DDS-free: the same frames always give the same masks; with ``live`` the pipeline runs as the
node does instead, refit on its worker and frames paced. Output topics are named as the node's
(``/segmenter/dynamic_mask`` ...), so every consumer reads both kinds of output bag alike. A frame that cannot
be decoded is skipped, counted and listed; a damaged input bag is processed up to the damage.
"""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path
from typing import Any

from moseg_ros.io.bag_images import Calibration, image_camera, read_images
from moseg_ros.io.bag_writer import BagWriter
from moseg_ros.io.bags import BagDamagedError, is_bag
from moseg_ros.io.frames import decode_frame
from moseg_ros.pipeline import Pipeline, PipelineConfig
from moseg_ros.timing import Pacer

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
