"""The flow view around each moving object: grow it over the pixels whose dense flow follows it, trim the
background its convex hull swallowed.

For each drawn group of moving tracks two affine flow models are fitted, the group's own (its tracks) and the local
background's (the static tracks in its box widened by ``reach``)::

    (u, v) ≈ (x, y, 1) · A        A: (3, 2), least squares, refitted once without vectors whose residual
                                  exceeds max(2 × the median, 0.5 px)

A box pixel the object's model explains within ``join_fit_px`` and better than the background's by ``margin_px``
joins the mask when connected to the group's tracks; one the background's explains within ``trim_fit_px`` and
better by ``margin_px`` leaves it. docs/method.md has why each condition is there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core.geometry import flat_covariance, to_homogeneous


@dataclass(frozen=True)
class ObjectFlowConfig:
    """Settings of the flow view around moving groups (pixels of the mask).

    Attributes:
        margin_px: how much better one model must explain a pixel's flow than the other to claim it.
        join_fit_px: the largest error of the object's model at a pixel that joins the region.
        trim_fit_px: the largest error of the background's model at a hull pixel that leaves it.
        reach: the group's box is widened by this share of its size on every side (at least ``link_px``).
        min_background: fewest static tracks in the box that give the background's model (else no change).
    """

    margin_px: float = 0.5
    join_fit_px: float = 1.0
    trim_fit_px: float = 0.5
    reach: float = 0.5
    min_background: int = 6


def fit_affine_flows(xy: Sequence[np.ndarray], uv: Sequence[np.ndarray]) -> list[np.ndarray | None]:
    """Robust least-squares affine flow models of several sets of points at once.

    uv ≈ [x, y, 1] · A, fitted by least squares, then refitted once without the vectors whose residual exceeds
    max(2 × the set's median residual, 0.5 px). One fit and one refit serve all sets, as a frame's groups and
    their backgrounds need; the sets are stacked, not padded to the largest (a background may hold a hundred
    times a small group's tracks).

    Args:
        xy: S arrays (N_s, 2) of positions (x, y), each N_s >= 1.
        uv: S arrays (N_s, 2) of the flow vectors at them.

    Returns:
        S models (3, 2) A (refitted only when three or more vectors remain); None for a set with fewer than
        three points or (near) collinear ones.
    """
    counts = np.array([len(points) for points in xy])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    of_set = np.repeat(np.arange(len(counts)), counts)
    points = np.concatenate(xy).astype(np.float64)
    flow = np.concatenate(uv).astype(np.float64)
    params, valid = _stacked_flow_fit(points, flow, starts, np.ones(len(points)))
    predicted = np.einsum("nk,nkc->nc", to_homogeneous(points), params[of_set])
    residual = np.hypot(*(predicted - flow).T)
    limit = np.maximum(2.0 * _stacked_medians(residual, of_set, starts, counts), 0.5)
    keep = residual <= limit[of_set]
    kept = np.add.reduceat(keep, starts)
    again = valid & (kept >= 3) & (kept < counts)
    if again.any():
        refitted, fitted = _stacked_flow_fit(points, flow, starts, (keep & again[of_set]).astype(np.float64))
        better = again & fitted
        params[better] = refitted[better]
    return [params[s] if valid[s] else None for s in range(len(counts))]


def _stacked_flow_fit(points: np.ndarray, flow: np.ndarray, starts: np.ndarray,
                      weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares flow models (S, 3, 2) of S sets stacked in (N, 2) ``points`` and ``flow`` (set s
    from ``starts[s]`` on), and (S,) valid: at least three weighted points, not on a line. Each set is centred on
    its weighted centroid, which keeps its normal equations well conditioned."""
    of_set = np.repeat(np.arange(len(starts)), np.diff(np.append(starts, len(points))))
    total = np.add.reduceat(weights, starts)
    centroid = np.add.reduceat(weights[:, None] * points, starts) / np.maximum(total, 1e-12)[:, None]
    design = to_homogeneous(points - centroid[of_set])
    weighted = weights[:, None] * design
    gram = np.add.reduceat(weighted[:, :, None] * design[:, None, :], starts)
    rhs = np.add.reduceat(weighted[:, :, None] * flow[:, None, :], starts)
    valid = (np.add.reduceat(weights > 0, starts) >= 3) & ~flat_covariance(gram[:, :2, :2])
    gram[~valid] = np.eye(3)
    centred = np.linalg.solve(gram, rhs)
    # uv = (x - c, 1) · B = (x, 1) · A with A's last row B's less c · B's first two.
    params = centred.copy()
    params[:, 2] -= np.einsum("sk,skc->sc", centroid, centred[:, :2])
    return params, valid


def _stacked_medians(values: np.ndarray, of_set: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(S,) the median of each set's ``values`` (stacked as ``_stacked_flow_fit``'s; every set non-empty)."""
    ordered = values[np.lexsort((values, of_set))]
    return 0.5 * (ordered[starts + (counts - 1) // 2] + ordered[starts + counts // 2])


def affine_flow_error(params: np.ndarray, flow: np.ndarray, x0: int, y0: int) -> np.ndarray:
    """Distance between a crop of a flow field and an affine flow model at each of its pixels.

    e(x, y) = ||flow(x, y) − [x, y, 1] · A||, (x, y) in the full field's pixels.

    Args:
        params: (3, 2) affine model A.
        flow: (h, w, 2) crop of a larger flow field.
        x0, y0: the crop's top-left pixel in the larger field.

    Returns:
        (h, w) float32 distances in pixels.
    """
    h, w = flow.shape[:2]
    a = params.astype(np.float32)
    x = np.arange(x0, x0 + w, dtype=np.float32)[None, :]
    y = np.arange(y0, y0 + h, dtype=np.float32)[:, None]
    du = flow[..., 0] - (a[0, 0] * x + (a[1, 0] * y + a[2, 0]))
    dv = flow[..., 1] - (a[0, 1] * x + (a[1, 1] * y + a[2, 1]))
    return cv2.magnitude(du, dv)


def refine_by_flow(mask: np.ndarray, flow: np.ndarray, xy: np.ndarray, uv: np.ndarray, group: np.ndarray,
                   link_px: float, config: ObjectFlowConfig = ObjectFlowConfig()) -> np.ndarray:
    """Grow and trim each drawn group's region by its flow model against the local background's.

    Args:
        mask: (H, W) bool regions drawn from the moving tracks (hulls).
        flow: (H, W, 2) dense flow of the same frame pair as ``uv``.
        xy: (N, 2) track positions in the mask's pixels.
        uv: (N, 2) each track's displacement over that pair.
        group: (N,) int group of each moving track, -1 for a static track.
        link_px: the distance that linked the groups (the smallest widening of a group's box).
        config: margins and reach.

    Returns:
        (H, W) bool refined mask; groups whose tracks mostly lie outside ``mask`` (not drawn), and groups
        or backgrounds whose tracks lie on a line (no affine model), are left out.
    """
    out = mask.copy()
    height, width = mask.shape
    static = group < 0
    seeds_all = np.rint(xy).astype(np.int64)
    seeds_all[:, 0] = seeds_all[:, 0].clip(0, width - 1)
    seeds_all[:, 1] = seeds_all[:, 1].clip(0, height - 1)
    boxes, sets = [], []
    for g in np.unique(group[~static]):
        members = group == g
        seeds = seeds_all[members]
        if mask[seeds[:, 1], seeds[:, 0]].mean() < 0.5 or members.sum() < 3:
            continue
        (x0, y0), (x1, y1) = xy[members].min(axis=0), xy[members].max(axis=0)
        grow_x, grow_y = max(config.reach * (x1 - x0), link_px), max(config.reach * (y1 - y0), link_px)
        bx0, by0 = int(max(0, x0 - grow_x)), int(max(0, y0 - grow_y))
        bx1, by1 = int(min(width, x1 + grow_x + 1)), int(min(height, y1 + grow_y + 1))
        around = static & (xy[:, 0] >= bx0) & (xy[:, 0] < bx1) & (xy[:, 1] >= by0) & (xy[:, 1] < by1)
        if around.sum() < config.min_background:
            continue
        boxes.append((seeds, bx0, by0, bx1, by1))
        sets += [members, around]
    if not boxes:
        return out
    models = fit_affine_flows([xy[s] for s in sets], [uv[s] for s in sets])
    for (seeds, bx0, by0, bx1, by1), own_model, background_model in zip(boxes, models[::2], models[1::2]):
        if own_model is None or background_model is None:
            continue
        crop = flow[by0:by1, bx0:bx1]
        own = affine_flow_error(own_model, crop, bx0, by0)
        background = affine_flow_error(background_model, crop, bx0, by0)
        joins = (background - own > config.margin_px) & (own < config.join_fit_px)
        count, components = cv2.connectedComponents(joins.astype(np.uint8))
        reached = np.zeros(count, dtype=bool)
        reached[components[seeds[:, 1] - by0, seeds[:, 0] - bx0]] = True
        reached[0] = False
        view = out[by0:by1, bx0:bx1]
        view &= (own - background <= config.margin_px) | (background >= config.trim_fit_px)
        view |= reached[components]
    return out
