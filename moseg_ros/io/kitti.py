"""Convert a KITTI raw drive or odometry sequence to a rosbag2 MCAP bag (Image + CameraInfo, real stamps,
ground-truth poses when there is a pose file).

Layouts (detected from SRC):
  raw        SRC/image_0X/data/*.png, SRC/image_0X/timestamps.txt, calib_cam_to_cam.txt in SRC or its parent
  odometry   SRC/image_X/*.png, SRC/times.txt (seconds from the start), SRC/calib.txt (PX)
Grey PNGs are written as mono8, colour ones as rgb8, each with a camera_info at the same stamp. Poses (--poses
FILE, or found beside the sequence: dataset/poses/XX.txt, SRC/../poses/XX.txt, SRC/poses*.txt) go on /gt/pose
(camera-to-world, "world"): line i is frame i, 12 numbers (row-major 3x4 [R|t]) or 13 with a leading timestamp.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

from moseg_ros.io.bag_writer import BagWriter

__all__ = ["KittiSequence", "find_sequence", "parse_calib", "parse_raw_timestamps", "find_poses", "parse_poses",
           "kitti_to_bag", "add_arguments", "run"]

_NS = 1_000_000_000
POSE_TOPIC = "/gt/pose"
WORLD_FRAME = "world"


@dataclasses.dataclass(frozen=True)
class KittiSequence:
    """One camera of a KITTI sequence: frames in order, their stamps and the camera model."""

    layout: str                 # "raw" or "odometry"
    camera: str                 # "02" (raw) or "0" (odometry), ...
    images: tuple[Path, ...]
    indices: tuple[int, ...]    # frame number of each image (its file name), ascending
    stamps_ns: tuple[int, ...]  # one per image
    K: np.ndarray               # (3, 3)
    P: np.ndarray               # (3, 4)
    D: np.ndarray               # (5,) plumb_bob, zeros for rectified images
    size: tuple[int, int] | None  # (width, height) from the calibration, None when it gives none


def parse_calib(path: Path) -> dict[str, str]:
    """``KEY: values`` lines of a KITTI calibration file (values left as text, parsed by :func:`calib_matrix`)."""
    if not path.is_file():
        raise FileNotFoundError(f"KITTI calibration file not found: {path}")
    entries: dict[str, str] = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, value = line.partition(":")
        if not sep or not key.strip():
            raise ValueError(f"{path}:{number}: bad calibration line (expected 'KEY: values'): {line!r}")
        entries[key.strip()] = value.strip()
    return entries


def calib_matrix(entries: dict[str, str], key: str, shape: tuple[int, ...], source: Path) -> np.ndarray:
    """Entry ``key`` of a parsed calibration file as a float array of ``shape``; ValueError naming the problem."""
    if key not in entries:
        raise ValueError(f"{source}: no {key!r} line (keys: {sorted(entries)})")
    try:
        values = np.array([float(v) for v in entries[key].split()])
    except ValueError:
        raise ValueError(f"{source}: {key} is not a list of numbers: {entries[key]!r}") from None
    if values.size != int(np.prod(shape)):
        raise ValueError(f"{source}: {key} has {values.size} numbers, expected {int(np.prod(shape))}")
    return values.reshape(shape)


def parse_raw_timestamps(path: Path) -> list[int]:
    """UTC nanoseconds of KITTI raw ``timestamps.txt`` lines ("2011-09-26 13:02:25.964389445")."""
    if not path.is_file():
        raise FileNotFoundError(f"KITTI raw timestamps not found: {path}")
    stamps = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        # datetime keeps microseconds only, so the 9-digit fraction is parsed on its own.
        whole, _, fraction = line.strip().partition(".")
        try:
            moment = dt.datetime.strptime(whole, "%Y-%m-%d %H:%M:%S").replace(tzinfo=dt.timezone.utc)
            if fraction and not fraction.isdigit():
                raise ValueError(fraction)
        except ValueError:
            raise ValueError(f"{path}:{number}: bad timestamp {line.strip()!r} "
                             "(expected 'YYYY-MM-DD HH:MM:SS.fffffffff')") from None
        nanos = int(fraction[:9].ljust(9, "0")) if fraction else 0
        stamps.append(int(moment.timestamp()) * _NS + nanos)
    return stamps


def parse_odometry_times(path: Path) -> list[int]:
    """Nanoseconds from the start of KITTI odometry ``times.txt`` lines (seconds, one per frame)."""
    if not path.is_file():
        raise FileNotFoundError(f"KITTI odometry times not found: {path}")
    stamps = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.strip():
            try:
                stamps.append(round(float(line) * _NS))
            except ValueError:
                raise ValueError(f"{path}:{number}: bad time {line.strip()!r} (expected seconds)") from None
    return stamps


def _frames(folder: Path, stamps: list[int], stamp_file: Path,
            limit: int | None) -> tuple[tuple[Path, ...], tuple[int, ...], tuple[int, ...]]:
    """PNG frames of ``folder`` in index order, their frame numbers and the stamp of each (line i of the stamp
    file is frame i)."""
    images = sorted(folder.glob("*.png"))
    if not images:
        raise FileNotFoundError(f"no .png frames in {folder}")
    try:
        indices = [int(p.stem) for p in images]
    except ValueError:
        raise ValueError(f"frame names in {folder} must be frame numbers like 000042.png") from None
    order = np.argsort(indices, kind="stable")
    images = [images[i] for i in order][:limit]
    indices = [indices[i] for i in order][:limit]
    if indices[-1] >= len(stamps):
        raise ValueError(f"timestamp count mismatch: {stamp_file} has {len(stamps)} entries but frame "
                         f"{images[-1].name} needs entry {indices[-1] + 1}")
    return tuple(images), tuple(indices), tuple(stamps[i] for i in indices)


def _pick_camera(src: Path, names: list[str], requested: str | None, preferred: str) -> str:
    present = [name for name in names if (src / f"image_{name}").is_dir()]
    if requested is not None:
        if requested not in present:
            raise FileNotFoundError(f"camera {requested!r}: no {src / f'image_{requested}'} "
                                    f"(present: {[f'image_{n}' for n in present]})")
        return requested
    return preferred if preferred in present else present[0]


def find_sequence(src: str | Path, *, camera: str | int | None = None, limit: int | None = None) -> KittiSequence:
    """Detect the layout of ``src`` and read its frames list, stamps and calibration (``limit`` first frames)."""
    src = Path(src)
    if not src.is_dir():
        raise FileNotFoundError(f"KITTI folder not found: {src}")
    if limit is not None and limit <= 0:
        raise ValueError(f"limit must be positive, got {limit}")
    if camera is not None and not str(camera).isdigit():
        raise ValueError(f"camera must be a camera number like 0 or 02, got {camera!r}")
    raw_cams = [f"{i:02d}" for i in range(4)]
    odo_cams = [str(i) for i in range(4)]
    if any((src / f"image_{c}" / "data").is_dir() for c in raw_cams):
        cam = _pick_camera(src, raw_cams, None if camera is None else f"{int(camera):02d}", "02")
        folder = src / f"image_{cam}"
        stamp_file = folder / "timestamps.txt"
        images, indices, stamps = _frames(folder / "data", parse_raw_timestamps(stamp_file), stamp_file, limit)
        calib_path = next((p for p in (src / "calib_cam_to_cam.txt", src.parent / "calib_cam_to_cam.txt")
                           if p.is_file()), src.parent / "calib_cam_to_cam.txt")
        calib = parse_calib(calib_path)
        size_rect = tuple(int(v) for v in calib_matrix(calib, f"S_rect_{cam}", (2,), calib_path))
        first = cv2.imread(str(images[0]), cv2.IMREAD_UNCHANGED)
        if first is not None and (first.shape[1], first.shape[0]) != size_rect and f"K_{cam}" in calib:
            # Unrectified ("extract") frames: the raw camera matrix and its distortion apply.
            K = calib_matrix(calib, f"K_{cam}", (3, 3), calib_path)
            D = calib_matrix(calib, f"D_{cam}", (5,), calib_path)
            size = tuple(int(v) for v in calib_matrix(calib, f"S_{cam}", (2,), calib_path))
            return KittiSequence("raw", cam, images, indices, stamps, K, np.hstack([K, np.zeros((3, 1))]), D, size)
        P = calib_matrix(calib, f"P_rect_{cam}", (3, 4), calib_path)
        return KittiSequence("raw", cam, images, indices, stamps, P[:, :3].copy(), P, np.zeros(5), size_rect)
    if any((src / f"image_{c}").is_dir() for c in odo_cams):
        cam = _pick_camera(src, odo_cams, None if camera is None else str(int(camera)), "0")
        stamp_file = src / "times.txt"
        images, indices, stamps = _frames(src / f"image_{cam}", parse_odometry_times(stamp_file), stamp_file, limit)
        calib_path = src / "calib.txt"
        P = calib_matrix(parse_calib(calib_path), f"P{cam}", (3, 4), calib_path)
        return KittiSequence("odometry", cam, images, indices, stamps, P[:, :3].copy(), P, np.zeros(5), None)
    raise FileNotFoundError(f"{src} is neither a KITTI raw drive (image_0X/data/) nor an odometry sequence (image_X/)")


def _pose_candidates(src: Path) -> list[Path]:
    """Where the pose file of sequence folder ``src`` is looked for, in order (KITTI odometry's place first)."""
    src = src.resolve()
    name = f"{src.name}.txt"
    beside = sorted(src.glob("poses*.txt")) if src.is_dir() else []  # e.g. poses_07_with_timestamps.txt
    return list(dict.fromkeys([src.parent.parent / "poses" / name, src.parent / "poses" / name,
                               src / "poses" / name, src / "poses.txt", *beside[:1]]))


def find_poses(src: str | Path) -> Path | None:
    """The ground-truth pose file of sequence folder ``src``, or None when there is none.

    Looked for as KITTI odometry keeps it (dataset/poses/07.txt for dataset/sequences/07), then as
    SRC/../poses/07.txt, SRC/poses/07.txt, SRC/poses.txt and the first SRC/poses*.txt by name.
    """
    return next((path for path in _pose_candidates(Path(src)) if path.is_file()), None)


def parse_poses(path: str | Path) -> np.ndarray:
    """Camera-to-world transforms (N, 4, 4) of a KITTI pose file, line i = frame i.

    Each line is 12 numbers, the row-major 3x4 [R|t] (KITTI odometry ground truth), or 13: a timestamp
    (ignored), then the 12; all lines alike, trailing blank lines ignored. A line that is not numbers, has
    another count or whose R is not a proper rotation raises ValueError naming the file and line.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"KITTI pose file not found: {path}")
    lines = path.read_text().splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise ValueError(f"{path}: no poses (empty file)")
    rows: list[list[float]] = []
    width = 0  # values per line, as on line 1
    for number, line in enumerate(lines, start=1):
        try:
            values = [float(v) for v in line.split()]
        except ValueError:
            raise ValueError(f"{path}:{number}: not a list of numbers: {line.strip()!r}") from None
        if len(values) not in (12, 13):
            raise ValueError(f"{path}:{number}: {len(values)} values, expected 12 (row-major 3x4 [R|t]) "
                             "or 13 (timestamp, then the 12)")
        if rows and len(values) != width:
            raise ValueError(f"{path}:{number}: {len(values)} values, but line 1 has {width}")
        width = len(values)
        rows.append(values[-12:])
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = np.array(rows).reshape(-1, 3, 4)
    rotations = poses[:, :3, :3]
    # The tolerance of BagWriter.write_pose, so every pose accepted here can be written.
    orthonormal = np.isclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-5).all(axis=(1, 2))
    proper = orthonormal & (np.linalg.det(rotations) > 0)
    if not proper.all():
        bad = int(np.argmin(proper))
        raise ValueError(f"{path}:{bad + 1}: the 3x3 part is not a rotation matrix "
                         f"(det {np.linalg.det(rotations[bad]):.6g}, rows {rotations[bad].tolist()})")
    return poses


def _read_frame(path: Path) -> tuple[np.ndarray, str]:
    """(pixels, encoding) of a KITTI PNG: grey -> mono8, colour -> rgb8."""
    pixels = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        raise ValueError(f"cannot read image {path}")
    if pixels.dtype != np.uint8:
        raise ValueError(f"{path}: expected an 8-bit PNG, got {pixels.dtype}")
    if pixels.ndim == 2:
        return pixels, "mono8"
    if pixels.shape[2] == 3:
        return cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB), "rgb8"
    raise ValueError(f"{path}: expected a grey or RGB PNG, got {pixels.shape[2]} channels")


def kitti_to_bag(src: str | Path, dst: str | Path, *, topic: str = "/camera/image_raw",
                 info_topic: str = "/camera/camera_info", frame_id: str = "camera",
                 camera: str | int | None = None, limit: int | None = None, poses: str | Path | None = None,
                 storage: str = "mcap") -> dict[str, int]:
    """Write ``src`` (KITTI raw or odometry) as a rosbag2 folder ``dst``; returns messages written per topic.

    Every frame keeps its size; a frame whose size differs from the first (or from the calibration's
    S_rect) raises, since one camera_info cannot describe both. The pose file ``poses`` (default: the one
    :func:`find_poses` finds, if any) adds one /gt/pose per frame at its image's stamp; its problems (see
    :func:`parse_poses`, or fewer lines than the frames need) raise before the bag is created.
    """
    sequence = find_sequence(src, camera=camera, limit=limit)
    pose_file = find_poses(src) if poses is None else Path(poses)
    frame_poses: list[np.ndarray | None] = [None] * len(sequence.images)
    if pose_file is not None:
        table = parse_poses(pose_file)
        if sequence.indices[-1] >= len(table):
            raise ValueError(f"pose count mismatch: {pose_file} has {len(table)} poses but frame "
                             f"{sequence.images[-1].name} needs line {sequence.indices[-1] + 1}")
        frame_poses = list(table[list(sequence.indices)])
    size = sequence.size
    writer = BagWriter(dst, storage=storage)
    try:
        with writer:
            _write_sequence(writer, sequence, frame_poses, size, topic, info_topic, frame_id)
    except BaseException:
        # Closed, a bag cut short by a bad frame (or by Ctrl-C) looks complete, and blocks the rerun: remove it.
        shutil.rmtree(dst, ignore_errors=True)
        raise
    return dict(writer.counts)


def _write_sequence(writer: BagWriter, sequence: KittiSequence, frame_poses: list[np.ndarray | None],
                    size: tuple[int, int] | None, topic: str, info_topic: str, frame_id: str) -> None:
    """Each frame's image, camera_info and (when known) pose; ValueError for a frame that cannot be read or whose
    size differs from the first's (or the calibration's)."""
    for path, stamp, pose in zip(sequence.images, sequence.stamps_ns, frame_poses):
        pixels, encoding = _read_frame(path)
        frame_size = (pixels.shape[1], pixels.shape[0])
        if size is None:
            size = frame_size
        elif frame_size != size:
            raise ValueError(f"{path} is {frame_size[0]}x{frame_size[1]}, expected {size[0]}x{size[1]}")
        writer.write_image(topic, stamp, frame_id, pixels, encoding)
        writer.write_camera_info(info_topic, stamp, frame_id, sequence.K, size[0], size[1],
                                 D=sequence.D, P=sequence.P)
        if pose is not None:
            writer.write_pose(POSE_TOPIC, stamp, WORLD_FRAME, pose)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `moseg kitti2bag`."""
    parser.add_argument("src", type=Path,
                        help="KITTI raw drive folder (image_02/data, ...) or odometry sequence folder")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output rosbag2 folder (must not exist)")
    parser.add_argument("--topic", default="/camera/image_raw", help="image topic (default %(default)s)")
    parser.add_argument("--info-topic", default="/camera/camera_info", help="camera_info topic (default %(default)s)")
    parser.add_argument("--frame-id", default="camera", help="header frame_id (default %(default)s)")
    parser.add_argument("--camera", default=None,
                        help="camera number: raw 00-03 (default 02), odometry 0-3 (default 0); first present otherwise")
    parser.add_argument("--limit", type=int, default=None, help="convert only the first N frames")
    parser.add_argument("--poses", type=Path, default=None, metavar="FILE",
                        help="KITTI pose file written on /gt/pose (PoseStamped, camera-to-world, frame_id world, at "
                             "the image stamps): line i = frame i, 12 numbers (row-major 3x4 [R|t]) or 13 (a "
                             "timestamp, then the 12). Default: dataset/poses/XX.txt of an odometry "
                             "dataset/sequences/XX, else SRC/../poses/XX.txt, SRC/poses/XX.txt, SRC/poses.txt or "
                             "SRC/poses*.txt; "
                             "none found: no /gt/pose")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                        help="bag storage (default %(default)s)")


def run(args: argparse.Namespace) -> int:
    """Run `moseg kitti2bag`; prints the counts, returns 0, or 2 with a message on bad input."""
    try:
        counts = kitti_to_bag(args.src, args.output, topic=args.topic, info_topic=args.info_topic,
                              frame_id=args.frame_id, camera=args.camera, limit=args.limit, poses=args.poses,
                              storage=args.storage)
    except (FileNotFoundError, FileExistsError, ValueError) as err:
        print(f"kitti2bag: error: {err}", file=sys.stderr)
        return 2
    for topic, count in counts.items():
        print(f"{topic}: {count} messages")
    if POSE_TOPIC not in counts:
        print(f"{POSE_TOPIC}: no pose file found (looked for {', '.join(map(str, _pose_candidates(args.src)))}; "
              "give one with --poses)")
    print(f"wrote {args.output}")
    return 0
