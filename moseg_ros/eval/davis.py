"""Score the node's dynamic masks on DAVIS-2016 clips against each clip's annotated moving object.

Layout: ``DIR/JPEGImages/480p/<clip>/*.jpg`` (or .png) and ``DIR/Annotations/480p/<clip>/*.png`` (non-zero: the
object). Frames in the natural order of their names, decoded as the node decodes a compressed image; annotations
paired by stem, else by order or by the number in their names. The pipeline runs over each clip as the node would
(stamps at 24 Hz); each annotated frame but the first is scored at the annotation's size. Per clip: J (mean IoU,
1 where both masks are empty), pixel precision and recall pooled over its frames, ms per frame; the mean line
averages J over clips and pools precision and recall. DAVIS annotates one object, so other movers count as false
positives. Clips, frames and annotations that cannot be used are listed with the reason, never scored silently;
a figure with nothing to count is NaN (null in the JSON).
"""

from __future__ import annotations

import argparse
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import PIL.Image
from threadpoolctl import threadpool_limits

from moseg_ros.eval.masks import mask_iou
from moseg_ros.eval.report import ClipSkipped, print_skipped, write_json
from moseg_ros.io.files import frame_number, image_files, read_frame
from moseg_ros.io.image import ImageDecodeError
from moseg_ros.config import add_live_argument, add_settings_arguments, pipeline_config
from moseg_ros.pipeline import Pipeline, PipelineConfig
from moseg_ros.timing import Pacer

FRAME_PERIOD_NS = 1_000_000_000 / 24  # DAVIS clips are 24 fps video (Perazzi et al., CVPR 2016)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
RESOLUTION = "480p"
# An annotation of another size than its frame is scored against the mask resized to it when their aspect ratios
# agree this closely (a clip's frames and annotations resized apart: 854x480 against 640x360 is 0.1 %).
ASPECT_TOLERANCE = 0.01


@dataclass
class ClipScore:
    """One clip's pixel agreement of dynamic masks with the annotated object (counts over scored frames)."""

    clip: str
    frames: int
    scored_frames: int
    j: float
    precision: float
    recall: float
    true_positives: int
    false_positives: int
    false_negatives: int
    ms_per_frame: float
    unreadable: list[str] = field(default_factory=list)
    mismatched: list[str] = field(default_factory=list)


def clip_names(root: Path) -> list[str]:
    """Names of the clip folders under root/JPEGImages/480p, sorted."""
    folder = root / "JPEGImages" / RESOLUTION
    return sorted(p.name for p in folder.iterdir() if p.is_dir()) if folder.is_dir() else []


def pair_annotations(images: list[Path], annotations: list[Path]) -> list[Path | None]:
    """The annotation of each image, or None for an image without one.

    Args:
        images: the clip's frames in order.
        annotations: the clip's annotation files in sorted order.

    Returns:
        One entry per image: the annotation with the same stem when any stems match (so a clip annotated on a
        subset of frames is paired correctly); otherwise, with as many annotations as images, the one at the same
        position; otherwise the one with the same number in its name (``frame_number``); None where none is.
    """
    by_stem = {p.stem: p for p in annotations}
    if by_stem.keys() & {p.stem for p in images}:
        return [by_stem.get(p.stem) for p in images]
    if len(annotations) == len(images):
        return list(annotations)
    by_number = {frame_number(p): p for p in annotations}
    return [by_number.get(number) if number is not None else None for number in map(frame_number, images)]


def read_annotation(path: Path) -> np.ndarray:
    """(H, W) bool object mask: a palette image's non-zero indices, any other image's pixels non-zero in a
    colour channel (grey 0/255 in DAVIS-2016, colours elsewhere; an alpha channel is not the object). Raises
    ImageDecodeError when the file cannot be read."""
    try:
        with PIL.Image.open(path) as image:
            image.load()
            pixels = np.asarray(image)  # a palette image's indices, not its colours
            if image.mode.endswith(("A", "a")):  # RGBA, LA, PA...: the last band is the alpha
                pixels = pixels[..., :-1]
    except Exception as error:  # Pillow raises OSError, EOFError, SyntaxError... on damaged files
        raise ImageDecodeError(f"cannot read annotation {path}: {error}") from None
    return pixels.any(axis=2) if pixels.ndim == 3 else pixels > 0


