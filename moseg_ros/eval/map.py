"""`moseg eval map BAG`: what our masks do to a real map builder (COLMAP through pycolmap).

COLMAP runs on the bag's frames without masks (``none``), with our dynamic masks (``ours``: from ``--masks
OUTPUT_BAG`` or made in-process) and with the ground truth's (``gt``, when the bag has ``/gt/dynamic_mask``):
SIFT with COLMAP's per-image masks, sequential matching, the global (GLOMAP) or incremental mapper. Per mode:
images registered, 3D points, reprojection error, features masked, landmarks on ground-truth movers (per mover
with ``/gt/instances``) and, against ``/gt/pose`` or ``--poses``, ATE after a similarity alignment and RPE (evo),
with a PNG of the trajectories. One thread and ``--seed``: the same inputs give the same numbers.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from moseg_ros.eval.masks import GT_DYNAMIC_TOPIC, masks_by_stamp
from moseg_ros.io.bag_images import read_images
from moseg_ros.io.bags import iter_messages, list_topics, stamp_to_ns
from moseg_ros.io.image import image_to_array
from moseg_ros.config import add_settings_arguments, pipeline_config
from moseg_ros.synth.street import GT_TOPICS
from moseg_ros.eval.colmap import export_frames, Frames, keypoints_by_image, MAPPERS, run_colmap, write_colmap_masks


MODES = ("none", "ours", "gt")
OUR_MASKS = "/segmenter/dynamic_mask"
GT_POSE_TOPIC = "/gt/pose"


def dynamic_landmark_pct(reconstruction: Any, frames: Frames, moving: dict[int, np.ndarray]) -> float:
    """Percent of 3D points with at least one observation on a ground-truth moving pixel."""
    on_mover = [points[values] for points, values in _observed(reconstruction, frames, moving)]
    total = reconstruction.num_points3D()
    return 100.0 * np.unique(np.concatenate(on_mover or [[]])).size / total if total else 0.0


def landmarks_by_instance(reconstruction: Any, frames: Frames, movers: dict[int, np.ndarray]) -> dict[int, int]:
    """Which movers leak into the map: per ground-truth instance id, the 3D points with at least one observation
    on a pixel where that instance moves (``movers``: (H, W) int ids by stamp, 0 where nothing moves); ids
    with none are left out."""
    pairs = [np.column_stack([points, ids])[ids > 0] for points, ids in _observed(reconstruction, frames, movers)]
    if not pairs:
        return {}
    ids, counts = np.unique(np.unique(np.concatenate(pairs), axis=0)[:, 1], return_counts=True)
    return dict(zip(ids.tolist(), counts.tolist()))


def _observed(reconstruction: Any, frames: Frames,
              maps: dict[int, np.ndarray]) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(point3D ids, the map's values at their observations) of every registered image whose stamp has a map
    (observations at pixel centres +0.5, COLMAP's convention)."""
    stamp_of = dict(zip(frames.names, frames.stamps))
    for image in reconstruction.images.values():
        values = maps.get(stamp_of.get(image.name, -1))
        observations = image.get_observation_points2D() if values is not None else []
        if len(observations) == 0:
            continue
        xy = np.floor(np.array([point.xy for point in observations])).astype(np.int64)
        x = xy[:, 0].clip(0, values.shape[1] - 1)
        y = xy[:, 1].clip(0, values.shape[0] - 1)
        yield np.array([point.point3D_id for point in observations], dtype=np.int64), values[y, x]


def camera_centres(reconstruction: Any, frames: Frames) -> dict[int, np.ndarray]:
    """4x4 camera-to-world of every registered image, by stamp."""
    stamp_of = dict(zip(frames.names, frames.stamps))
    poses = {}
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        T = np.eye(4)
        T[:3, :4] = image.cam_from_world().inverse().matrix()
        poses[stamp_of[image.name]] = T
    return poses


def trajectory_errors(estimated: dict[int, np.ndarray], reference: dict[int, np.ndarray]) -> dict[str, Any]:
    """ATE (RMSE of positions after a similarity alignment) and RPE (RMSE of the translation between
    consecutive frames, after the same alignment) with evo, over the stamps both have; also the aligned
    positions for plotting. None values when fewer than 3 stamps are shared."""
    from evo.core import metrics
    from evo.core.trajectory import PoseTrajectory3D

    stamps = sorted(set(estimated) & set(reference))
    if len(stamps) < 3:
        return {"ate": None, "rpe": None, "aligned": None}
    seconds = np.array(stamps, dtype=np.float64) / 1e9
    est = PoseTrajectory3D(poses_se3=[estimated[s] for s in stamps], timestamps=seconds)
    ref = PoseTrajectory3D(poses_se3=[reference[s] for s in stamps], timestamps=seconds)
    est.align(ref, correct_scale=True)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1, delta_unit=metrics.Unit.frames)
    rpe.process_data((ref, est))
    return {"ate": float(ape.get_statistic(metrics.StatisticsType.rmse)),
            "rpe": float(rpe.get_statistic(metrics.StatisticsType.rmse)), "aligned": est.positions_xyz}


