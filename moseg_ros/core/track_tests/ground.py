"""The ground test: a track below the horizon farther than the road there moves (a car followed at the camera's speed).

For a camera driving over level ground the road's inverse depth is an affine function of the row below the
epipole, so its parallax is too; ``ground_slope`` fits it to the lowest inverse depths of the tracks, and a track
moves when its parallax ratio to that floor is below ``ground_ratio`` or, where it stands (``standing_rows``), it
falls short of the floor by ``shortfall_px`` and a share. docs/method.md has the derivation.
"""

from __future__ import annotations

import numpy as np

from moseg_ros.core.track_tests.cheirality import Parallax
from moseg_ros.core.track_tests.columns import footing_base, footing_columns, FootingColumns
from moseg_ros.core.track_tests.settings import TrackMotionConfig


def ground_slope(x1: np.ndarray, parallax: Parallax, config: TrackMotionConfig = TrackMotionConfig()) -> float | None:
    """The ground's inverse depth (x the pair's baseline) per row below the epipole.

    slope = lower quartile over bands k of percentile_q(ρ of band k's tracks) / (height of band k's centre), with
    ρ = signed / gain > 0 and height = row − epipole row > 0 (``ground_parallax_ratio`` explains the bands).

    Args:
        x1: (N, 2) positions in the pair's earlier frame.
        parallax: the pair's ``signed_parallax``.
        config: the ground settings.

    Returns:
        The slope; None when the camera does not move forward or fewer than three bands hold
        ``ground_band_tracks`` tracks.
    """
    if parallax.epipole_row is None:
        return None
    height = x1[:, 1] - parallax.epipole_row
    depth = parallax.signed / np.maximum(parallax.gain, 1e-12)  # inverse depth x baseline
    usable = (height > 0) & (parallax.gain > 0) & (depth > 0)
    if usable.sum() < 3 * config.ground_band_tracks:
        return None
    edges = np.linspace(0.0, float(height[usable].max()) + 1e-6, config.ground_bands + 1)
    band = np.digitize(height, edges) - 1
    slopes = []
    for k in range(config.ground_bands):
        members = usable & (band == k)
        if members.sum() >= config.ground_band_tracks:
            slopes.append(np.percentile(depth[members], config.ground_quantile) / (0.5 * (edges[k] + edges[k + 1])))
    return float(np.percentile(slopes, 25)) if len(slopes) >= 3 else None


def ground_parallax_ratio(x1: np.ndarray, parallax: Parallax, config: TrackMotionConfig = TrackMotionConfig(),
                          slope: float | None = None) -> np.ndarray | None:
    """Each track's signed parallax over the parallax the ground would have at its pixel.

    ratio = signed / (slope · (row − epipole row) · gain)

    The ground's inverse depth is taken as ``slope x (row - epipole row)`` below the epipole: in each of
    ``ground_bands`` bands of rows there, the ``ground_quantile`` percentile of the tracks' inverse depths
    (signed / gain) over the band's distance from the epipole gives a slope, and the lower quartile of the
    bands' slopes is the floor's (the road holds the lowest inverse depths of a band; bands seeing only
    objects on it give steeper slopes).

    Args:
        x1: (N, 2) positions in the pair's earlier frame (where ``parallax`` was measured).
        parallax: the pair's ``signed_parallax``.
        config: the ground settings.
        slope: the pair's ``ground_slope`` when the caller has it (computed here otherwise).

    Returns:
        (N,) float32 ratios, NaN above the epipole and where the floor's parallax is below ``ground_min_px``;
        None when the camera does not move forward or fewer than three bands hold ``ground_band_tracks`` tracks.
    """
    floor = ground_floor(x1, parallax, config, slope)
    return None if floor is None else (parallax.signed / floor).astype(np.float32)