def at_annotation_size(predicted: np.ndarray, truth_shape: tuple[int, int]) -> np.ndarray | None:
    """(H, W) bool: the (h, w) bool ``predicted`` mask at the annotation's (H, W) shape (nearest), when their
    aspect ratios agree within ``ASPECT_TOLERANCE``; None when they do not (not the annotation of this frame)."""
    if predicted.shape == truth_shape:
        return predicted
    aspect = (predicted.shape[1] / predicted.shape[0]) / (truth_shape[1] / truth_shape[0])
    if abs(aspect - 1.0) > ASPECT_TOLERANCE:
        return None
    resized = cv2.resize(predicted.astype(np.uint8), truth_shape[::-1], interpolation=cv2.INTER_NEAREST)
    return resized > 0


def pooled_ratio(numerator: int, denominator: int) -> float:
    """numerator / denominator, NaN when the denominator is 0."""
    return numerator / denominator if denominator else float("nan")


def score_clip(name: str, images: list[Path], annotations: list[Path | None],
               config: PipelineConfig, live: float = 0.0) -> ClipScore:
    """Run the pipeline over the clip's frames and compare each annotated frame's mask (after the first frame the
    pipeline gets) with it. ``live``: a camera's rate (Hz) to run the pipeline at as the node does (0: offline).
    A frame of another size than the clip's first readable one is listed (``mismatched``) and not run: the
    pipeline would start over on it. Raises ClipSkipped when no frame is scored."""
    ious, seconds, unreadable, mismatched = [], [], [], []
    tp = fp = fn = 0
    size = None
    pacer = Pacer(live)
    with Pipeline(config, live=live > 0) as pipeline:
        for t, (image, annotation) in enumerate(zip(images, annotations)):
            try:
                frame = read_frame(image)
            except ValueError:
                unreadable.append(image.name)
                continue
            size = size or frame.shape[:2]
            if frame.shape[:2] != size:
                mismatched.append(f"{image.name} ({frame.shape[1]}x{frame.shape[0]}, the clip's {size[1]}x{size[0]})")
                continue
            pacer.wait()
            result = pipeline.process(frame, round(t * FRAME_PERIOD_NS), next_frame_at=pacer.next_due)
            seconds.append(result.seconds)
            if len(seconds) == 1 or annotation is None:
                continue
            try:
                truth = read_annotation(annotation)
            except ValueError:
                unreadable.append(annotation.name)
                continue
            predicted = at_annotation_size(result.masks.dynamic > 0, truth.shape)
            if predicted is None:
                mismatched.append(f"{annotation.name} ({truth.shape[1]}x{truth.shape[0]} against "
                                  f"{frame.shape[1]}x{frame.shape[0]})")
                continue
            ious.append(mask_iou(predicted, truth))
            tp += np.count_nonzero(predicted & truth)
            fp += np.count_nonzero(predicted & ~truth)
            fn += np.count_nonzero(~predicted & truth)
    if not ious:
        raise ClipSkipped(_why_skipped(seconds, annotations, unreadable, mismatched))
    return ClipScore(
        clip=name, frames=len(images), scored_frames=len(ious), j=float(np.mean(ious)),
        precision=pooled_ratio(tp, tp + fp), recall=pooled_ratio(tp, tp + fn),
        true_positives=int(tp), false_positives=int(fp), false_negatives=int(fn),
        ms_per_frame=1e3 * float(np.mean(seconds[1:])), unreadable=unreadable, mismatched=mismatched)


def _why_skipped(processed: list[float], annotations: list[Path | None], unreadable: list[str],
                 mismatched: list[str]) -> str:
    """Why a clip had no frame scored."""
    if not processed:
        return "no readable frame"
    if len(processed) == 1:
        return "one frame: nothing after the pipeline's first"
    if mismatched:
        return "no annotation of its frame's aspect"
    if not any(annotation is not None for annotation in annotations):
        return "no annotation pairs with a frame (stems, order or numbers)"
    return "no readable annotation after the pipeline's first frame" if unreadable else "no annotated frame scored"