def file_poses(path: Path, bag: Path) -> dict[int, np.ndarray]:
    """Ground-truth poses from a KITTI pose file (io/kitti.py's format), line i for the bag's i-th image."""
    from moseg_ros.io.kitti import parse_poses

    poses = parse_poses(path)
    stamps = [image.stamp_ns for image in read_images(bag)]
    if len(poses) < len(stamps):
        raise ValueError(f"{path} has {len(poses)} poses for the {len(stamps)} images of {bag}")
    return dict(zip(stamps, poses))


def _poses(bag: Path, pose_file: Path | None = None) -> dict[int, np.ndarray]:
    from scipy.spatial.transform import Rotation

    if pose_file is not None:
        return file_poses(pose_file, bag)
    if GT_POSE_TOPIC not in list_topics(bag):
        return {}
    poses = {}
    for _, _, msg in iter_messages(bag, [GT_POSE_TOPIC]):
        T = np.eye(4)
        q = msg.pose.orientation
        T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        T[:3, 3] = [msg.pose.position.x, msg.pose.position.y, msg.pose.position.z]
        poses[stamp_to_ns(msg.header.stamp)] = T
    return poses


def mode_metrics(reconstruction: Any | None, frames: Frames, keypoints: dict[str, np.ndarray],
                 unmasked: dict[str, np.ndarray], moving: dict[int, np.ndarray],
                 reference: dict[int, np.ndarray], movers: dict[int, np.ndarray] | None = None) -> dict[str, Any]:
    """One mode's numbers (see the module docstring); ``unmasked`` are the keypoints of the run without masks,
    ``movers`` the ground-truth instance ids where they move (``moving_instances``), when the bag has them."""
    total = sum(len(v) for v in unmasked.values())
    kept = sum(len(v) for v in keypoints.values())
    row: dict[str, Any] = {"images": len(frames.names), "images_registered": 0, "points3d": 0,
                           "reprojection_error_px": None, "features": kept,
                           "features_lost_pct": 100.0 * (total - kept) / total if total else 0.0,
                           "dynamic_landmark_pct": None, "ate": None, "rpe": None}
    if reconstruction is None:
        return row
    row.update(images_registered=reconstruction.num_reg_images(), points3d=reconstruction.num_points3D(),
               reprojection_error_px=float(reconstruction.compute_mean_reprojection_error()))
    if moving:
        row["dynamic_landmark_pct"] = dynamic_landmark_pct(reconstruction, frames, moving)
    if movers:
        row["dynamic_landmarks_by_instance"] = landmarks_by_instance(reconstruction, frames, movers)
    if reference:
        errors = trajectory_errors(camera_centres(reconstruction, frames), reference)
        row.update(ate=errors["ate"], rpe=errors["rpe"])
        row["_aligned"] = errors["aligned"]
    return row