def ground_floor(x1: np.ndarray, parallax: Parallax, config: TrackMotionConfig = TrackMotionConfig(),
                 slope: float | None = None, rows: np.ndarray | None = None) -> np.ndarray | None:
    """The parallax the ground would have at each track's pixel: floor = slope · max(row − epipole row, 0) · gain.

    ``ground_parallax_ratio`` describes the floor.

    Args:
        x1: (N, 2) positions in the pair's earlier frame.
        parallax: the pair's ``signed_parallax``.
        config: the ground settings.
        slope: the pair's ``ground_slope`` when the caller has it (computed here otherwise).
        rows: optional (N,) rows to take in each track's column instead of its own.

    Returns:
        (N,) float64 pixels, NaN above the epipole and where it is below ``ground_min_px``; None without a slope.
    """
    if slope is None:
        slope = ground_slope(x1, parallax, config)
    if slope is None:
        return None
    rows = x1[:, 1] if rows is None else rows
    floor = slope * np.maximum(rows - parallax.epipole_row, 0.0) * parallax.gain
    return np.where(floor >= config.ground_min_px, floor, np.nan)


def standing_shortfall(x1: np.ndarray, parallax: Parallax, ground: np.ndarray | None,
                       config: TrackMotionConfig = TrackMotionConfig(), slope: float | None = None,
                       columns: FootingColumns | None = None) -> np.ndarray | None:
    """Pixels by which each track falls short of the ground where it stands, by both of the shortfall test's
    measures.

    margin = floor − signed − min(max(shortfall_px, (1 − shortfall_ratio) · floor),
                                  max(shortfall_strong_px, (1 − shortfall_strong_ratio) · floor))

    the floor being ``ground_floor`` at the track's ``standing_rows`` (the strong term only when
    ``shortfall_strong_px`` > 0). Positive: farther than the ground there by more than ``shortfall_px`` and
    below ``shortfall_ratio`` of it, or by more than ``shortfall_strong_px`` and below ``shortfall_strong_ratio``
    of it (one pair's verdict on both, so that the window's majority, ``short_of_ground``, asks both of the
    same pairs).

    Args:
        x1: (N, 2) positions in the pair's earlier frame.
        parallax: the pair's ``signed_parallax``.
        ground: optional (N,) ground ratios (for ``footing_columns``).
        config: the shortfall settings.
        slope: the pair's ``ground_slope`` when the caller has it.
        columns: the pair's ``footing_columns`` when the caller has them.

    Returns:
        (N,) float32 margins; NaN and None as ``ground_floor``.
    """
    floor = ground_floor(x1, parallax, config, slope, standing_rows(x1, parallax, ground, config, columns))
    if floor is None:
        return None
    # Each measure asks for the larger of its pixels and its share of the floor; the track meets the lesser ask.
    needed = np.maximum(config.shortfall_px, (1.0 - config.shortfall_ratio) * floor)
    if config.shortfall_strong_px > 0:
        strong = np.maximum(config.shortfall_strong_px, (1.0 - config.shortfall_strong_ratio) * floor)
        needed = np.minimum(needed, strong)
    return (floor - parallax.signed - needed).astype(np.float32)


def standing_rows(x1: np.ndarray, parallax: Parallax, ground: np.ndarray | None,
                  config: TrackMotionConfig = TrackMotionConfig(),
                  columns: FootingColumns | None = None) -> np.ndarray:
    """The row each track's object stands on at least.

    The lowest track below it in its column (``footing_columns``) at its own inverse depth within
    ``shortfall_same_depth``, or its own row (above the epipole, and without such a track).

    An upright static object is as near as the ground where it stands, and that lies at or below its lowest
    track; a pedestrian walking away looks farther than the ground under its feet from every one of its tracks,
    while its upper tracks look nearer than the road at their own rows (which lies farther away).

    Args:
        x1: (N, 2) positions in the pair's earlier frame.
        parallax: the pair's ``signed_parallax``.
        ground: optional (N,) ground ratios (for ``footing_columns``).
        config: ``shortfall_same_depth`` and the column settings.
        columns: the pair's ``footing_columns`` when the caller has them.

    Returns:
        (N,) float64 rows.
    """
    rows = x1[:, 1].astype(np.float64)
    if parallax.epipole_row is None:
        return rows
    tested, index, under, depth = footing_columns(x1, parallax, ground, config) if columns is None else columns
    if tested.size:
        rows[tested] = footing_base(rows[tested], x1[index, 1], under, depth[index], depth[tested],
                                     config.shortfall_same_depth)
    return rows


