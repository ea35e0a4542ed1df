"""Shared fixtures: real-data location, private ROS domains, small textured scenes."""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from moseg_ros.core.track_tests.cheirality import guessed_camera_matrix

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
_domains = itertools.count()


def shared_data(*parts: str) -> Path:
    """A path under ../shared/data, skipping the calling test with the reason when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data absent: {path} (../shared/data is only beside the repository in development/CI)")
    return path


@pytest.fixture
def ros_domain() -> int:
    """A ROS domain id no other test of this run (or a parallel run with another pid) is using."""
    return 1 + (os.getpid() * 13 + next(_domains)) % 100


def textured_frames(n: int, height: int = 188, width: int = 621, seed: int = 0,
                    mover_speed_px: int = 3, stop: int | None = None,
                    block_x: int | None = None) -> list[np.ndarray]:
    """Frames of a camera panning over a random texture, with a block sliding down across it.

    The background shifts 2 px left per frame (one rigid motion, horizontal epipolar lines); the block
    moves ``mover_speed_px`` px down per frame, off those lines, so it is an independent motion. With
    ``stop`` it parks at that frame: from then on it rides with the background. ``block_x``: the block's left
    edge (default a quarter of the width).
    """
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur((rng.random((height, width + 4 * n)) * 255).astype(np.uint8), (5, 5), 0)
    block = cv2.GaussianBlur((rng.random((height // 3, width // 8)) * 255).astype(np.uint8), (5, 5), 0)
    frames = []
    for i in range(n):
        frame = texture[:, 2 * i:2 * i + width].copy()
        parked = 0 if stop is None else max(0, i - stop)
        x = (width // 4 if block_x is None else block_x) - 2 * parked
        y = height // 6 + mover_speed_px * (i - parked)
        frame[y:y + block.shape[0], x:x + block.shape[1]] = block[:height - y]
        frames.append(np.repeat(frame[..., None], 3, axis=2))
    return frames


@pytest.fixture
def textured_bag(tmp_path: Path) -> Path:
    """A 20-frame rgb8 bag at 10 Hz on /camera/image_raw with camera_info."""
    from moseg_ros.io.bag_writer import BagWriter

    path = tmp_path / "textured"
    k = np.array([[500.0, 0, 310], [0, 500, 94], [0, 0, 1]])
    with BagWriter(path) as writer:
        for i, frame in enumerate(textured_frames(20)):
            stamp = 1_700_000_000_000_000_000 + i * 100_000_000
            writer.write_image("/camera/image_raw", stamp, "camera_optical", frame, "rgb8", log_time_ns=stamp)
            writer.write_camera_info("/camera/camera_info", stamp, "camera_optical", k, 621, 188,
                                     log_time_ns=stamp)
    return path


def pan_follow_flow(height: int = 120, width: int = 320, degrees: float = 1.0):
    """The dense flow (current -> previous frame) of the pan after a car above (turning ``degrees`` a frame):
    static surfaces 12-40 m away and the car, a block of pixels whose flow is zero. Returns to_previous
    (H, W, 2), is_car (H, W), K."""
    K_flow = guessed_camera_matrix((height, width))
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    depth = 26.0 + 14.0 * np.sin(xs / 37.0) * np.cos(ys / 23.0)
    rays = np.stack([xs, ys, np.ones_like(xs)], axis=-1) @ np.linalg.inv(K_flow).T
    angle = -np.deg2rad(degrees)
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    world = (rays * depth[..., None]) @ R + np.array([0.2, 0.0, 0.0])  # R^T X_c + c of the current camera
    seen = world @ K_flow.T
    to_previous = (seen[..., :2] / seen[..., 2:] - np.stack([xs, ys], axis=-1)).astype(np.float32)
    is_car = np.zeros((height, width), bool)
    is_car[50:90, 130:200] = True
    to_previous[is_car] = 0.0
    return to_previous, is_car, K_flow


def oncoming_street_flow(height: int = 120, width: int = 320, oncoming: bool = True, lateral: float = 0.0):
    """The dense flow (current -> previous frame) of the street of ``oncoming_street``, ray-cast per pixel: a camera
    1.5 m above a flat road that drove 1 m forward (and ``lateral`` m to the right) since the previous frame,
    between walls at x = +-6 m; the front faces of a car parked 15 m ahead on the right and, in the left lane, of
    a car 16 m ahead that drove 1 m towards the camera (``oncoming``; else parked there too). Returns
    to_previous (H, W, 2), is_parked (H, W), is_oncoming (H, W), K."""
    K_flow = np.array([[300.0, 0.0, width / 2], [0.0, 300.0, height / 2], [0.0, 0.0, 1.0]])
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([xs, ys, np.ones_like(xs)], axis=-1) @ np.linalg.inv(K_flow).T  # z = 1
    with np.errstate(divide="ignore"):
        hits = [np.where(rays[..., 1] > 0, 1.5 / rays[..., 1], np.inf),  # the road (y = 1.5 m, y points down)
                np.where(rays[..., 0] != 0, 6.0 / np.abs(rays[..., 0]), np.inf)]  # the walls
    depth = np.minimum(np.minimum(*hits), 200.0)
    is_face = []
    for x0, x1, z in ((3.0, 4.8, 15.0), (-3.5, -1.7, 16.0)):
        x, y = rays[..., 0] * z, rays[..., 1] * z
        face = (x >= x0) & (x <= x1) & (y >= 0.0) & (y <= 1.5) & (z < depth)
        depth[face] = z
        is_face.append(face)
    world = rays * depth[..., None]
    world[..., 2] += 1.0  # where the current frame's points lay in the previous camera's frame
    world[..., 0] += lateral
    if oncoming:
        world[is_face[1], 2] += 1.0  # the car was 1 m farther
    seen = world @ K_flow.T
    to_previous = (seen[..., :2] / seen[..., 2:] - np.stack([xs, ys], axis=-1)).astype(np.float32)
    return to_previous, is_face[0], is_face[1], K_flow
