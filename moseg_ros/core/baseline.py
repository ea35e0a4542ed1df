"""The `epipolar_baseline` motion decision: one dominant epipolar geometry, per-pixel residuals.

The camera's own motion is the dominant rigid motion of the scene, so a RANSAC fit of one fundamental matrix
to dense-flow correspondences recovers it; a pixel whose correspondence lies far from its epipolar line
(Sampson distance, Hartley & Zisserman eq. 11.9) moves by itself. This is the baseline the paper's fused
method improves on: it is blind to motion inside the epipolar plane (a car driving ahead of the camera in its
own direction, or straight towards it), which a flow model catches.

When one homography explains the dominant motion about as well as F does (a camera that only rotates, or a
scene that is mostly one plane), F is not determined by the data and a wrong member of its family can
swallow a mover; the residual is then the homography's transfer error instead (the model-selection idea of
Torr's GRIC, as in ORB-SLAM's initialisation, reduced to an inlier-count test).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core import geometry
from moseg_ros.core.flow_field import forward_backward_error, lands_inside, pixel_grid
from moseg_ros.core.robust import fundamental_polished, homography_ransac


@dataclass(frozen=True)
class BaselineConfig:
    """Settings of the epipolar baseline (pixels are at the working resolution).

    Attributes:
        grid_step: correspondences for the fit are read every grid_step pixels.
        fb_max_px: forward-backward tolerance, fb_max_px + fb_max_fraction · |flow| (pixels) ...
        fb_max_fraction: ... so large flows may carry proportionally larger round-trip error.
        ransac_threshold_px: RANSAC inlier threshold of F and H (pixels).
        residual_threshold_px: smallest per-pixel residual threshold (pixels).
        residual_noise_factor: threshold = max(residual_threshold_px, factor · 1.4826 · median inlier distance).
        min_parallax_px: median flow below which the camera stands still (the dominant motion is the identity).
        min_inliers: fewest samples (and RANSAC inliers of F) for a fit.
        homography_preference: H replaces F when its inliers are at least this share of F's.
        gric_min_sigma_px: smallest noise σ (pixels) in Torr's GRIC.
        border_fraction: per-pixel evidence only where the flow lands this share of the width inside the image.
    """

    grid_step: int = 10
    fb_max_px: float = 1.0
    fb_max_fraction: float = 0.05
    ransac_threshold_px: float = 0.5
    residual_threshold_px: float = 1.5
    residual_noise_factor: float = 4.0
    min_parallax_px: float = 0.3
    min_inliers: int = 30
    homography_preference: float = 0.9
    gric_min_sigma_px: float = 0.1
    border_fraction: float = 0.0


@dataclass
class EpipolarResidual:
    """Per-pixel epipolar evidence for the current frame.

    Attributes:
        residual: (H, W) float32 Sampson distance in pixels (sqrt of eq. 11.9); 0 where unknown.
        valid: (H, W) bool, pixels whose flow passed the forward-backward check and lands at least
            ``border_fraction`` of the image width inside the previous frame.
        threshold: residual above which a pixel counts as independently moving this frame.
        fundamental: (3, 3) F with x_prev^T F x_cur = 0, or None when the geometry was not estimable.
        homography: (3, 3) H with x_prev ~ H x_cur when the dominant motion is a homography (the identity
            when the camera stands still), else None.
        inlier_ratio: RANSAC inlier fraction of the sampled correspondences.
    """

    residual: np.ndarray
    valid: np.ndarray
    threshold: float
    fundamental: np.ndarray | None
    inlier_ratio: float
    homography: np.ndarray | None = None


def sampson_pixels(fundamental: np.ndarray, points: np.ndarray, matches: np.ndarray) -> np.ndarray:
    """Sampson distance in pixels of correspondences under one fundamental matrix.

    d(x, x') = |x'ᵀ F x| / sqrt((F x)₁² + (F x)₂² + (Fᵀ x')₁² + (Fᵀ x')₂²)

    The one-model case of geometry.sampson_distance (its square root), written out in float32: it runs on every
    pixel of a frame, where the batched form's homogeneous copies cost more than the arithmetic.

    Args:
        fundamental: (3, 3) F with matchesᵀ F points = 0.
        points: (N, 2) points x.
        matches: (N, 2) their correspondences x'.

    Returns:
        (N,) float32 distances in pixels.
    """
    F = fundamental.astype(np.float32)
    x, y = points[:, 0].astype(np.float32, copy=False), points[:, 1].astype(np.float32, copy=False)
    u, v = matches[:, 0].astype(np.float32, copy=False), matches[:, 1].astype(np.float32, copy=False)
    line = [F[i, 0] * x + F[i, 1] * y + F[i, 2] for i in range(3)]      # F x
    back = [F[0, i] * u + F[1, i] * v + F[2, i] for i in range(2)]      # first two of F^T x'
    numerator = u * line[0] + v * line[1] + line[2]
    denominator = line[0] ** 2 + line[1] ** 2 + back[0] ** 2 + back[1] ** 2
    return np.abs(numerator) / np.sqrt(np.maximum(denominator, 1e-30))


def homography_distance(homography: np.ndarray, points: np.ndarray, matches: np.ndarray) -> np.ndarray:
    """Root-mean symmetric transfer error in pixels of correspondences under one homography.

    d(x, x') = sqrt((||x' − H x||² + ||x − H⁻¹ x'||²) / 2)

    The one-model case of geometry.homography_transfer_error (HZ eq. 4.7), written out in float32 as
    ``sampson_pixels`` is.

    Args:
        homography: (3, 3) invertible H with matches ~ H points.
        points: (N, 2) points x.
        matches: (N, 2) their correspondences x'.

    Returns:
        (N,) float32 distances in pixels.
    """
    squared = _transferred(homography, points, matches) + _transferred(np.linalg.inv(homography), matches, points)
    return np.sqrt(np.float32(0.5) * squared)


def _transferred(homography: np.ndarray, points: np.ndarray, matches: np.ndarray) -> np.ndarray:
    """(N,) float32 ||matches - H points||² of (N, 2) correspondences."""
    H = homography.astype(np.float32)
    x, y = points[:, 0].astype(np.float32, copy=False), points[:, 1].astype(np.float32, copy=False)
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    w = np.where(np.abs(w) < 1e-12, np.float32(1e-12), w)
    u = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w - matches[:, 0]
    v = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w - matches[:, 1]
    return u * u + v * v


def epipolar_residual(to_previous: np.ndarray, to_current: np.ndarray,
                      config: BaselineConfig = BaselineConfig()) -> EpipolarResidual:
    """Fit the dominant epipolar geometry between two frames and score every pixel of the current one.

    Args:
        to_previous: (H, W, 2) flow from the current frame to the previous one.
        to_current: (H, W, 2) flow from the previous frame to the current one (for the forward-backward check).
        config: thresholds.

    Returns:
        The per-pixel residual map and the fitted geometry. When the camera stands still (median flow below
        ``min_parallax_px``) the dominant motion is the identity: the residual is each pixel's flow and
        ``homography`` the identity. When RANSAC finds too few inliers the residual is all zeros (no evidence
        either way) and both models are None. The homography replaces F when it explains nearly as many
        samples (``homography_preference``) or when Torr's GRIC prefers it.
    """
    h, w = to_previous.shape[:2]
    grid = pixel_grid(h, w)
    # Large flows (near objects under forward motion) carry proportionally larger round-trip error.
    tolerance = config.fb_max_px + config.fb_max_fraction * np.hypot(to_previous[..., 0], to_previous[..., 1])
    checked = forward_backward_error(to_previous, to_current) < tolerance
    # The fit still samples the border's matches: they are few, RANSAC drops the wrong ones, and matches spread
    # wide condition F best; only the per-pixel evidence leaves them out.
    valid = checked & lands_inside(to_previous, config.border_fraction * w) if config.border_fraction > 0 else checked
    residual = np.zeros((h, w), dtype=np.float32)
    empty = EpipolarResidual(residual, valid, np.inf, None, 0.0)

    step = config.grid_step
    sample_ok = checked[::step, ::step]
    points = grid[::step, ::step][sample_ok]
    matches = points + to_previous[::step, ::step][sample_ok]
    if len(points) < config.min_inliers:
        return empty
    if np.median(np.linalg.norm(matches - points, axis=1)) < config.min_parallax_px:
        # The camera stands still: the dominant motion is the identity, and any flow is the residual.
        identity = np.eye(3)
        residual[valid] = np.hypot(to_previous[valid][:, 0], to_previous[valid][:, 1])
        noise = 1.4826 * float(np.median(np.linalg.norm(matches - points, axis=1)))
        threshold = max(config.residual_threshold_px, config.residual_noise_factor * noise)
        return EpipolarResidual(residual, valid, float(threshold), None, 1.0, identity)
    fundamental, inliers = fundamental_polished(points, matches, config.ransac_threshold_px)
    if fundamental is None or inliers.sum() < config.min_inliers:
        return empty

    homography, h_inliers = homography_ransac(points, matches, cv2.USAC_FAST, config.ransac_threshold_px)
    planar = homography is not None and h_inliers.sum() >= config.homography_preference * inliers.sum()
    if not planar and homography is not None:
        # Or when Torr's GRIC prefers the homography (F's extra freedom explains only noise).
        f_squared = sampson_pixels(fundamental, points, matches) ** 2
        h_squared = homography_distance(homography, points, matches) ** 2
        sigma = max(1.4826 * float(np.median(np.sqrt(f_squared[inliers]))), config.gric_min_sigma_px)
        planar = geometry.homography_preferred(f_squared, h_squared, sigma)
    # Every pixel is scored and the unreliable ones zeroed after: cheaper than gathering the valid ones.
    here, there = grid.reshape(-1, 2), (grid + to_previous).reshape(-1, 2)
    if planar:
        residual = homography_distance(homography, here, there).reshape(h, w)
        inlier_distance = homography_distance(homography, points[h_inliers], matches[h_inliers])
    else:
        homography = None
        residual = sampson_pixels(fundamental, here, there).reshape(h, w)
        inlier_distance = sampson_pixels(fundamental, points[inliers], matches[inliers])
    noise = 1.4826 * np.median(inlier_distance)
    threshold = max(config.residual_threshold_px, config.residual_noise_factor * noise)
    residual = np.where(valid, residual, np.float32(0.0)).astype(np.float32, copy=False)
    return EpipolarResidual(residual, valid, float(threshold), fundamental, float(inliers.mean()), homography)


# Instance ids up to this are counted in a table indexed by id; larger ones (an upstream segmenter's hashes) by rank.
DENSE_IDS = 1 << 16
# Instances with fewer valid pixels are left undecided (not dynamic).
MIN_INSTANCE_PIXELS = 20


def dynamic_instances(instances: np.ndarray, moving: np.ndarray, valid: np.ndarray,
                      min_fraction: float = 0.3, min_pixels: int = MIN_INSTANCE_PIXELS) -> np.ndarray:
    """Instance ids of which a large enough share of reliable pixels moves independently.

    Args:
        instances: (H, W) int ids, 0 or below = background.
        moving: (H, W) bool per-pixel evidence.
        valid: (H, W) bool, where the evidence is reliable.
        min_fraction: share of an instance's valid pixels that must move.
        min_pixels: instances with fewer valid pixels are left undecided (not dynamic).

    Returns:
        (D,) int32 sorted ids of the dynamic instances.
    """
    ids, fraction, valid_count = instance_shares(instances, moving, valid)
    return ids[(fraction >= min_fraction) & (valid_count >= min_pixels)]


def instance_shares(instances: np.ndarray, moving: np.ndarray,
                    valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Share of each instance's valid pixels that move, and the count of its valid pixels.

    share_k = |valid ∩ moving ∩ instance k| / max(|valid ∩ instance k|, 1)

    Ids up to ``DENSE_IDS`` are counted in a table (an id in it but not in the map has no valid pixels);
    larger ones by rank among the ids present.

    Args:
        instances: (H, W) int ids, 0 or below = background (never counted).
        moving: (H, W) bool per-pixel evidence.
        valid: (H, W) bool, where the evidence is reliable.

    Returns:
        ids (K,) int32 sorted positive ids; share (K,) float64; valid count (K,) int.
    """
    ids = instances.ravel()
    counted = valid.ravel() & (ids > 0)  # ids <= 0 are background, never counted
    present = None
    if ids.max(initial=0) > DENSE_IDS:  # counted by rank among the ids present, not in a table up to the largest
        present, ids = np.unique(ids, return_inverse=True)
        ids = ids.ravel()
    n = max(int(ids.max(initial=0)), 0) + 1
    valid_count = np.bincount(ids[counted], minlength=n)
    moving_count = np.bincount(ids[counted & moving.ravel()], minlength=n)
    fraction = moving_count / np.maximum(valid_count, 1)
    numbers = np.arange(n) if present is None else present
    positive = numbers > 0
    return numbers[positive].astype(np.int32), fraction[positive], valid_count[positive]