def decided_ratios(ground: np.ndarray, floor: np.ndarray, config: TrackMotionConfig, noise: float) -> np.ndarray:
    """The ground ratios the ratio test decides on: NaN where floor < ground_ratio_noise · noise.

    The footing and shortfall tests keep every ratio.

    Args:
        ground: (N,) ratios (``ground_parallax_ratio``).
        floor: (N,) the ground's parallax (``ground_floor``, pixels).
        config: ``ground_ratio_noise``.
        noise: the pair's noise (pixels).

    Returns:
        (N,) float32 ratios.
    """
    return np.where(floor >= config.ground_ratio_noise * noise, ground, np.nan).astype(np.float32)


def short_of_ground(shortfall: np.ndarray) -> np.ndarray:
    """Tracks short of the ground where they stand in more than half of the pairs that measured them.

    ``moving_tracks``' ground shortfall test before its ``measurable`` check. A majority rather than the
    median: the median of an even count averages a pair far short with one that is not.

    Args:
        shortfall: (N, P) margins of ``standing_shortfall`` (positive = short; NaN = not measured).

    Returns:
        (N,) bool.
    """
    return np.count_nonzero(shortfall > 0, axis=1) > 0.5 * np.count_nonzero(~np.isnan(shortfall), axis=1)


def aperture_share(gray: np.ndarray, points: np.ndarray, centre: np.ndarray, window: int) -> np.ndarray:
    """Share of the image-gradient energy around each point that lies along the line from ``centre`` through it.

    It says how well a patch tracker measures the point's motion along that line (0 on an edge running along
    it, the aperture problem; 1 on an edge across it, about 0.5 on a corner).

    d^T G d / trace(G), with G the structure tensor (summed products of Sobel 3x3 gradients) over a ``window`` x
    ``window`` patch and d the unit direction from ``centre`` to the point. Computed on each point's patch
    alone (the border pixel repeated outside the image): the test asks it of a few tracks a frame.

    Args:
        gray: (H, W) image.
        points: (N, 2) positions (x, y) in it; outside ones take the nearest border pixel.
        centre: (2,) where the lines start (the epipole of a camera driving forward: its parallax runs from it).
        window: side of the patch, pixels (odd).

    Returns:
        (N,) shares in [0, 1].
    """
    h, w = gray.shape
    x, y = np.clip(np.rint(points).astype(np.int64), 0, [w - 1, h - 1]).T
    reach = np.arange(-(window // 2) - 1, window // 2 + 2)
    rows, columns = np.clip(y[:, None] + reach, 0, h - 1), np.clip(x[:, None] + reach, 0, w - 1)
    patch = gray[rows[:, :, None], columns[:, None, :]].astype(np.float32)  # (N, window + 2, window + 2)
    smooth_y = patch[:, :-2] + 2.0 * patch[:, 1:-1] + patch[:, 2:]
    smooth_x = patch[:, :, :-2] + 2.0 * patch[:, :, 1:-1] + patch[:, :, 2:]
    gx, gy = smooth_y[:, :, 2:] - smooth_y[:, :, :-2], smooth_x[:, 2:] - smooth_x[:, :-2]
    xx, xy, yy = ((a * b).sum(axis=(1, 2)) for a, b in ((gx, gx), (gx, gy), (gy, gy)))
    d = points - np.asarray(centre, dtype=np.float64)
    d /= np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
    along = xx * d[:, 0] ** 2 + 2.0 * xy * d[:, 0] * d[:, 1] + yy * d[:, 1] ** 2
    return along / np.maximum(xx + yy, 1e-12)
