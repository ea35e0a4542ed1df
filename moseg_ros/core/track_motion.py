"""Which point trajectories move by themselves: a robust epipolar test per track over a window.

The camera's own motion is the dominant rigid motion of the tracked points, so for every frame pair (m, m+g)
of the window a RANSAC fundamental matrix is fitted to the tracks seen in both frames, and every track gets
its Sampson distance (Hartley & Zisserman eq. 11.9, in pixels) under it. A track moves when the median of its
distances over the pairs it spans exceeds ``max(factor x the median over all tracks, floor)``: the median
over pairs forgives one bad pair (a KLT slip), the median over tracks scales the threshold with the window's
noise. When one homography explains about as many tracks as F does (a camera that only rotates, or a scene
that is mostly one plane), F is not determined by the data and a wrong member of its family can swallow a
mover; the distance is then the homography's transfer error (the model-selection idea of Torr's GRIC, as in
core/baseline.py). This residual test is blind to motion inside the epipolar plane.

Part of that blind spot is closed by cheirality (Hartley & Zisserman 9.6.3). With the camera's K, or a
guessed one (focal 0.9 x width, principal point at the centre; only a sign is used, so the guess barely
matters: 0.58, 0.9 and 1.2 x width gave the same on KITTI), E = K^T F K gives R and t, and the infinite homography
K R K^-1 maps x1 to where a point at infinite depth would land. A static point's image moves away from there
as its inverse depth grows, so its signed parallax is positive; a car pulling away ahead gets a negative one.
The sign of t is voted by F's inliers with |parallax| > ``cheir_decided_px``; a pair counts only with
``cheir_consensus`` agreement, which drops pure rotations and pairs dominated by a mover. A track moves when
its median signed parallax is below -``cheir_px``. With a guessed K the rotation is misjudged in a turn and
static foliage came out 'behind infinity' (KITTI odometry 07, 3-4.5 degrees per pair): pairs turning more
than ``guessed_max_rotation_deg`` then give no sign. An oncoming car projects exactly like a nearer static
point in every pair and stays invisible to both tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core.geometry import homography_preferred, homography_transfer_error, sampson_distance
from moseg_ros.core.robust import fundamental_ransac, homography_ransac


@dataclass(frozen=True)
class TrackMotionConfig:
    """Settings of the per-track epipolar test (pixels at the tracking resolution)."""

    gap: int = 2
    ransac_px: float = 1.0
    factor: float = 3.0
    floor_px: float = 1.0
    min_tracks: int = 20
    min_parallax_px: float = 0.5
    cheir_px: float = 2.0
    cheir_consensus: float = 0.9
    cheir_decided_px: float = 1.0
    cheir_min_votes: int = 20
    guessed_max_rotation_deg: float = 2.0
    homography_preference: float = 0.9
    gric_min_sigma_px: float = 0.1


def guessed_camera_matrix(image_size: tuple[int, int], focal_fraction: float = 0.9) -> np.ndarray:
    """(3, 3) K of an uncalibrated camera: focal ``focal_fraction`` x width, principal point at the centre."""
    h, w = image_size
    f = focal_fraction * w
    return np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])


def rotation_degrees(R: np.ndarray) -> float:
    """The angle of a (3, 3) rotation matrix, in degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def signed_parallax(x1: np.ndarray, x2: np.ndarray, fundamental: np.ndarray, inliers: np.ndarray,
                    K: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                    max_rotation_deg: float = np.inf) -> np.ndarray | None:
    """(N,) float32 signed parallax in pixels from the infinite homography (positive = positive depth).

    Args:
        x1, x2: (N, 2) float64 correspondences, x2^T F x1 = 0.
        fundamental: (3, 3) F.
        inliers: (N,) bool RANSAC inliers of F (they vote on the sign).
        K: (3, 3) camera matrix (from camera_info, or ``guessed_camera_matrix``).
        config: the cheirality settings.
        max_rotation_deg: a pair that turns more is not used (with a guessed K, the infinite homography's
            error grows with the rotation).

    Returns:
        None when the pair does not decide the sign (too few votes, no consensus, or too much rotation).
    """
    R1, R2, t = cv2.decomposeEssentialMat(K.T @ fundamental @ K)
    # Of the two rotations the true one is the small one (the other is turned 180 degrees about the baseline).
    R = R1 if np.trace(R1) >= np.trace(R2) else R2
    if rotation_degrees(R) > max_rotation_deg:
        return None
    a = (K @ R @ np.linalg.inv(K) @ np.c_[x1, np.ones(len(x1))].T).T  # rotated rays, pixels x depth
    b = (K @ t).ravel()                                                 # the translation, pixels x depth
    at_infinity = a[:, :2] / a[:, 2:3]
    # x2(rho) = (a_xy + rho b_xy) / (a_z + rho b_z); its direction as the inverse depth rho leaves 0.
    direction = b[None, :2] * a[:, 2:3] - b[2] * a[:, :2]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True) + 1e-12
    signed = np.sum((x2 - at_infinity) * direction, axis=1)
    votes = signed[inliers & (np.abs(signed) > config.cheir_decided_px)]
    if len(votes) < config.cheir_min_votes:
        return None
    positive = float(np.mean(votes > 0))
    if max(positive, 1.0 - positive) < config.cheir_consensus:
        return None
    return (signed if positive >= 0.5 else -signed).astype(np.float32)


