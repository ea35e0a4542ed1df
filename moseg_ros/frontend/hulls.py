"""Hulls of moving tracks: flagged tracks linked into groups, each group's hull drawn (the regions stage's drawing).

Flagged tracks closer than a link distance are linked (scipy.spatial.cKDTree's pairs, then the graph's connected
components, scipy.sparse.csgraph); each group large enough fills its hull: the convex hull, or the triangles of its
tracks' Delaunay triangulation whose sides are short (an alpha shape's region, which follows the bays of an outline
that the convex hull bridges), unless the tracks known to be static crowd it. ``touching`` keeps the connected
regions of one mask that reach another's pixels (hysteresis, as in Canny's edges).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay, QhullError, cKDTree


def linked_groups(points: np.ndarray, link_px: float, min_group: int) -> np.ndarray:
    """Groups of points linked when closer than ``link_px`` (the connected components of that graph).

    Args:
        points: (N, 2) positions (x, y).
        link_px: largest distance between two linked points.
        min_group: smallest group kept.

    Returns:
        (N,) int64 group of each point; -1 for the points of groups smaller than ``min_group``.
    """
    if len(points) < min_group:
        return np.full(len(points), -1, dtype=np.int64)
    pairs = cKDTree(points).query_pairs(link_px, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
    _, group = connected_components(graph, directed=False)
    return np.where(np.bincount(group)[group] >= min_group, group, -1).astype(np.int64)


def hull_mask(points: np.ndarray, shape: tuple[int, int], link_px: float, min_group: int,
              static: np.ndarray | None = None, purity: float = 0.0, group: np.ndarray | None = None,
              reach_px: float = 0.0) -> np.ndarray:
    """Mask of the hulls of the groups of linked points that are pure enough.

    Points closer than ``link_px`` are linked; the hull of every group of ``min_group`` or more is filled when
    n_group >= purity · (n_group + static points inside its convex hull).

    Args:
        points: (N, 2) positions (x, y).
        shape: (H, W) of the mask.
        link_px: largest distance between two linked points.
        min_group: smallest group that makes a region.
        static: optional (S, 2) positions of points known not to move; a hull they crowd is not drawn.
        purity: the smallest share of a hull's points that must be ``points`` (0: every group is drawn).
        group: optional (N,) ``linked_groups(points, link_px, min_group)``, when the caller has it already.
        reach_px: > 0: a group's hull is the union of the triangles of its points' Delaunay triangulation whose
            sides are at most this long (``reach_triangles``: a concave outline); 0: its convex hull.

    Returns:
        (H, W) bool mask.
    """
    mask = np.zeros(shape, dtype=np.uint8)
    group = linked_groups(points, link_px, min_group) if group is None else group
    sizes = np.bincount(group[group >= 0])
    static = np.zeros((0, 2)) if static is None or purity <= 0 else np.rint(static).astype(np.int64)
    for g in np.flatnonzero(sizes >= min_group):
        members = points[group == g]
        hull = cv2.convexHull(np.rint(members).astype(np.int32))
        x0, y0, w, h = cv2.boundingRect(hull)
        local = np.zeros((h, w), dtype=np.uint8)
        cv2.fillConvexPoly(local, hull - np.array([x0, y0], dtype=np.int32), 1)
        if len(static):
            near = static - [x0, y0]
            near = near[(near[:, 0] >= 0) & (near[:, 0] < w) & (near[:, 1] >= 0) & (near[:, 1] < h)]
            if sizes[g] < purity * (sizes[g] + local[near[:, 1], near[:, 0]].sum()):
                continue
        triangles = reach_triangles(members, reach_px) if reach_px > 0 and len(members) > 3 else None
        if triangles is not None:
            local[:] = 0
            if len(triangles):
                cv2.fillPoly(local, list(np.rint(triangles - [x0, y0]).astype(np.int32)), 1)
        view = mask[y0:y0 + h, x0:x0 + w]
        view |= local[:view.shape[0], :view.shape[1]]
    return mask.astype(bool)


def reach_triangles(points: np.ndarray, reach_px: float) -> np.ndarray | None:
    """The triangles of the points' Delaunay triangulation (scipy.spatial.Delaunay) whose sides are all at most
    ``reach_px`` long.

    Their union is the alpha shape's region, which follows an outline's bays where the convex hull bridges them.

    Args:
        points: (N, 2) positions (x, y).
        reach_px: longest side kept.

    Returns:
        (T, 3, 2) corners of the triangles; None when the points span no triangle (collinear, or fewer than
        three distinct).
    """
    try:
        corners = points[Delaunay(points).simplices]
    except QhullError:
        return None
    sides = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    return corners[sides.max(axis=1) <= reach_px]


def touching(candidates: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """The 8-connected regions of ``candidates`` that share a pixel with ``seeds`` (hysteresis).

    Args:
        candidates: (h, w) bool.
        seeds: (h, w) bool.

    Returns:
        (h, w) bool.
    """
    count, labels = cv2.connectedComponents(candidates.astype(np.uint8), connectivity=8)
    keep = np.zeros(count, dtype=bool)
    keep[labels[candidates & seeds]] = True
    keep[0] = False
    return keep[labels]
