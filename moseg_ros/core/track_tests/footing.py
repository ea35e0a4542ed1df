"""The footing test: a track nearer than the surface seen under it moves (a car driving towards the camera).

Below the horizon a static surface is never nearer than what is visible under it in the same column, so a
track whose inverse depth exceeds its footing's (a low order statistic of the tracks under it, or the fitted
road at the first road track under it) by ``footing_allowance`` and ``footing_px`` moves. ``nearer_than_road``
runs the same test on every pixel of a dense flow. docs/method.md has the derivation.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from moseg_ros.core.flow_field import pixel_grid
from moseg_ros.core.track_tests.cheirality import DenseParallax, Parallax
from moseg_ros.core.track_tests.columns import footing_base, footing_columns, FootingColumns
from moseg_ros.core.track_tests.ground import ground_slope
from moseg_ros.core.track_tests.settings import TrackMotionConfig


def nearer_than_road(parallax: DenseParallax, valid: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(), *,
                     excess_px: float | None = None, clearance: float = 0.0,
                     sample_step: int = 4) -> np.ndarray | None:
    """Reliable pixels below the epipole that look nearer than the road where they stand: the footing test
    (``footing_excess``) for every pixel of a dense flow.

    A pixel moves when signed > footing_allowance(first road row) · footing parallax + excess_px.

    The road's inverse depth is ``ground_slope`` fitted to every ``sample_step``-th reliable pixel. A pixel of the
    road is one within ``footing_road_tol`` of it; a pixel stands no lower than the first road pixel under it in
    its column, so the road's inverse depth there bounds a static pixel's own. A pixel moves when its parallax
    exceeds the parallax that bound gives it, times ``footing_allowance``, by more than ``excess_px``. An
    oncoming car closes in faster than the camera drives and looks nearer than the road it stands on; its
    tracks are few while it is far, and the first road track under it lies well below the road it stands on
    (docs/experiments.md), while the dense flow sees the road up to a few pixels under its bumper. The lower part
    of a static object is as near as its foot, so it passes for road within the tolerance, and a margin at least
    the tolerance keeps the object above it unflagged; the allowance's overhang share keeps a parked car's bumper
    over the farther road under its body.

    Args:
        parallax: the flow's ``dense_parallax``.
        valid: (H, W) bool pixels whose flow is reliable.
        config: the footing and ground settings.
        excess_px: the least excess in the flow's own pixels (default ``footing_px``, which is in the tracks').
        clearance: a footing counts only where its column holds road more than this share of the height below it.
        sample_step: the stride of the pixels the road's slope is fitted to.

    Returns:
        (H, W) bool; None without an epipole row (the camera does not move along its axis, or the pair turned)
        or a road.
    """
    if parallax.epipole_row is None:
        return None
    h, w = valid.shape
    sample = (slice(None, None, sample_step), slice(None, None, sample_step))
    keep = valid[sample]
    pixels = pixel_grid(h, w)[sample][keep].astype(np.float64)
    sampled = replace(parallax.vote, signed=parallax.signed[sample][keep], gain=parallax.gain[sample][keep],
                      epipole_row=parallax.epipole_row)
    slope = ground_slope(pixels, sampled, config)
    if slope is None:
        return None
    rows = np.arange(h, dtype=np.float32)[:, None]
    below = rows > parallax.epipole_row
    road_depth = slope * np.maximum(rows - parallax.epipole_row, 0.0)  # (H, 1) inverse depth x baseline
    road_px = road_depth * parallax.gain
    depth = parallax.signed / np.maximum(parallax.gain, 1e-12)
    road = valid & below & (road_px >= config.ground_min_px) & (
        np.abs(depth - road_depth) <= config.footing_road_tol * road_depth)
    # The first road row at or under each pixel of its column (h: none), a running minimum from the image's bottom
    # up; in the smallest integer type that holds h, twice as fast as in floats.
    index = np.arange(h, dtype=np.min_scalar_type(h))[:, None]
    first_road = np.minimum.accumulate(np.where(road, index, index.dtype.type(h))[::-1], axis=0)[::-1]
    footing_px = slope * np.maximum(first_road.astype(np.float32) - parallax.epipole_row, 0.0) * parallax.gain
    # The tolerance lets an object's own lowest part pass for road where the road under it is out of view (a parked
    # car cut by the image's lower edge): a footing counts only where the road goes on clearly below it.
    further = first_road.astype(np.intp) + int(np.ceil(clearance * h))
    confirmed = (further < h) & (np.take_along_axis(first_road, np.minimum(further, h - 1), axis=0) < h)
    decided = valid & below & confirmed & (footing_px >= config.ground_min_px)
    excess_px = config.footing_px if excess_px is None else excess_px
    allowed = footing_allowance(first_road, parallax.epipole_row, parallax.vote.focal, config) * footing_px
    return decided & (parallax.signed > allowed + excess_px)


def footing_excess(x1: np.ndarray, parallax: Parallax, ground: np.ndarray | None,
                   config: TrackMotionConfig = TrackMotionConfig(), slope: float | None = None,
                   columns: FootingColumns | None = None) -> np.ndarray | None:
    """(N,) float32 pixels by which each track's parallax exceeds what the surface under it allows.

    For a track below the epipole, the tracks below it within ``footing_band`` of the tracks' horizontal extent
    are its column. Its footing is the ``footing_support``-th lowest inverse depth (signed / gain) of the
    column or, when lower and ``ground`` is given, the ground's inverse depth at the row the track's object
    stands on: the lower of the column's first road track (a ground ratio within ``footing_road_tol`` of 1) and
    the object's lowest track (``footing_base``: the lowest track of the column at the track's own inverse
    depth, within ``footing_same_depth``, that is not a road track itself). The excess is

        excess = signed − footing_allowance · footing · gain.

    A static track's excess is negative; an oncoming car's
    is positive (it closes in faster than the camera drives and looks nearer than the road under it).

    Args:
        x1: (N, 2) positions in the pair's earlier frame.
        parallax: the pair's ``signed_parallax``.
        ground: (N,) the pair's ``ground_parallax_ratio`` or None; tracks below ``ground_ratio`` are no
            footing (a followed car looks farther than anything behind it).
        config: the footing settings (``ground_min_px``: where the footing's parallax is below it, the track
            is not decided).
        slope: the pair's ``ground_slope`` when the caller has it (computed here otherwise, when ``ground``
            is given).
        columns: the pair's ``footing_columns`` when the caller has them (found here otherwise).

    Returns:
        (N,) float32 excesses in pixels, NaN where not decided; None when the camera does not move forward.
    """
    if parallax.epipole_row is None:
        return None
    excess = np.full(len(x1), np.nan, dtype=np.float32)
    tested, index, under, depth = footing_columns(x1, parallax, ground, config) if columns is None else columns
    if not tested.size:
        return excess
    rows = x1[index, 1]
    k = config.footing_support
    support = np.full(len(tested), np.inf, dtype=np.float32)
    support_row = x1[tested, 1].astype(np.float64)
    if under.shape[1] >= k:
        candidates = np.where(under, depth[index], np.inf).astype(np.float32)
        kth = np.argpartition(candidates, k - 1, axis=1)[:, k - 1:k]
        support, support_row = (np.take_along_axis(candidates, kth, axis=1)[:, 0],
                                np.take_along_axis(rows, kth, axis=1)[:, 0])
    if ground is None or config.footing_road_tol <= 0:
        slope = None
    elif slope is None:
        slope = ground_slope(x1, parallax, config)
    road = (under & (np.abs(ground[index] - 1.0) <= config.footing_road_tol) if slope is not None
            else np.zeros_like(under))
    base = footing_base(x1[tested, 1], rows, under & ~road, depth[index], depth[tested], config.footing_same_depth)
    if slope is not None:
        first_road = np.where(road, rows, np.inf).min(axis=1)
        found = np.isfinite(first_road)
        stands = np.maximum(first_road[found], base[found])
        road_support = slope * (stands - parallax.epipole_row)
        lower = road_support < support[found]
        on_road = np.flatnonzero(found)[lower]
        support[on_road], support_row[on_road] = road_support[lower], stands[lower]
    ahead = support * parallax.gain[tested]  # the parallax the footing's depth gives at the track
    # Where nothing of the column lies clearly below the object's lowest track, its ground contact is out of view
    # (a near parked van cut by the image's edge), and what the column holds lies beside the object, not under it.
    seen = (under & (rows > base[:, None] + config.footing_clearance * float(np.ptp(x1[:, 1])))).any(axis=1)
    decided = np.isfinite(ahead) & (ahead >= config.ground_min_px) & seen
    allowance = footing_allowance(support_row, parallax.epipole_row, parallax.focal, config)
    excess[tested[decided]] = (parallax.signed[tested] - allowance * ahead)[decided]
    return excess


def footing_allowance(rows: np.ndarray, epipole_row: float, focal: float,
                      config: TrackMotionConfig = TrackMotionConfig()) -> np.ndarray:
    """The factor over a footing's parallax that a static point's parallax may reach.

    a = 1 + footing_margin + footing_overhang · max(row − epipole_row, 0) / focal

    the last term the overhang's share of the footing's inverse depth over a level road
    (``TrackMotionConfig.footing_overhang``).

    Args:
        rows: (...) rows of the footings (any shape).
        epipole_row: the pair's epipole row.
        focal: K's vertical focal length (pixels).
        config: ``footing_margin`` and ``footing_overhang``.

    Returns:
        (...) float32 factors.
    """
    tangent = np.maximum(np.asarray(rows, dtype=np.float32) - np.float32(epipole_row), 0.0) / np.float32(focal)
    return 1.0 + config.footing_margin + config.footing_overhang * tangent
