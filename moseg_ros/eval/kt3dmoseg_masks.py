"""Score the node's dynamic masks on real KITTI street frames at KT3DMoSeg's labelled points.

For every clip with frames (``DIR/OriginalSequences/<clip>/*.png`` or .jpg, matched to the trajectory frames by
the number in their names, else by natural order) the pipeline runs as the node would, and each labelled point
visible in a frame is looked up in its dynamic mask. Label 1 is the static background, >= 2 the movers. Per clip
and pooled: recall on moving points, static points flagged, object-frames detected (half of a mover's visible
points masked), ms per frame, and how the published instances follow the movers (eval/identities.py: id
switches, instances holding two movers, movers split over two). The first frame of each clip is not scored.
Clips without frames, unreadable frames, frames that do not hold the clip's trajectories (``mismatched``) and
missing ones are listed with the reason; a figure with nothing to count is NaN (null in the JSON).
"""

from __future__ import annotations

import argparse
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from moseg_ros.eval.identities import InstanceFollow
from moseg_ros.eval.kt3dmoseg import Clip, default_dir, find_clips, load_clip, no_clips_message
from moseg_ros.eval.report import ClipSkipped, print_skipped, write_json
from moseg_ros.io.files import frame_number, image_files, read_frame
from moseg_ros.config import add_live_argument, add_settings_arguments, pipeline_config
from moseg_ros.pipeline import Pipeline, PipelineConfig
from moseg_ros.timing import Pacer

FRAME_PERIOD_NS = 100_000_000  # the clips are consecutive KITTI frames, nominally 10 Hz
FRAME_SUFFIXES = (".png", ".jpg", ".jpeg")
# A frame larger than this many times the extent of the clip's points both ways is not the frame they were tracked
# on (the trajectories of KT3DMoSeg's clips reach 0.85-1.0 of their frames' width and 0.94-1.0 of their height;
# frames resized 1.3 times scored 10 % of the moving points).
OVERSIZE = 1.2


@dataclass
class ClipMaskScore:
    """One clip's point-level agreement of dynamic masks with the labels (points count point-frames)."""

    clip: str
    frames: int
    moving_points: int
    static_points: int
    moving_recall: float
    static_flagged: float
    ms_per_frame: float
    moving_hits: int
    static_hits: int
    object_frames: int
    object_frames_detected: int
    id_switches: int = 0
    shared_object_frames: int = 0
    split_object_frames: int = 0
    unreadable: list[str] = field(default_factory=list)
    mismatched: list[str] = field(default_factory=list)
    missing: list[int] = field(default_factory=list)


def frames_folder(root: Path, clip: str) -> Path | None:
    """The clip's frame folder under root/OriginalSequences, matched case-insensitively, or None."""
    folder = root / "OriginalSequences"
    if not folder.is_dir():
        return None
    matches = [p for p in folder.iterdir() if p.is_dir() and p.name.lower() == clip.lower()]
    return matches[0] if matches else None


def points_in_masks(masks: list[np.ndarray], clip: Clip) -> np.ndarray:
    """(N, F) bool: whether each trajectory point lies in its frame's dynamic mask (False where not visible)."""
    return values_at_points(masks, clip) > 0


def values_at_points(maps: list[np.ndarray], clip: Clip) -> np.ndarray:
    """(N, F) int64: each trajectory point's value in its frame's (H, W) map, each map of its own size (0 where not
    visible or outside)."""
    values = np.zeros(clip.visible.shape, dtype=np.int64)
    for t, image in enumerate(maps):
        height, width = image.shape
        seen = clip.visible[:, t]
        xy = np.rint(clip.tracks[seen, t]).astype(np.int64)
        inside = (xy[:, 0] >= 0) & (xy[:, 0] < width) & (xy[:, 1] >= 0) & (xy[:, 1] < height)
        rows = np.flatnonzero(seen)[inside]
        values[rows, t] = image[xy[inside, 1], xy[inside, 0]]
    return values