def moving_instances(bag: Path, moving: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """(H, W) int32 ground-truth instance ids (``/gt/instances``) where ``moving`` (by stamp) is set, 0 elsewhere,
    by stamp: the movers of a synthetic bag."""
    movers = {}
    for _, _, msg in iter_messages(bag, [GT_TOPICS["instances"]]):
        stamp = stamp_to_ns(msg.header.stamp)
        if stamp in moving:
            movers[stamp] = np.where(moving[stamp], image_to_array(msg), 0).astype(np.int32)
    return movers


def _our_masks(bag: Path, masks_bag: Path | None, config: Any, work: Path) -> dict[int, np.ndarray]:
    if masks_bag is None:
        from moseg_ros.tools.bag_masks import process_bag

        masks_bag = work / "our_masks"
        process_bag(bag, masks_bag, config=config)
    return masks_by_stamp(masks_bag, OUR_MASKS)


def _check_masks_match(masks: dict[int, np.ndarray], frames: Frames, masks_bag: Path | None, bag: Path) -> None:
    """ValueError when a given masks bag has a mask at none of the frames' stamps (``ours`` would silently be a
    second unmasked run, after minutes of COLMAP); a warning when it covers only some of them."""
    matched = sum(stamp in masks for stamp in frames.stamps)
    if masks_bag is None or matched == len(frames.stamps):
        return
    if matched == 0:
        raise ValueError(f"{masks_bag} has no {OUR_MASKS} at any stamp of {bag}'s frames (masks of another bag?)")
    print(f"moseg eval map: warning: {masks_bag} has masks for {matched} of {len(frames.stamps)} frames; the others "
          "keep every feature", file=sys.stderr)


def evaluate_map(bag: Path, *, masks_bag: Path | None = None, mapper: str = "global", every: int = 1,
                 config: Any = None, work: Path | None = None, progress: bool = True,
                 pose_file: Path | None = None, seed: int = 0) -> dict[str, Any]:
    """Run COLMAP per mode on ``bag`` and return {mode: metrics} (modes without masks are left out); the
    ground-truth poses come from ``pose_file`` (a KITTI pose file) when given, else the bag's /gt/pose. Each
    mode's COLMAP draws from ``seed``: the same bag, masks and seed give the same numbers (``run_colmap``)."""
    from moseg_ros.pipeline import PipelineConfig

    import pycolmap

    if mapper not in MAPPERS:
        raise ValueError(f"unknown mapper {mapper!r}; use one of {MAPPERS}")
    if progress:  # COLMAP's own log (a line per image and step) would bury the progress bar
        pycolmap.logging.minloglevel = int(pycolmap.logging.Level.WARNING)
    bag = Path(bag)
    with tempfile.TemporaryDirectory(prefix="moseg-map-") as tmp:
        work = Path(work or tmp)
        frames = export_frames(bag, work / "images", every)
        topics = list_topics(bag)
        truth = masks_by_stamp(bag, GT_DYNAMIC_TOPIC) if GT_DYNAMIC_TOPIC in topics else {}
        movers = moving_instances(bag, truth) if GT_TOPICS["instances"] in topics else {}
        reference = _poses(bag, pose_file)
        sources = {"none": None, "ours": _our_masks(bag, masks_bag, config or PipelineConfig(), work)}
        _check_masks_match(sources["ours"], frames, masks_bag, bag)
        if truth:
            sources["gt"] = truth
        results, unmasked = {}, {}
        for step, (mode, dynamic) in enumerate(sources.items(), start=1):
            if progress:
                print(f"\r[{'#' * step}{'.' * (len(sources) - step)}] COLMAP {mode} ({step}/{len(sources)})",
                      end="", file=sys.stderr, flush=True)
            masks = None
            if dynamic is not None:
                masks = work / f"masks_{mode}"
                write_colmap_masks(frames, dynamic, masks)
            reconstruction = run_colmap(frames, work / mode, masks, mapper, seed)
            keypoints = keypoints_by_image(work / mode / "database.db")
            unmasked = unmasked or keypoints
            results[mode] = mode_metrics(reconstruction, frames, keypoints, unmasked, truth, reference, movers)
        if progress:
            print(file=sys.stderr)
    return results


def plot_trajectories(results: dict[str, Any], reference: np.ndarray | None, path: Path) -> None:
    """Top view (x, z) of each mode's aligned camera positions over the ground truth, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6, 6))
    if reference is not None:
        axes.plot(reference[:, 0], reference[:, 2], "k-", linewidth=2, label="ground truth")
    for mode, row in results.items():
        aligned = row.get("_aligned")
        if aligned is not None:
            axes.plot(aligned[:, 0], aligned[:, 2], ".-", markersize=3, label=f"{mode} (ATE {row['ate']:.3f})")
    axes.set_xlabel("x")
    axes.set_ylabel("z")
    axes.axis("equal")
    axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg eval map`."""
    parser.add_argument("bag", type=Path, help="input bag with the camera images (and /gt/pose, /gt/dynamic_mask)")
    parser.add_argument("--masks", type=Path, metavar="OUTPUT_BAG",
                        help="our masks: an output bag of `moseg process`/`replay` (default: run the method now)")
    parser.add_argument("--mapper", choices=MAPPERS, default="global", help="COLMAP's mapper (default: global)")
    parser.add_argument("--every", type=int, default=1, help="take every N-th frame (default 1)")
    parser.add_argument("--poses", type=Path, metavar="FILE",
                        help="ground-truth poses: a KITTI pose file, line i for the bag's i-th image (default: "
                             "the bag's /gt/pose)")
    parser.add_argument("--seed", type=int, default=0,
                        help="COLMAP's random seed: the same bag, masks and seed give the same numbers (default 0)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the results here (and the plot beside)")
    add_settings_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Print the results per mode; exit 2 when the bag cannot be used."""
    if args.every < 1:
        print(f"moseg eval map: error: --every must be >= 1, got {args.every}", file=sys.stderr)
        return 2
    try:
        results = evaluate_map(args.bag, masks_bag=args.masks, mapper=args.mapper, every=args.every,
                               config=pipeline_config(args), pose_file=args.poses, seed=args.seed)
    except (FileNotFoundError, ValueError) as error:
        print(f"moseg eval map: error: {error}", file=sys.stderr)
        return 2
    printable = {mode: {k: v for k, v in row.items() if not k.startswith("_")} for mode, row in results.items()}
    print(json.dumps(printable, indent=2))
    if args.json:
        args.json.write_text(json.dumps(printable, indent=2) + "\n")
        reference = _poses(args.bag, args.poses)
        positions = np.array([reference[s][:3, 3] for s in sorted(reference)]) if reference else None
        plot_trajectories(results, positions, args.json.with_suffix(".png"))
    return 0
