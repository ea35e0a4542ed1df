"""OpenCV's robust two-view estimators, with every failure reported as "no model".

cv2.findFundamentalMat and cv2.findHomography return None for data without a model, but their USAC
variants can also raise (``!model.empty()`` in setModelParameters, when the final refit of a degenerate
sample comes out empty: seen on real KITTI frames streamed with dropped frames). A frame without a model
has no motion evidence; it must not be an error.
"""

from __future__ import annotations

import cv2
import numpy as np

Fit = tuple[np.ndarray, np.ndarray] | tuple[None, None]


def _checked(model: np.ndarray | None, inliers: np.ndarray | None) -> Fit:
    # Both estimators may return several stacked 3x3 solutions, or an empty one, for degenerate data.
    if model is None or inliers is None or model.shape != (3, 3):
        return None, None
    return model, inliers.ravel().astype(bool)


def fundamental_ransac(x1: np.ndarray, x2: np.ndarray, method: int, threshold_px: float,
                       confidence: float = 0.999, max_iterations: int = 1000) -> Fit:
    """F with x2^T F x1 = 0 and its (N,) bool inliers, robustly fitted to (N, 2) float32/64 correspondences;
    (None, None) when OpenCV finds no model or fails on the data."""
    try:
        model, inliers = cv2.findFundamentalMat(x1, x2, method, threshold_px, confidence, max_iterations)
    except cv2.error:
        return None, None
    return _checked(model, inliers)


def homography_ransac(x1: np.ndarray, x2: np.ndarray, method: int, threshold_px: float,
                      max_iterations: int = 2000, confidence: float = 0.995) -> Fit:
    """H with x2 ~ H x1 and its (N,) bool inliers, robustly fitted to (N, 2) float32/64 correspondences;
    (None, None) when OpenCV finds no model or fails on the data. The defaults are OpenCV's."""
    try:
        model, inliers = cv2.findHomography(x1, x2, method, threshold_px, None, max_iterations, confidence)
    except cv2.error:
        return None, None
    return _checked(model, inliers)