def followed_instances(instances: np.ndarray, scored: np.ndarray, labels: np.ndarray) -> InstanceFollow:
    """How the published instances ((N, F) ids at the points, ``values_at_points``) follow each moving object
    (``labels`` (N,) >= 2) over the (N, F) ``scored`` point-frames (eval/identities.py)."""
    follow = InstanceFollow()
    for t in range(scored.shape[1]):
        points = scored[:, t] & (labels >= 2)
        if points.any():
            follow.add(instances[points, t], labels[points], np.unique(labels[points]))
    return follow


def object_frame_detections(hits: np.ndarray, scored: np.ndarray, labels: np.ndarray) -> tuple[int, int]:
    """Count the object-frames of the moving objects and those detected.

    Args:
        hits: (N, F) bool, each point in its frame's mask.
        scored: (N, F) bool, the point-frames that count (visible, not the first frame).
        labels: (N,) labels; each label >= 2 is one moving object.

    Returns:
        (object-frames with at least one scored point, those with at least half of those points hit).
    """
    objects = np.unique(labels[labels >= 2])
    members = (labels[None, :] == objects[:, None]).astype(np.int64)  # (K, N) one-hot
    points = members @ scored.astype(np.int64)  # (K, F) scored points of each object in each frame
    inside = members @ (hits & scored).astype(np.int64)
    present = points > 0
    return int(present.sum()), int((present & (2 * inside >= points)).sum())


def trajectory_frames(files: list[Path], count: int) -> list[Path | None]:
    """The file of each of a clip's ``count`` trajectory frames (None where there is none): by the number in the
    files' names (``frame_number``) when every name holds a number of its own, else in the files' order
    (``files``: natural order). Numbers count from 0 when some name holds 0, else from 1 (the layout's
    ``%06d.png``) when they fit, else from the lowest (frames cut from a longer sequence, 0000000045.png on)."""
    numbers = [frame_number(path) for path in files]
    if None in numbers or len(set(numbers)) < len(numbers):
        return [*files[:count], *[None] * (count - len(files))]
    first = 0 if 0 in numbers else 1 if max(numbers, default=0) <= count else min(numbers)
    frames: list[Path | None] = [None] * count
    for path, number in zip(files, numbers):
        if 0 <= number - first < count:
            frames[number - first] = path
    return frames


def holds_points(shape: tuple[int, ...], extent: np.ndarray) -> bool:
    """Whether a frame of ``shape`` (H, W[, 3]) is one the clip's points (reaching ``extent``, (x, y) at most)
    were tracked on: they lie inside it (within a pixel), and it is not ``OVERSIZE`` times their extent both
    ways."""
    height, width = shape[:2]
    inside = extent[0] <= width and extent[1] <= height
    return inside and not (width > OVERSIZE * (extent[0] + 1) and height > OVERSIZE * (extent[1] + 1))


