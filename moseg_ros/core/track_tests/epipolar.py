"""The epipolar test: each track's distance from the camera's dominant epipolar geometry in one frame pair.

A track moves when its distance from the camera's dominant epipolar geometry (Sampson, Hartley & Zisserman
eq. 11.9) stays large over the window; when a homography explains about as many tracks as F (a camera that only
rotates, a planar scene), F is not determined and the homography's transfer error is used instead.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from moseg_ros.core.geometry import homography_preferred, homography_transfer_error, sampson_distance
from moseg_ros.core.robust import fundamental_polished, homography_ransac
from moseg_ros.core.track_tests.settings import TrackMotionConfig


def beyond_allowance(distance: np.ndarray, displacement: np.ndarray, allowance: float) -> np.ndarray:
    """Epipolar distance beyond an allowance that grows with the displacement: max(d − allowance · |x2 − x1|, 0).

    Args:
        distance: (...) epipolar distances of correspondences (any shape).
        displacement: (..., 2) each one's displacement (x2 − x1, or a dense flow).
        allowance: ``TrackMotionConfig.epipole_allowance`` (the front-end's ``dense_allowance`` for a dense
            flow); <= 0 leaves the distances as they are.

    Returns:
        (...) float32 distances.
    """
    if allowance <= 0:
        return np.asarray(distance, dtype=np.float32)
    return np.maximum(distance - allowance * np.hypot(displacement[..., 0], displacement[..., 1]),
                      0.0).astype(np.float32)


def may_be_planar(x1: np.ndarray, x2: np.ndarray, f_inliers: np.ndarray,
                  config: TrackMotionConfig = TrackMotionConfig()) -> bool:
    """Whether a homography might explain about as many of the correspondences as F does.

    True when a quick RANSAC homography on every ``screen_stride``-th correspondence explains at least
    ``homography_screen`` of F's inliers among them, when it finds no model, or when the screen is off
    (``homography_screen`` <= 0). False tells the caller to skip the full fit.

    Args:
        x1, x2: (N, 2) correspondences.
        f_inliers: (N,) bool F's inliers.
        config: the screen's settings.
    """
    if config.homography_screen <= 0:
        return True
    step = max(1, config.screen_stride)
    model, inliers = homography_ransac(x1[::step], x2[::step], cv2.RANSAC, config.ransac_px,
                                       config.screen_iterations, 0.99)
    # No quick model decides nothing: the full fit does.
    return model is None or bool(inliers.sum() >= config.homography_screen * f_inliers[::step].sum())

class EpipolarFit(NamedTuple):
    """One frame pair's dominant motion and each track's distance from it.

    Attributes:
        distance: (N,) float32 pixels: the Sampson distance under F beyond the epipole allowance; under a
            homography (F degenerate) its symmetric transfer error; for a still camera the whole motion.
        fundamental: (3, 3) F with x2ᵀ F x1 = 0, or None when F is degenerate or the camera stands still.
        inliers: (N,) bool F's RANSAC inliers, or None with no F.
        noise: the pair's noise, 1.4826 × the median of F's inliers' distances (pixels; inf without inliers).
    """

    distance: np.ndarray
    fundamental: np.ndarray | None = None
    inliers: np.ndarray | None = None
    noise: float = np.inf


def epipolar_fit(x1: np.ndarray, x2: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                 planar_check: bool = True) -> EpipolarFit | None:
    """The camera's dominant motion between two frames' tracks and each track's distance from it.

    F by RANSAC and polishing; F is degenerate when a homography explains ``homography_preference`` as many
    tracks or Torr's GRIC prefers it (then the homography's transfer error is the distance). Under F,

        d = max(sqrt(Sampson(F, x1, x2)) − epipole_allowance · |x2 − x1|, 0)   (``beyond_allowance``).

    Args:
        x1, x2: (N, 2) track positions in the earlier and the later frame.
        config: settings.
        planar_check: False skips the homography (a caller that knows the camera translates).

    Returns:
        EpipolarFit with (N,) distances, or None with fewer than ``min_tracks`` tracks or no F at all.
    """
    if len(x1) < config.min_tracks:
        return None
    x1, x2 = np.asarray(x1, dtype=np.float64), np.asarray(x2, dtype=np.float64)
    if np.median(np.linalg.norm(x2 - x1, axis=1)) < config.min_parallax_px:
        # The camera stands still: the dominant motion is the identity, any motion is the residual.
        return EpipolarFit(np.linalg.norm(x2 - x1, axis=1).astype(np.float32))
    fundamental, f_inliers = fundamental_polished(x1, x2, config.inlier_px)
    if fundamental is None:
        return None
    homography, h_inliers = (homography_ransac(x1, x2, cv2.USAC_MAGSAC, config.ransac_px)
                             if planar_check and may_be_planar(x1, x2, f_inliers, config) else (None, None))
    f_squared = sampson_distance(fundamental[None], x1, x2)[0]
    noise = 1.4826 * float(np.median(np.sqrt(f_squared[f_inliers]))) if f_inliers.any() else np.inf
    planar = False
    if homography is not None:
        h_squared = 0.5 * homography_transfer_error(homography[None], x1, x2)[0]
        planar = h_inliers.sum() >= config.homography_preference * f_inliers.sum()
        if not planar:
            planar = homography_preferred(f_squared, h_squared, max(noise, config.gric_min_sigma_px))
    if planar:
        return EpipolarFit(np.sqrt(h_squared).astype(np.float32), noise=noise)
    # cv2's F satisfies x2ᵀ F x1 = 0, the convention of geometry.sampson_distance(F, x1, x2).
    distance = beyond_allowance(np.sqrt(f_squared), x2 - x1, config.epipole_allowance)
    return EpipolarFit(distance, fundamental, f_inliers, noise)


def pair_residual(x1: np.ndarray, x2: np.ndarray,
                  config: TrackMotionConfig = TrackMotionConfig()) -> np.ndarray | None:
    """Distance of N correspondences from the dominant motion fitted to them by RANSAC.

    Sampson distance under F (beyond ``epipole_allowance``, see ``epipolar_fit``), or the symmetric transfer
    error under a homography when one explains at least ``homography_preference`` as many correspondences as F
    (F is then degenerate).

    Args:
        x1: (N, 2) positions in the earlier frame.
        x2: (N, 2) the same points in the later frame.
        config: RANSAC threshold, smallest usable number of tracks and parallax.

    Returns:
        (N,) float32 distances in pixels, or None when there are too few points, too little parallax (the
        geometry is not determined) or RANSAC finds no model.
    """
    fit = epipolar_fit(x1, x2, config)
    return None if fit is None else fit.distance


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