def evaluate(root: Path, config: PipelineConfig, max_frames: int | None = None,
             live: float = 0.0) -> tuple[list[ClipScore], dict[str, str]]:
    """Score every clip of ``root`` that has readable frames and annotations (``live``: see ``score_clip``);
    returns the scores and the skipped clips with the reason. ``max_frames``: the first frames of each clip,
    paired with their annotations before they are cut."""
    scores, skipped = [], {}
    for name in clip_names(root):
        images = image_files(root / "JPEGImages" / RESOLUTION / name, IMAGE_SUFFIXES)
        annotations = image_files(root / "Annotations" / RESOLUTION / name, (".png",))
        if not images or not annotations:
            skipped[name] = "no frames" if not images else "no annotations"
            continue
        paired = pair_annotations(images, annotations)
        try:
            scores.append(score_clip(name, images[:max_frames], paired[:max_frames], config, live))
        except ClipSkipped as reason:
            skipped[name] = str(reason)
    return scores, skipped


def finite_mean(values: list[float]) -> float:
    """Mean of the finite values (a clip with nothing scored is NaN and left out), NaN if there are none."""
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def summary(scores: list[ClipScore]) -> dict[str, float]:
    """J and ms per frame averaged over clips; precision and recall pooled over all scored frames."""
    tp = sum(s.true_positives for s in scores)
    return {"mean_j": finite_mean([s.j for s in scores]),
            "precision": pooled_ratio(tp, tp + sum(s.false_positives for s in scores)),
            "recall": pooled_ratio(tp, tp + sum(s.false_negatives for s in scores)),
            "ms_per_frame": finite_mean([s.ms_per_frame for s in scores])}


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg eval davis`."""
    parser.add_argument("dir", type=Path, help="DAVIS-2016 folder (JPEGImages/480p/<clip>/, Annotations/480p/<clip>/)")
    add_settings_arguments(parser)
    add_live_argument(parser)
    parser.add_argument("--max-frames", type=positive_int, default=None,
                        help="process at most this many frames per clip (default: all)")
    parser.add_argument("--json", type=Path, help="also write the per-clip rows and the means to this file")


def run(args: argparse.Namespace) -> int:
    """Print the per-clip table and the mean line; 0 on success, 2 without clips or without a scored one."""
    if not clip_names(args.dir):
        print(f"no DAVIS clips (JPEGImages/{RESOLUTION}/<clip>/) under {args.dir}")
        return 2
    config = pipeline_config(args)
    with threadpool_limits(1):
        scores, skipped = evaluate(args.dir, config, args.max_frames, args.live)
    if not scores:
        print(f"no DAVIS clip under {args.dir} has a frame scored against an annotation "
              f"(Annotations/{RESOLUTION}/<clip>/*.png); skipped: {', '.join(skipped)}")
        print_skipped(skipped)
        return 2
    print(f"{'clip':20s} {'frames':>6s} {'scored':>6s} {'J %':>6s} {'precision %':>11s} {'recall %':>8s} "
          f"{'ms/frame':>8s}")
    for s in scores:
        print(f"{s.clip:20s} {s.frames:6d} {s.scored_frames:6d} {100 * s.j:6.1f} {100 * s.precision:11.1f} "
              f"{100 * s.recall:8.1f} {s.ms_per_frame:8.1f}")
    means = summary(scores)
    print(f"mean over {len(scores)} clips: J {100 * means['mean_j']:.1f} %, pooled precision "
          f"{100 * means['precision']:.1f} %, recall {100 * means['recall']:.1f} %, "
          f"{means['ms_per_frame']:.1f} ms per frame ({config.method})")
    print_skipped(skipped)
    for s in scores:
        if s.unreadable:
            print(f"{s.clip}: unreadable, skipped: {', '.join(s.unreadable)}")
        if s.mismatched:
            print(f"{s.clip}: not scored, of another size or aspect: {', '.join(s.mismatched)}")
    if args.json:
        write_json(args.json, {**means, "clips": [asdict(s) for s in scores], "clips_skipped": list(skipped),
                               "skipped_why": skipped, "config": asdict(config), "live_hz": args.live})
    return 0