def pair_evidence(x1: np.ndarray, x2: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                  K: np.ndarray | None = None, guessed: bool = False) -> tuple[np.ndarray, np.ndarray | None] | None:
    """Distances (as ``pair_residual``) and, given a camera matrix K and a non-degenerate F, the signed
    parallax of ``signed_parallax`` (None otherwise); None when there is no model at all. ``guessed``: K is
    not the camera's, so pairs turning more than ``guessed_max_rotation_deg`` give no sign."""
    if len(x1) < config.min_tracks:
        return None
    x1, x2 = np.asarray(x1, dtype=np.float64), np.asarray(x2, dtype=np.float64)
    if np.median(np.linalg.norm(x2 - x1, axis=1)) < config.min_parallax_px:
        # The camera stands still: the dominant motion is the identity, any motion is the residual.
        return np.linalg.norm(x2 - x1, axis=1).astype(np.float32), None
    fundamental, f_inliers = fundamental_ransac(x1, x2, cv2.USAC_MAGSAC, config.ransac_px)
    if fundamental is None:
        return None
    homography, h_inliers = homography_ransac(x1, x2, cv2.USAC_MAGSAC, config.ransac_px)
    f_squared = sampson_distance(fundamental[None], x1, x2)[0]
    planar = False
    if homography is not None:
        h_squared = 0.5 * homography_transfer_error(homography[None], x1, x2)[0]
        # F is degenerate when the homography explains about as many tracks, or when Torr's GRIC prefers it.
        planar = h_inliers.sum() >= config.homography_preference * f_inliers.sum()
        if not planar:
            sigma = max(1.4826 * float(np.median(np.sqrt(f_squared[f_inliers]))), config.gric_min_sigma_px)
            planar = homography_preferred(f_squared, h_squared, sigma)
    if planar:
        # F is degenerate: no translation to take a sign from.
        return np.sqrt(h_squared).astype(np.float32), None
    # cv2's F satisfies x2^T F x1 = 0, the convention of geometry.sampson_distance(F, x1, x2).
    distance = np.sqrt(f_squared).astype(np.float32)
    signed = None
    if K is not None:
        limit = config.guessed_max_rotation_deg if guessed else np.inf
        signed = signed_parallax(x1, x2, fundamental, f_inliers, K, config, limit)
    return distance, signed


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
    evidence = pair_evidence(x1, x2, config)
    return None if evidence is None else evidence[0]


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


def moving_tracks(residuals: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                  signed: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: tracks whose median distance over their pairs exceeds max(factor x median, floor), or
    whose median signed parallax is below -cheir_px.

    Args:
        residuals: (N, P) distances from ``pair_residuals`` (NaN = not measured).
        config: the factor and floor.
        signed: optional (N, P) signed parallax (NaN = not measured or pair undecided).
    """
    measured = ~np.isnan(residuals).all(axis=1)
    moving = np.zeros(residuals.shape[0], dtype=bool)
    if not measured.any():
        return moving
    per_track = np.nanmedian(residuals[measured], axis=1)
    threshold = max(config.factor * float(np.median(per_track)), config.floor_px)
    moving[measured] = per_track > threshold
    if signed is not None:
        decided = ~np.isnan(signed).all(axis=1)
        if decided.any():
            moving[decided] |= np.nanmedian(signed[decided], axis=1) < -config.cheir_px
    return moving
