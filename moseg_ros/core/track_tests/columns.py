"""What lies under each track in its image column: the candidates a footing or a standing row is read from.

Shared by the ground test (the row an object stands on) and the footing test (the surface seen under it).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from moseg_ros.core.track_tests.cheirality import Parallax
from moseg_ros.core.track_tests.settings import TrackMotionConfig


class FootingColumns(NamedTuple):
    """What lies under each track of a pair (``footing_columns``).

    Attributes:
        tested: (T,) int indices of the tracks below the epipole (T = 0 when no band holds a candidate).
        index: (T, run) int indices of the tracks in each one's column band (as ``_band_below``).
        under: (T, run) bool, True where that track is a candidate under the tested one.
        depth: (N,) every track's inverse depth, signed / gain.
    """

    tested: np.ndarray
    index: np.ndarray
    under: np.ndarray
    depth: np.ndarray


def footing_columns(x1: np.ndarray, parallax: Parallax, ground: np.ndarray | None,
                    config: TrackMotionConfig = TrackMotionConfig()) -> FootingColumns:
    """The column under each track below the epipole and the tracks in it that may be a footing.

    The column is ``footing_band`` of the tracks' horizontal extent wide; a footing lies in front of infinity
    and, with ``ground``, not below ``ground_ratio`` (a followed car looks farther than anything behind it).
    The footing and standing tests share them.

    Args:
        x1: (N, 2) positions in the pair's earlier frame.
        parallax: the pair's ``signed_parallax`` (with an epipole row).
        ground: optional (N,) ground ratios (``ground_parallax_ratio``).
        config: ``footing_band`` and ``ground_ratio``.

    Returns:
        FootingColumns.
    """
    depth = parallax.signed / np.maximum(parallax.gain, 1e-12)
    below_horizon = x1[:, 1] > parallax.epipole_row
    footing = below_horizon & (parallax.gain > 0) & (depth > 0)
    if ground is not None:
        footing &= ~(ground < config.ground_ratio)
    tested = np.flatnonzero(below_horizon)
    column = _band_below(x1, np.flatnonzero(footing), tested, config.footing_band * float(np.ptp(x1[:, 0])))
    if column is None:
        return FootingColumns(tested[:0], np.zeros((0, 0), dtype=np.int64), np.zeros((0, 0), dtype=bool), depth)
    return FootingColumns(tested, *column, depth)


def footing_base(row: np.ndarray, rows: np.ndarray, under: np.ndarray, depths: np.ndarray, depth: np.ndarray,
                  same_depth: float) -> np.ndarray:
    """The lowest row (largest y) of each tested track's object.

    base = max(row, max{rows_j : under_j, |depths_j / depth − 1| <= same_depth}): its own row or that of the
    lowest track under it at its own inverse depth. A thin pole hides little of the road beside its trunk; the
    road seen there lies behind it, not under it.

    Args:
        row: (T,) the tested tracks' rows.
        rows: (T, run) rows of the tracks in each one's band (from ``_band_below``).
        under: (T, run) bool, the tracks under it.
        depths: (T, run) their inverse depths.
        depth: (T,) the tested tracks' inverse depths.
        same_depth: relative tolerance of "the same inverse depth".

    Returns:
        (T,) float64 rows.
    """
    same = under & (np.abs(depths / np.maximum(depth, 1e-12)[:, None] - 1.0) <= same_depth)
    return np.maximum(np.where(same, rows, -np.inf).max(axis=1), row)


def _band_below(x: np.ndarray, candidates: np.ndarray, tested: np.ndarray,
                band: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The candidates in each tested point's column: (T, run) indices into x and (T, run) bool, True where the
    candidate is within ``band`` of the tested point's column and lower in the image; None when no band holds
    one.

    The candidates are sorted by column, so each tested point compares only with the run of candidates in its
    band (a (tested, longest run) table instead of (tested, candidates))."""
    if len(candidates) == 0 or len(tested) == 0:
        return None
    order = candidates[np.argsort(x[candidates, 0], kind="stable")]
    cx = x[order, 0]
    first = np.searchsorted(cx, x[tested, 0] - band, side="right")
    stop = np.searchsorted(cx, x[tested, 0] + band, side="left")
    run = int((stop - first).max())
    if run < 1:
        return None
    index = first[:, None] + np.arange(run)
    inside = index < stop[:, None]
    index = order[np.minimum(index, len(order) - 1)]
    return index, inside & (x[index, 1] > x[tested, 1][:, None])
