"""Ground-contact test (object_level's): does the foot of an object slide over the ground plane?

The ground's image motion between two frames is one homography H_g whatever the depth, so the ground's flow at an
object's foot is what the foot's flow would be if the object were static. Per frame pair H_g is fitted to the
background's flow low in the image; each object's foot (pixels with ``clearance`` ground rows below them) is
compared with the ground's flow carried up from ``ground_rows`` below,
u_g(x) = u(x + d) + (H_g(x) − x) − (H_g(x + d) − (x + d)), as e = median |u_obj − u_g| against s = median |u_g|.
An object's score over the window is median(e) / (relative · median(s) + absolute): above 1 it moves.
docs/method.md has the derivation.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core.robust import homography_ransac


@dataclass(frozen=True)
class GroundConfig:
    """Settings of the ground-contact test.

    Attributes:
        fit_rows: the ground homography is fitted to background flow vectors in this bottom fraction of the image.
        grid_step: flow vectors for the fit are read every grid_step pixels.
        ransac_px: RANSAC inlier threshold of the fit (pixels), at least ...
        ransac_fraction: ... this fraction of the median flow of the vectors.
        min_vectors: fewest background vectors in the fit region for a fit.
        min_inlier_fraction: a plane that explains fewer of them is not taken as the ground.
        clearance: background rows that must lie right below a foot pixel.
        probe_rows: (first, last) rows above the foot whose object flow is compared (last excluded).
        ground_rows: (first, last) rows below the foot whose ground flow is measured (last <= clearance + 1).
        min_columns: fewest foot columns for an object's contact in a pair (thin or far objects have
            unreliable flow at their foot).
        min_pairs: fewest pairs with contact for a window score.
        relative: share of the ground's speed at the foot a static object may deviate by.
        absolute: flow noise (pixels) a static object may deviate by.
        max_speed_fraction: feet where the ground moves more than this fraction of the image width per frame
            are not compared: dense flow fails on such displacements (objects right beside the camera).
    """

    fit_rows: float = 1.0 / 3.0
    grid_step: int = 4
    ransac_px: float = 1.5
    ransac_fraction: float = 0.1
    min_vectors: int = 50
    min_inlier_fraction: float = 0.4
    clearance: int = 5
    probe_rows: tuple[int, int] = (2, 6)
    ground_rows: tuple[int, int] = (3, 6)
    min_columns: int = 4
    min_pairs: int = 2
    relative: float = 0.08
    max_speed_fraction: float = 0.04
    absolute: float = 0.4

    def __post_init__(self) -> None:
        if not 1 <= self.ground_rows[0] < self.ground_rows[1] <= self.clearance + 1:
            raise ValueError(f"ground_rows {self.ground_rows} must lie within the {self.clearance} clearance rows")
        if not 0 <= self.probe_rows[0] < self.probe_rows[1]:
            raise ValueError(f"probe_rows {self.probe_rows} must be increasing rows above the foot")
        if self.min_pairs < 1 or self.min_columns < 1:
            raise ValueError("min_pairs and min_columns must be >= 1")


def fit_ground_homography(labels: np.ndarray, flow: np.ndarray, config: GroundConfig) -> np.ndarray | None:
    """Homography of the ground plane between two frames from the background's flow at the image bottom.

    Args:
        labels: (H, W) int instance ids of the first frame (0 = background).
        flow: (H, W, 2) forward flow to the second frame.
        config: settings.

    Returns:
        (3, 3) H_g with x' ~ H_g x, or None when there is no dominant plane in the bottom rows.
    """
    height, width = labels.shape
    top = int(round(height * (1.0 - config.fit_rows)))
    ys, xs = np.mgrid[top:height:config.grid_step, 0:width:config.grid_step]
    uv = flow[ys, xs]
    usable = (labels[ys, xs] == 0) & np.all(np.isfinite(uv), axis=-1)
    if usable.sum() < config.min_vectors:
        return None
    src = np.stack([xs[usable], ys[usable]], axis=1).astype(np.float32)
    dst = src + uv[usable].astype(np.float32)
    # Flow errors grow with the flow: near the camera the ground moves tens of pixels per frame.
    threshold = max(config.ransac_px, config.ransac_fraction * float(np.median(np.linalg.norm(dst - src, axis=1))))
    homography, inliers = homography_ransac(src, dst, cv2.RANSAC, threshold)
    if homography is None or inliers.mean() < config.min_inlier_fraction:
        return None
    return homography


def foot_pixels(labels: np.ndarray, clearance: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of objects (id > 0) whose next ``clearance`` rows below are background and inside the image.

    Args:
        labels: (H, W) int instance ids (0 = background).
        clearance: background rows required below a foot pixel.

    Returns:
        rows (M,) and cols (M,) int of the foot pixels (as np.nonzero).
    """
    height = labels.shape[0]
    foot = np.zeros(labels.shape, dtype=bool)
    rows_with_room = height - clearance
    if rows_with_room <= 0:
        return np.nonzero(foot)
    foot[:rows_with_room] = labels[:rows_with_room] > 0
    for d in range(1, clearance + 1):
        foot[:rows_with_room] &= labels[d:rows_with_room + d] == 0
    return np.nonzero(foot)


