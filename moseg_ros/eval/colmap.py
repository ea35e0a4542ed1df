"""COLMAP through pycolmap on a bag's frames: frames and masks exported, SIFT with per-image masks, sequential
matching, the global (GLOMAP) or incremental mapper, on one thread and a seed (the same inputs, the same map)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from moseg_ros.io.bag_images import image_camera, read_images


MAPPERS = ("global", "incremental")


@dataclasses.dataclass(frozen=True)
class Frames:
    """The frames exported for COLMAP: image names in order, their stamps and the camera matrix (or None)."""

    folder: Path
    names: list[str]
    stamps: list[int]
    camera_matrix: np.ndarray | None
    shape: tuple[int, int]


def export_frames(bag: Path, folder: Path, every: int = 1) -> Frames:
    """Write every ``every``-th image of the bag as PNG (``frame_000000.png`` ...) into ``folder``; the camera
    matrix is the first valid K of the camera_info beside the image topic for the images' size (as ``moseg
    process`` gives the frames theirs), None without one (COLMAP then estimates the focal length)."""
    folder.mkdir(parents=True, exist_ok=True)
    topic, calibration = image_camera(bag)
    names, stamps, shape, K = [], [], (0, 0), None
    for i, image in enumerate(read_images(bag, topic)):
        if i % every:
            continue
        rgb = image.rgb()
        shape = rgb.shape[:2]
        if K is None:
            K = calibration.at(image.log_time_ns, shape)
        name = f"frame_{len(names):06d}.png"
        cv2.imwrite(str(folder / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        names.append(name)
        stamps.append(image.stamp_ns)
    if len(names) < 3:
        raise ValueError(f"{bag}: {len(names)} frames taken (every {every}); a map needs at least 3")
    return Frames(folder, names, stamps, K, shape)


def write_colmap_masks(frames: Frames, dynamic: dict[int, np.ndarray], folder: Path) -> int:
    """COLMAP mask images (``<image name>.png``: 0 = no features here, 255 = keep) from dynamic masks by stamp.

    A frame without a mask keeps everything. Returns how many frames had a mask.
    """
    folder.mkdir(parents=True, exist_ok=True)
    found = 0
    for name, stamp in zip(frames.names, frames.stamps):
        moving = dynamic.get(stamp)
        keep = np.full(frames.shape, 255, np.uint8)
        if moving is not None:
            keep[cv2.resize(moving.astype(np.uint8), frames.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0] = 0
            found += 1
        cv2.imwrite(str(folder / f"{name}.png"), keep)
    return found


def run_colmap(frames: Frames, work: Path, masks: Path | None, mapper: str = "global",
               seed: int = 0) -> Any | None:
    """Features (masked by ``masks`` when given), sequential matching and a mapper; the largest reconstruction
    (pycolmap.Reconstruction) or None when nothing was reconstructed. The database stays in ``work``.

    Every step runs on one thread and draws from ``seed``, so the same frames, masks and seed give the same
    map: on several threads COLMAP numbers the images in the order their features are done, and matching and
    the mapper follow the ids (docs/experiments.md: the spread it gave)."""
    import pycolmap

    pycolmap.set_random_seed(seed)
    database = extract_features(frames, work, masks)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = 1
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = seed
    pycolmap.match_sequential(database, matching_options=matching, verification_options=verification,
                              device=pycolmap.Device.cpu)
    output = work / "sparse"
    output.mkdir(exist_ok=True)
    if mapper == "global":
        reconstructions = pycolmap.global_mapping(database, frames.folder, output, options=_global_options(seed))
    else:
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads, options.random_seed = 1, seed
        # Driving straight ahead, every pair's forward share of the motion exceeds COLMAP's 0.95 bound on the
        # initial pair, and small steps give triangulation angles of a few degrees.
        options.mapper.init_max_forward_motion = 1.0
        options.mapper.init_min_tri_angle = 4.0
        reconstructions = pycolmap.incremental_mapping(database, frames.folder, output, options=options)
    if not reconstructions:
        return None
    return max(reconstructions.values(), key=lambda r: r.num_reg_images())


def _global_options(seed: int) -> Any:
    """The global mapper's options on one thread, every random draw of it from ``seed``."""
    import pycolmap

    options = pycolmap.GlobalPipelineOptions()
    options.num_threads, options.random_seed = 1, seed
    mapper = options.mapper
    mapper.num_threads, mapper.random_seed = 1, seed
    mapper.rotation_averaging.random_seed = seed
    mapper.global_positioning.random_seed = seed
    mapper.retriangulation.random_seed = seed
    mapper.bundle_adjustment.ceres.solver_options.num_threads = 1
    return options


def extract_features(frames: Frames, work: Path, masks: Path | None) -> Path:
    """SIFT features of the frames into ``work/database.db`` (one pinhole camera from K when known), none on
    the pixels ``masks`` (COLMAP mask images) set to 0; returns the database path."""
    import pycolmap

    work.mkdir(parents=True, exist_ok=True)
    database = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    if frames.camera_matrix is not None:
        reader.camera_model, reader.camera_params = colmap_camera(frames.camera_matrix)
    if masks is not None:
        reader.mask_path = str(masks)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = 4096
    extraction.num_threads = 1  # see run_colmap
    pycolmap.extract_features(database, frames.folder, image_names=frames.names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    return database


def colmap_camera(K: np.ndarray) -> tuple[str, str]:
    """COLMAP camera model and parameters for a ROS camera matrix (principal point +0.5: ROS and OpenCV put
    pixel centres at integers, COLMAP at halves).

    Square pixels (f_x, f_y within 1 %) give SIMPLE_PINHOLE, one focal length that bundle adjustment refines:
    with f_x and f_y apart, a level camera that only yaws (a car on flat ground, the synthetic street) leaves
    f_y unobservable (scaling every height by s and f_y by 1/s changes no projection), it drifts (721 -> 224
    px) and the global mapper drops every track. Other cameras get PINHOLE with both focal lengths.
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5
    if abs(fx - fy) <= 0.01 * max(fx, fy):
        return "SIMPLE_PINHOLE", f"{(fx + fy) / 2},{cx},{cy}"
    return "PINHOLE", f"{fx},{fy},{cx},{cy}"


def keypoints_by_image(database: Path) -> dict[str, np.ndarray]:
    """(N, 2) keypoint positions (x, y, pixel centres at +0.5) per image name, from a COLMAP database."""
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        return {image.name: np.asarray(db.read_keypoints(image.image_id))[:, :2] for image in db.read_all_images()}
    finally:
        db.close()