def score_clip(clip: Clip, frame_paths: list[Path | None], config: PipelineConfig,
               live: float = 0.0) -> ClipMaskScore:
    """Run the pipeline over the clip's frames (``trajectory_frames``: one entry per trajectory frame, None where
    it has no file) and score its masks at the labelled points. ``live``: a camera's rate (Hz) to run the pipeline
    at as the node does (0: offline). Raises ClipSkipped when no frame could be given to the pipeline."""
    n = min(len(frame_paths), clip.visible.shape[1])
    extent = clip.tracks[clip.visible].max(axis=0) if clip.visible.any() else np.zeros(2)
    masks: list[np.ndarray | None] = []
    instances: list[np.ndarray | None] = []
    seconds, unreadable, mismatched = [], [], []
    size = None  # the clip's frame size: its first frame's that holds the points
    pacer = Pacer(live)
    with Pipeline(config, live=live > 0) as pipeline:
        for t in range(n):
            frame = _frame(frame_paths[t], extent, size, unreadable, mismatched)
            size = size or (frame.shape[:2] if frame is not None else None)
            if frame is None:
                masks.append(None)
                instances.append(None)
                continue
            pacer.wait()
            result = pipeline.process(frame, t * FRAME_PERIOD_NS, next_frame_at=pacer.next_due)
            masks.append(result.masks.dynamic)
            instances.append(result.masks.instance_labels)
            seconds.append(result.seconds)
    unread = np.array([mask is None for mask in masks], dtype=bool)
    if unread.all():
        raise ClipSkipped(_why_skipped(unreadable, mismatched, extent))
    blank = np.zeros((1, 1), dtype=np.int32)  # an unread frame's: none of its points is scored
    shown = Clip(clip.name, clip.tracks[:, :n], clip.visible[:, :n], clip.labels)
    hits = points_in_masks([blank if mask is None else mask for mask in masks], shown)
    ids = values_at_points([blank if labels is None else labels for labels in instances], shown)
    scored = clip.visible[:, :n] & ~unread
    scored[:, :int(np.argmin(unread)) + 1] = False  # up to the pipeline's first frame
    if not scored.any():
        raise ClipSkipped("no frame to score after the pipeline's first")
    moving = (clip.labels >= 2)[:, None] & scored
    static = (clip.labels == 1)[:, None] & scored
    object_frames, detected = object_frame_detections(hits, scored, clip.labels)
    follow = followed_instances(ids, scored, clip.labels)
    return ClipMaskScore(
        clip=clip.name, frames=n, moving_points=int(moving.sum()), static_points=int(static.sum()),
        moving_recall=float(hits[moving].mean()) if moving.any() else float("nan"),
        static_flagged=float(hits[static].mean()) if static.any() else float("nan"),
        ms_per_frame=1e3 * float(np.mean(seconds[1:])) if len(seconds) > 1 else float("nan"),
        moving_hits=int(hits[moving].sum()), static_hits=int(hits[static].sum()),
        object_frames=object_frames, object_frames_detected=detected,
        id_switches=sum(follow.switches.values()), shared_object_frames=sum(follow.shared.values()),
        split_object_frames=sum(follow.split.values()),
        unreadable=unreadable, mismatched=mismatched,
        missing=[t for t in range(n) if frame_paths[t] is None])


def _frame(path: Path | None, extent: np.ndarray, size: tuple[int, int] | None, unreadable: list[str],
           mismatched: list[str]) -> np.ndarray | None:
    """The frame of ``path`` for the pipeline, or None (listed in ``unreadable``, in ``mismatched`` when it does not
    hold the points or is not of the clip's ``size`` (None: not known yet), or without a file)."""
    if path is None:
        return None
    try:
        frame = read_frame(path)
    except ValueError:
        unreadable.append(path.name)
        return None
    if not holds_points(frame.shape, extent) or size not in (None, frame.shape[:2]):
        mismatched.append(f"{path.name} ({frame.shape[1]}x{frame.shape[0]})")
        return None
    return frame


def _why_skipped(unreadable: list[str], mismatched: list[str], extent: np.ndarray) -> str:
    """Why a clip had no frame for the pipeline."""
    if mismatched:
        return (f"its frames ({', '.join(mismatched[:3])}{', ...' if len(mismatched) > 3 else ''}) do not hold its "
                f"trajectories, which reach x = {extent[0]:.0f}, y = {extent[1]:.0f}: not the frames they were "
                f"tracked on (resized?)")
    if unreadable:
        return f"no readable frame ({len(unreadable)} unreadable)"
    return "no frames"


def evaluate(root: Path, config: PipelineConfig = PipelineConfig(),
             live: float = 0.0) -> tuple[list[ClipMaskScore], dict[str, str]]:
    """Score every clip of ``root`` that has frames (``live``: see ``score_clip``); returns the scores and the
    clips skipped, each with the reason."""
    scores, skipped = [], {}
    for path in find_clips(root):
        try:
            clip = load_clip(path)
        except ValueError as error:
            skipped[path.stem.removesuffix("_Tracks")] = str(error)
            continue
        folder = frames_folder(root, clip.name)
        files = image_files(folder, FRAME_SUFFIXES) if folder else []
        try:
            scores.append(score_clip(clip, trajectory_frames(files, clip.visible.shape[1]), config, live))
        except ClipSkipped as reason:
            skipped[clip.name] = str(reason)
    return scores, skipped


def ratio(numerator: int, denominator: int) -> float:
    """numerator / denominator, NaN when the denominator is 0."""
    return numerator / denominator if denominator else float("nan")


