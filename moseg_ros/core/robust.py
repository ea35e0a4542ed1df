"""OpenCV's robust two-view estimators, with every failure reported as "no model".

cv2.findFundamentalMat and cv2.findHomography return None for data without a model, but their USAC
variants can also raise (``!model.empty()`` in setModelParameters, when the final refit of a degenerate
sample comes out empty: seen on real street frames streamed with dropped frames). A frame without a model
has no motion evidence; it must not be an error.
"""

from __future__ import annotations

import cv2
import numpy as np

from moseg_ros.core.geometry import sampson_distance

Fit = tuple[np.ndarray, np.ndarray] | tuple[None, None]


def _checked(model: np.ndarray | None, inliers: np.ndarray | None) -> Fit:
    # Both estimators may return several stacked 3x3 solutions, or an empty one, for degenerate data.
    if model is None or inliers is None or model.shape != (3, 3):
        return None, None
    return model, inliers.ravel().astype(bool)


def fundamental_ransac(x1: np.ndarray, x2: np.ndarray, method: int, threshold_px: float,
                       confidence: float = 0.999, max_iterations: int = 1000) -> Fit:
    """Robust fit of a fundamental matrix with x2ᵀ F x1 = 0 (cv2.findFundamentalMat).

    Args:
        x1, x2: (N, 2) float32/64 correspondences.
        method: OpenCV method flag (cv2.FM_RANSAC, cv2.USAC_MAGSAC, ...).
        threshold_px: inlier threshold (pixels).
        confidence, max_iterations: passed to OpenCV.

    Returns:
        F (3, 3) and inliers (N,) bool; (None, None) when OpenCV finds no model or fails on the data.
    """
    try:
        model, inliers = cv2.findFundamentalMat(x1, x2, method, threshold_px, confidence, max_iterations)
    except cv2.error:
        return None, None
    return _checked(model, inliers)


def fundamental_polished(x1: np.ndarray, x2: np.ndarray, threshold_px: float, confidence: float = 0.999,
                         max_iterations: int = 100, rounds: int = 2, min_share: float = 0.7) -> Fit:
    """Fundamental matrix with x2ᵀ F x1 = 0 by plain RANSAC polished by least-squares refits on its inliers.

    OpenCV's plain seven-point RANSAC, then up to ``rounds`` least-squares (normalised eight-point) refits on
    the inliers (Sampson distance at most ``threshold_px``), each kept while it holds no fewer of them.

    The refits are the local optimisation that USAC_FAST and MAGSAC++ run, without their cost, which grows with the
    number of points rather than of iterations: on a frame's dense-flow samples or tracks, mostly inliers, this
    keeps as many inliers with the same spread of their distances in a fraction of the time (docs/experiments.md).
    Plain RANSAC has no early rejection of bad samples, though, and the iterations it needs grow steeply with the
    outliers' share: it gets ``max_iterations`` (enough while ``min_share`` of the points are inliers), and data
    where it finds fewer inliers than that, or no model, go to MAGSAC++ at the same threshold, whose cost stays
    bounded.

    Args:
        x1, x2: (N, 2) float32/64 correspondences.
        threshold_px: inlier threshold on the Sampson distance (pixels).
        confidence, max_iterations: of the plain RANSAC.
        rounds: most refits.
        min_share: inlier share below which MAGSAC++ is run instead.

    Returns:
        F (3, 3) and inliers (N,) bool; (None, None) as ``fundamental_ransac``.
    """
    model, inliers = fundamental_ransac(x1, x2, cv2.FM_RANSAC, threshold_px, confidence, max_iterations)
    if model is None or inliers.mean() < min_share:
        model, _ = fundamental_ransac(x1, x2, cv2.USAC_MAGSAC, threshold_px)
        inliers = None if model is None else _within(model, x1, x2, threshold_px)
    for _ in range(rounds if model is not None else 0):
        refit, _ = fundamental_ransac(x1[inliers], x2[inliers], cv2.FM_8POINT, threshold_px)
        if refit is None:
            break
        held = _within(refit, x1, x2, threshold_px)
        if held.sum() < inliers.sum():
            break
        model, inliers = refit, held
    return model, inliers


def _within(fundamental: np.ndarray, x1: np.ndarray, x2: np.ndarray, threshold_px: float) -> np.ndarray:
    """(N,) bool: the correspondences whose Sampson distance under F is at most ``threshold_px``."""
    return sampson_distance(fundamental[None], x1, x2)[0] <= threshold_px ** 2


def homography_ransac(x1: np.ndarray, x2: np.ndarray, method: int, threshold_px: float,
                      max_iterations: int = 2000, confidence: float = 0.995) -> Fit:
    """Robust fit of a homography with x2 ~ H x1 (cv2.findHomography; the defaults are OpenCV's).

    Args:
        x1, x2: (N, 2) float32/64 correspondences.
        method: OpenCV method flag (cv2.RANSAC, cv2.USAC_FAST, ...).
        threshold_px: inlier threshold on the transfer error (pixels).
        max_iterations, confidence: passed to OpenCV.

    Returns:
        H (3, 3) and inliers (N,) bool; (None, None) when OpenCV finds no model or fails on the data.
    """
    try:
        model, inliers = cv2.findHomography(x1, x2, method, threshold_px, None, max_iterations, confidence)
    except cv2.error:
        return None, None
    return _checked(model, inliers)


def row_medians(values: np.ndarray) -> np.ndarray:
    """Median of each row, NaN ignored.

    The same numbers as ``np.nanmedian(values, axis=1)`` (the mean of the two middle values of an even count),
    from one sort: for short rows NumPy's nanmedian goes through masked arrays, several times slower, and the
    refit takes about four of these a frame while holding the GIL the frame path needs.

    Args:
        values: (N, P) values, NaN = missing.

    Returns:
        (N,) medians; NaN for a row without a number.
    """
    if values.shape[1] == 0:
        return np.full(values.shape[0], np.nan)
    ordered = np.sort(values, axis=1)  # NaN sorts last
    count = values.shape[1] - np.isnan(values).sum(axis=1)
    rows = np.arange(values.shape[0])
    middle = 0.5 * (ordered[rows, np.maximum((count - 1) // 2, 0)] + ordered[rows, np.maximum(count // 2, 0)])
    return np.where(count > 0, middle, np.nan)