def _plane_flow(rows: np.ndarray, cols: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """(n, 2) flow H(x) − x of the plane at pixels (rows, cols)."""
    x = np.stack([cols, rows], axis=1).astype(np.float64)
    return cv2.perspectiveTransform(x[None], homography)[0] - x if len(x) else x


def _ground_flow_at_foot(rows: np.ndarray, cols: np.ndarray, flow: np.ndarray, homography: np.ndarray,
                         config: GroundConfig) -> np.ndarray:
    """The ground's flow at each foot pixel: measured on the ground just below, carried up by H_g.

    u_g(x) = u(x + d) + (H_g flow(x) − H_g flow(x + d)), averaged over the rows d of ``ground_rows`` below:
    the measured flow keeps the homography's fit error out, the homography only adds the small change of the
    ground's flow over d rows.
    """
    at_foot = _plane_flow(rows, cols, homography)
    first, last = config.ground_rows
    estimates = [flow[rows + d, cols] + at_foot - _plane_flow(rows + d, cols, homography)
                 for d in range(first, last)]
    return np.mean(estimates, axis=0) if estimates else at_foot


def contact_errors(labels: np.ndarray, flow: np.ndarray, homography: np.ndarray, object_ids: np.ndarray,
                   config: GroundConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per object, how far its flow above its foot is from the ground's flow at the foot, in one pair.

    e = median |u(x − d) − u_g(x)| over foot pixels x and the rows d of ``probe_rows`` on the same object,
    s = median |u_g(x)|, u_g the ground's flow carried up from ``ground_rows`` below (module docstring).

    Args:
        labels: (H, W) int instance ids of the first frame; flow: (H, W, 2) forward flow.
        homography: (3, 3) ground homography of the pair (fit_ground_homography).
        object_ids: (K,) ids to score.
        config: settings.

    Returns:
        error (K,) median |u_obj − u_g| (pixels) and speed (K,) median |u_g| at the foot; NaN for objects
        with fewer than ``min_columns`` foot columns.
    """
    rows, cols = foot_pixels(labels, config.clearance)
    ids = labels[rows, cols]
    ground = _ground_flow_at_foot(rows, cols, flow, homography, config)
    first, last = config.probe_rows
    probe_err, probe_speed, probe_id = [], [], []
    for d in range(first, last):
        above = np.maximum(rows - d, 0)
        same = labels[above, cols] == ids
        diff = flow[above[same], cols[same]] - ground[same]
        probe_err.append(np.linalg.norm(diff, axis=1))
        probe_speed.append(np.linalg.norm(ground[same], axis=1))
        probe_id.append(ids[same])
    err, speed, pid = (np.concatenate(a) for a in (probe_err, probe_speed, probe_id))
    error = np.full(len(object_ids), np.nan)
    ground_speed = np.full(len(object_ids), np.nan)
    for k, obj in enumerate(object_ids):
        if np.unique(cols[ids == obj]).size < config.min_columns:
            continue
        sel = (pid == obj) & np.isfinite(err)
        if sel.any():
            error[k], ground_speed[k] = np.median(err[sel]), np.median(speed[sel])
    too_fast = ground_speed > config.max_speed_fraction * labels.shape[1]
    error[too_fast] = ground_speed[too_fast] = np.nan
    return error, ground_speed


def contact_scores(labels: np.ndarray, flows: np.ndarray, object_ids: np.ndarray,
                   config: GroundConfig | None = None) -> np.ndarray:
    """Ground-contact score of each object over a window (> 1: its foot slides over the ground, it moves).

    score = median_pairs(error) / (relative · median_pairs(ground speed) + absolute) over the pairs in which
    the ground was found and the object had a foot (at least ``min_pairs`` of them).

    Args:
        labels: (F, H, W) int per-frame instance ids (0 = background).
        flows: (F-1, H, W, 2) forward flow from frame m to m + 1.
        object_ids: (K,) ids to score.
        config: settings (default GroundConfig()).

    Returns:
        (K,) scores; NaN where the object never had enough contact with a visible ground.
    """
    config = config or GroundConfig()
    object_ids = np.asarray(object_ids)
    errors, speeds = [], []
    for m in range(flows.shape[0]):
        homography = fit_ground_homography(labels[m], flows[m], config)
        if homography is None:
            continue
        error, speed = contact_errors(labels[m], flows[m], homography, object_ids, config)
        errors.append(error)
        speeds.append(speed)
    scores = np.full(len(object_ids), np.nan)
    if not errors:
        return scores
    errors, speeds = np.array(errors), np.array(speeds)
    seen = np.isfinite(errors).sum(axis=0) >= config.min_pairs
    if seen.any():
        err = np.nanmedian(errors[:, seen], axis=0)
        speed = np.nanmedian(speeds[:, seen], axis=0)
        scores[seen] = err / (config.relative * speed + config.absolute)
    return scores
