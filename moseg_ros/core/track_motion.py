"""Which point trajectories move by themselves: the four track tests of one frame pair, and their verdict over a window.

Per frame pair (m, m + gap) ``pair_evidence`` fits the camera's dominant F to the tracks seen in both frames
(core/track_tests/epipolar.py) and, with K, signs their parallax (cheirality.py) and compares it with the road's
(ground.py) and with the surface under each track (footing.py). ``moving_tracks`` decides per track over the
window: its median epipolar distance above max(factor × the median over tracks, floor), or any depth test.
docs/method.md has the geometry and why each setting is what it is.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from moseg_ros.core.robust import row_medians
from moseg_ros.core.track_tests.cheirality import guarded_signs, signed_parallax
from moseg_ros.core.track_tests.columns import footing_columns
from moseg_ros.core.track_tests.epipolar import epipolar_fit
from moseg_ros.core.track_tests.footing import footing_excess
from moseg_ros.core.track_tests.ground import (decided_ratios, ground_floor, ground_slope, short_of_ground,
                                               standing_shortfall)
from moseg_ros.core.track_tests.settings import TrackMotionConfig


class PairEvidence(NamedTuple):
    """One frame pair's evidence per track; the depth tests' fields only given a camera matrix and a
    non-degenerate F, each None when not decided.

    Attributes:
        distance: (N,) epipolar distances, as ``pair_residual``.
        signed: (N,) signed parallax (``signed_parallax``), or None.
        ground: (N,) ground ratios (``decided_ratios``), or None.
        footing: (N,) footing excesses (``footing_excess``), or None.
        shortfall: (N,) shortfall margins (``standing_shortfall``), or None.
    """

    distance: np.ndarray
    signed: np.ndarray | None = None
    ground: np.ndarray | None = None
    footing: np.ndarray | None = None
    shortfall: np.ndarray | None = None


def pair_evidence(x1: np.ndarray, x2: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                  K: np.ndarray | None = None, guarded: bool = False,
                  planar_check: bool = True) -> PairEvidence | None:
    """The evidence of one frame pair's tracks.

    The distances are ``epipolar_fit``'s; the depth tests run only under a non-degenerate F and with ``K``.

    Args:
        x1, x2: (N, 2) track positions in the pair's first and second frame (pixels).
        config: settings.
        K: optional (3, 3) camera matrix; None = no depth tests.
        guarded: the rotation may be misjudged: a track is behind infinity only by at least ``behind_share``
            of the rotation's image motion at it, and pairs turning more than ``max_rotation_deg`` sign
            nothing else (``signed_parallax``).
        planar_check: False skips the homography's test of F's degeneracy (a caller that knows the camera
            translates, from a pair of the same window; the homography fit is the costlier half).

    Returns:
        PairEvidence with (N,) fields; None when there is no model at all.
    """
    fit = epipolar_fit(x1, x2, config, planar_check)
    if fit is None or fit.fundamental is None or K is None:
        return None if fit is None else PairEvidence(fit.distance)
    x1, x2, distance = np.asarray(x1, dtype=np.float64), np.asarray(x2, dtype=np.float64), fit.distance
    limit = config.max_rotation_deg if guarded else np.inf
    parallax = signed_parallax(x1, x2, fit.fundamental, fit.inliers, K, config, limit)
    if parallax is None:
        return PairEvidence(distance)
    slope = ground_slope(x1, parallax, config)  # once for the ground, shortfall and footing tests
    signed = guarded_signs(x1, parallax, config.behind_share) if guarded else parallax.signed
    if slope is None:
        return PairEvidence(distance, signed, None, footing_excess(x1, parallax, None, config, slope))
    floor = ground_floor(x1, parallax, config, slope)  # once for the ratios and which of them are decided
    ground = (parallax.signed / floor).astype(np.float32)  # as ground_parallax_ratio gives them
    columns = footing_columns(x1, parallax, ground, config)  # once for the footing and shortfall tests
    return PairEvidence(distance, signed, decided_ratios(ground, floor, config, fit.noise),
                        footing_excess(x1, parallax, ground, config, slope, columns),
                        standing_shortfall(x1, parallax, ground, config, slope, columns))


def moving_tracks(residuals: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                  signed: np.ndarray | None = None, ground: np.ndarray | None = None,
                  footing: np.ndarray | None = None, shortfall: np.ndarray | None = None,
                  dense: np.ndarray | None = None, measurable: np.ndarray | None = None,
                  depth: np.ndarray | None = None) -> np.ndarray:
    """Which tracks move over a window: the epipolar distance test or any depth test (``depth_moving``).

    A track n moves when its median distance d_n over its pairs exceeds

        τ = max(factor · median_n d_n, floor_px)

    (and, when ``dense`` is given, dense_n >= corroboration · d_n or d_n > evident_factor · τ), or when its
    median signed parallax is below -cheir_px, its median ground ratio below ground_ratio, its median footing
    excess above footing_px, or it falls short of the ground where it stands in most pairs
    (``short_of_ground``, where ``measurable``).

    Args:
        residuals: (N, P) distances from ``pair_residuals`` (NaN = not measured).
        config: the factor and floor.
        signed: optional (N, P) signed parallax (NaN = not measured or pair undecided).
        ground: optional (N, P) ratios of ``ground_parallax_ratio`` (NaN = undecided).
        footing: optional (N, P) excesses of ``footing_excess`` (NaN = undecided).
        shortfall: optional (N, P) margins of ``standing_shortfall`` (NaN = undecided).
        dense: optional (N,) the dense flow's epipolar residual near each track, in the units of its distance
            (NaN: not known there, no corroboration asked).
        measurable: optional (N,) bool, the tracks whose image can show their parallax (``aperture_share``);
            the shortfall test takes only those (default: every track).
        depth: optional (N,) bool, the depth tests' part (``depth_moving`` of the same arguments) when the caller
            has it already; then ``signed`` to ``measurable`` are not read.

    Returns:
        (N,) bool, True for moving tracks.
    """
    per_track = row_medians(residuals)
    measured = ~np.isnan(per_track)
    moving = np.zeros(residuals.shape[0], dtype=bool)
    if not measured.any():
        return moving
    threshold = max(config.factor * float(np.median(per_track[measured])), config.floor_px)
    moving[measured] = per_track[measured] > threshold
    if dense is not None and config.corroboration > 0:
        doubted = dense < config.corroboration * per_track  # NaN compares False
        moving &= ~doubted | (per_track > config.evident_factor * threshold)
    if depth is None:
        depth = depth_moving(residuals.shape[0], config, signed, ground, footing, shortfall, measurable)
    return moving | depth


def depth_moving(n: int, config: TrackMotionConfig = TrackMotionConfig(), signed: np.ndarray | None = None,
                 ground: np.ndarray | None = None, footing: np.ndarray | None = None,
                 shortfall: np.ndarray | None = None, measurable: np.ndarray | None = None) -> np.ndarray:
    """The part of ``moving_tracks`` that the depth tests flag (cheirality, the ground's ratio and shortfall,
    the footing).

    These catch tracks whose motion lies along their epipolar lines, which no epipolar distance and no model of
    an object's own motion shows (a car driving along the camera's axis images as a static copy of it:
    docs/experiments.md).

    Args:
        n: the number of tracks N.
        config, signed, ground, footing, shortfall, measurable: as ``moving_tracks``.

    Returns:
        (N,) bool.
    """
    moving = np.zeros(n, dtype=bool)
    if signed is not None:
        moving |= _median_below(signed, -config.cheir_px)
    if ground is not None:
        moving |= _median_below(ground, config.ground_ratio)
    if footing is not None:
        moving |= _median_below(-footing, -config.footing_px)
    if shortfall is not None:
        short = short_of_ground(shortfall)
        moving |= short if measurable is None else short & measurable
    return moving


def _median_below(values: np.ndarray, limit: float) -> np.ndarray:
    """(N,) bool: rows of (N, P) ``values`` with a measurement (not NaN) whose median is below ``limit``."""
    return row_medians(values) < limit  # NaN (no measurement) compares False