def pooled(scores: list[ClipMaskScore]) -> dict[str, float | int]:
    """Recall, static points flagged, object-frames detected, the instances' id switches, shared and split
    object-frames over every scored point-frame (object-frame) of every clip, so that long, densely labelled clips
    weigh more than in the per-clip means."""
    object_frames = sum(s.object_frames for s in scores)
    return {"recall": ratio(sum(s.moving_hits for s in scores), sum(s.moving_points for s in scores)),
            "static_flagged": ratio(sum(s.static_hits for s in scores), sum(s.static_points for s in scores)),
            "object_frames": object_frames,
            "object_frames_detected": ratio(sum(s.object_frames_detected for s in scores), object_frames),
            "id_switches": sum(s.id_switches for s in scores),
            "shared_object_frames": sum(s.shared_object_frames for s in scores),
            "split_object_frames": sum(s.split_object_frames for s in scores)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg eval kt3dmoseg-masks`."""
    parser.add_argument("dir", type=Path, nargs="?", default=None,
                        help="KT3DMoSeg folder (Data/*.mat and OriginalSequences/); default ../shared/data/kt3dmoseg")
    parser.add_argument("--json", type=Path, help="also write the per-clip rows and means to this file")
    add_settings_arguments(parser)
    add_live_argument(parser)


def run(args: argparse.Namespace) -> int:
    """Print the per-clip table and the means; 2 without clips or without a clip that has its frames."""
    root = args.dir or default_dir()
    if not find_clips(root):
        print(no_clips_message(root))
        return 2
    config = pipeline_config(args)
    with threadpool_limits(1):
        scores, skipped = evaluate(root, config, args.live)
    if not scores:
        print(f"no KT3DMoSeg clip under {root} has readable frames (OriginalSequences/<clip>/*.png); "
              f"skipped: {', '.join(skipped)}")
        print_skipped(skipped)
        return 2
    print(f"{'clip':16s} {'frames':>6s} {'moving pts':>10s} {'static pts':>10s} {'recall %':>9s} "
          f"{'static flagged %':>16s} {'obj-frames det.':>16s} {'ms/frame':>9s}")
    for s in scores:
        print(f"{s.clip:16s} {s.frames:6d} {s.moving_points:10d} {s.static_points:10d} {100 * s.moving_recall:9.1f} "
              f"{100 * s.static_flagged:16.2f} {f'{s.object_frames_detected} / {s.object_frames}':>16s} "
              f"{s.ms_per_frame:9.1f}")
    means = {"moving_recall_mean": float(np.nanmean([s.moving_recall for s in scores])),
             "static_flagged_mean": float(np.nanmean([s.static_flagged for s in scores])),
             "clips_scored": len(scores), "clips_without_frames": list(skipped), "skipped_why": skipped}
    print(f"mean over {len(scores)} clips: moving-point recall {100 * means['moving_recall_mean']:.1f} %, "
          f"static points flagged {100 * means['static_flagged_mean']:.2f} %")
    totals = pooled(scores)
    print(f"pooled over all scored point-frames: moving-point recall {100 * totals['recall']:.1f} %, "
          f"static points flagged {100 * totals['static_flagged']:.2f} %")
    print("object-frames detected (at least half of their visible points in the mask): "
          f"{100 * totals['object_frames_detected']:.1f} % of {totals['object_frames']}")
    print(f"instances at the moving objects' points: {totals['id_switches']} id switches, "
          f"{totals['shared_object_frames']} object-frames whose instance holds another moving object, "
          f"{totals['split_object_frames']} split over two or more instances")
    print_skipped(skipped)
    for s in scores:
        if s.unreadable:
            print(f"{s.clip}: unreadable, skipped: {', '.join(s.unreadable)}")
        if s.mismatched:
            print(f"{s.clip}: frames that do not hold the trajectories, skipped: {', '.join(s.mismatched)}")
        if s.missing:
            print(f"{s.clip}: trajectory frames without a file (from 0): {', '.join(map(str, s.missing))}")
    if args.json:
        write_json(args.json, {**means, **totals, "live_hz": args.live, "clips": [asdict(s) for s in scores]})
    return 0

