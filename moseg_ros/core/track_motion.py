"""Which point trajectories move by themselves: a robust epipolar test per track over a window.

The camera's own motion is the dominant rigid motion of the tracked points, so for every frame pair (m, m+g)
of the window a RANSAC fundamental matrix is fitted to the tracks seen in both frames, and every track gets
its Sampson distance (Hartley & Zisserman eq. 11.9, in pixels) under it. A track moves when the median of its
distances over the pairs it spans exceeds ``max(factor x the median over all tracks, floor)``: the median
over pairs forgives one bad pair (a KLT slip), the median over tracks scales the threshold with the window's
noise. When one homography explains about as many tracks as F does (a camera that only rotates, or a scene
that is mostly one plane), F is not determined by the data and a wrong member of its family can swallow a
mover; the distance is then the homography's transfer error (the model-selection idea of Torr's GRIC, as in
core/baseline.py). This is the residual test; it is blind to motion inside the epipolar plane, which the
object-level flow view has to catch.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core.geometry import homography_transfer_error, sampson_distance


@dataclass(frozen=True)
class TrackMotionConfig:
    """Settings of the per-track epipolar test (pixels at the tracking resolution)."""

    gap: int = 2
    ransac_px: float = 1.0
    factor: float = 3.0
    floor_px: float = 1.0
    min_tracks: int = 20
    min_parallax_px: float = 0.5
    homography_preference: float = 0.9


def pair_residual(x1: np.ndarray, x2: np.ndarray,
                  config: TrackMotionConfig = TrackMotionConfig()) -> np.ndarray | None:
    """Distance of N correspondences from the dominant motion fitted to them by RANSAC (MAGSAC++).

    Sampson distance under F, or the symmetric transfer error under a homography when one explains at least
    ``homography_preference`` as many correspondences as F (F is then degenerate).

    Args:
        x1: (N, 2) positions in the earlier frame.
        x2: (N, 2) the same points in the later frame.
        config: RANSAC threshold, smallest usable number of tracks and parallax.

    Returns:
        (N,) float32 distances in pixels, or None when there are too few points, too little parallax (the
        geometry is not determined) or RANSAC finds no model.
    """
    if len(x1) < config.min_tracks:
        return None
    x1, x2 = np.asarray(x1, dtype=np.float64), np.asarray(x2, dtype=np.float64)
    if np.median(np.linalg.norm(x2 - x1, axis=1)) < config.min_parallax_px:
        return None
    fundamental, f_inliers = cv2.findFundamentalMat(x1, x2, cv2.USAC_MAGSAC, config.ransac_px, 0.999, 1000)
    if fundamental is None or fundamental.shape != (3, 3) or f_inliers is None:
        return None
    homography, h_inliers = cv2.findHomography(x1, x2, cv2.USAC_MAGSAC, config.ransac_px)
    if homography is not None and h_inliers is not None and (
            h_inliers.sum() >= config.homography_preference * f_inliers.sum()):
        return np.sqrt(0.5 * homography_transfer_error(homography[None], x1, x2)[0]).astype(np.float32)
    # cv2's F satisfies x2^T F x1 = 0, the convention of geometry.sampson_distance(F, x1, x2).
    return np.sqrt(sampson_distance(fundamental[None], x1, x2)[0]).astype(np.float32)


def pair_residuals(tracks: np.ndarray, visible: np.ndarray,
                   config: TrackMotionConfig = TrackMotionConfig()) -> np.ndarray:
    """Sampson distance of every track under the dominant F of every frame pair (m, m + gap) of a window.

    Args:
        tracks: (N, F, 2) positions (x, y), NaN where not visible.
        visible: (N, F) bool.
        config: the gap and the settings of ``pair_residual``.

    Returns:
        (N, P) float32 distances in pixels, P = F - gap pairs, NaN where the track is not in both frames or
        the pair has no model.
    """
    pairs = max(visible.shape[1] - config.gap, 0)
    residuals = np.full((visible.shape[0], pairs), np.nan, dtype=np.float32)
    for m in range(pairs):
        both = visible[:, m] & visible[:, m + config.gap]
        distance = pair_residual(tracks[both, m], tracks[both, m + config.gap], config)
        if distance is not None:
            residuals[both, m] = distance
    return residuals


def moving_tracks(residuals: np.ndarray, config: TrackMotionConfig = TrackMotionConfig()) -> np.ndarray:
    """(N,) bool: tracks whose median distance over their pairs exceeds max(factor x median, floor).

    Args:
        residuals: (N, P) distances from ``pair_residuals`` (NaN = not measured).
        config: the factor and floor.
    """
    measured = ~np.isnan(residuals).all(axis=1)
    moving = np.zeros(residuals.shape[0], dtype=bool)
    if not measured.any():
        return moving
    per_track = np.nanmedian(residuals[measured], axis=1)
    threshold = max(config.factor * float(np.median(per_track)), config.floor_px)
    moving[measured] = per_track > threshold
    return moving
