"""Stage 2a, track evidence: which tracks move, from the track tests of every frame pair of the window.

Runs on the refit's worker (or inline). Each frame pair (m, m + gap) is fitted once (``pair_evidence``: the
epipolar, cheirality, ground and footing tests); a track moves when ``moving_tracks`` says so over the window's
pairs (its epipolar distance corroborated by the last dense residual near it), and stays flagged while it was
flagged in ``sticky_windows`` windows, the last at most ``sticky_frames`` frames ago.
"""

from __future__ import annotations

import collections
from dataclasses import replace

import cv2
import numpy as np

from moseg_ros.core.baseline import EpipolarResidual
from moseg_ros.core.track_motion import PairEvidence, depth_moving, moving_tracks, pair_evidence
from moseg_ros.core.track_tests.ground import aperture_share, short_of_ground
from moseg_ros.core.track_tests.settings import TrackMotionConfig
from moseg_ros.frontend.motion_config import MotionFrontEndConfig
from moseg_ros.frontend.observe import Observation


def dense_near(points: np.ndarray, residual: np.ndarray, reach: int) -> np.ndarray:
    """The largest residual within ``reach`` pixels (a square) of each point.

    Args:
        points: (N, 2) positions (x, y) at the residual's size; points outside take the nearest border pixel.
        residual: (h, w) residual map.
        reach: half the side of the square, pixels.

    Returns:
        (N,) values of ``residual``'s dtype.
    """
    if reach > 0:
        residual = cv2.dilate(residual, np.ones((2 * reach + 1, 2 * reach + 1), dtype=np.uint8))
    h, w = residual.shape
    xy = np.clip(np.rint(points).astype(np.int64), 0, [w - 1, h - 1])
    return residual[xy[:, 1], xy[:, 0]]


def rotation_limit(config: TrackMotionConfig, frames: int) -> float:
    """Degrees a pair ``frames`` apart may turn before it is ``turned``: max_rotation_deg / gap · frames.

    ``max_rotation_deg`` holds for the track pairs (``gap`` frames), so the limit per frame is the same for
    every pair.
    """
    return config.max_rotation_deg / config.gap * frames


class TrackEvidence:
    """The track test over the window, with sticky flags; state of its own, touched only by its caller's thread."""

    def __init__(self, config: MotionFrontEndConfig) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget the window's pair fits and the sticky flags."""
        # One (track ids, PairEvidence) per frame pair (m, m + gap) of the window: each pair is fitted once.
        self._pairs: collections.deque[tuple[np.ndarray, PairEvidence]] = collections.deque(
            maxlen=self.config.window_length - self.config.track_motion.gap)
        # Living tracks that were ever flagged (sorted ids), in how many windows, and the last frame flagged.
        self._flag_ids = np.zeros(0, dtype=np.int64)
        self._flag_counts = np.zeros(0, dtype=np.int64)
        self._flag_last = np.zeros(0, dtype=np.int64)
        self._depth_ids = np.zeros(0, dtype=np.int64)  # flagged tracks the depth tests flagged (Refit.depth_flagged)
        self._counted_through: int | None = None  # the frame of the last refit whose flags were counted
        # The newest frame whose track pair has been fitted (a refit that skipped frames fits theirs first).
        self._fitted_through = -1

    def flagged(self, observation: Observation,
                last_residual: tuple[int, EpipolarResidual] | None) -> tuple[np.ndarray, np.ndarray]:
        """Ids of the observed frame's tracks that move, and of those among them the depth tests flagged.

        A track moves in this window, or is sticky from earlier windows; the depth tests' ids are those flagged
        by them in this window, or in an earlier one while they stayed flagged (``Refit.depth_flagged``). A
        track's epipolar distance counts only where the last dense residual near it corroborates it
        (``TrackMotionConfig.corroboration``, ``_dense_near``).

        Args:
            observation: the frame's observation (its window, pairs and tracks).
            last_residual: the last dense residual and its frame, None without one.

        Returns:
            (n,) sorted flagged track ids and (d,) sorted ids among them the depth tests flagged.
        """
        self._catch_up(observation)
        newest = None
        if observation.pair is not None:
            newest = self._fit_pair(*observation.pair, observation)
            if newest is not None:
                self._pairs.append(newest)
        # The long pair is fitted only while the newest short pair decides a sign (a translating camera, F
        # not degenerate): the ground and footing tests need nothing else.
        long = None
        if observation.long_pair is not None and newest is not None and newest[1].signed is not None:
            long = self._fit_pair(*observation.long_pair, observation, observation.long_span)
        if not self._pairs:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        ids = np.unique(np.concatenate([pair[0] for pair in self._pairs]))
        # (distance, signed, ground, footing, shortfall) x (track, pair), NaN where a pair did not measure it; the
        # last column is the long pair's, which gives only the ground, footing and shortfall tests.
        tables = np.full((len(PairEvidence._fields), ids.size, len(self._pairs) + 1), np.nan, dtype=np.float32)
        named = dict(zip(PairEvidence._fields, tables))
        for m, (pair_ids, evidence) in enumerate(self._pairs):
            rows = np.searchsorted(ids, pair_ids)
            for table, values in zip(tables, evidence):
                if values is not None:
                    table[rows, m] = values
        if long is not None:
            long_ids, evidence = long
            known = np.isin(long_ids, ids)
            rows = np.searchsorted(ids, long_ids[known])
            for name in ("ground", "footing", "shortfall"):
                values = getattr(evidence, name)
                if values is not None:
                    named[name][rows, -1] = values[known]
        short = short_of_ground(named["shortfall"])
        measurable = self._measurable(ids, observation, short)
        by_depth = depth_moving(ids.size, self.config.track_motion, *tables[1:], measurable=measurable)
        near = self._dense_near(ids, observation, last_residual)
        flagged = ids[moving_tracks(tables[0], self.config.track_motion, dense=near,
                                    depth=by_depth)]
        flagged = np.union1d(flagged, self._count_flags(flagged, observation.alive, observation.index))
        depth = ids[by_depth]
        self._depth_ids = np.union1d(np.intersect1d(self._depth_ids, flagged), np.intersect1d(depth, flagged))
        return flagged, self._depth_ids

    def _catch_up(self, observation: Observation) -> None:
        """Fit the track pairs of up to ``catch_up_pairs`` frames, the newest first, of those since the last refit
        that are still in ``observation``'s window: a background refit slower than the camera takes only the
        newest frame, and the window's track test would otherwise see only every second or third pair, and lose
        moving tracks (docs/experiments.md). Nothing to do when every frame is refitted."""
        gap, first = self.config.track_motion.gap, observation.first
        missed = range(max(self._fitted_through + 1, first + gap), observation.index)
        for index in missed[max(len(missed) - self.config.catch_up_pairs, 0):]:
            now = observation.window[index - first]
            fitted = self._fit_pair(*observation.window[index - first - gap], *now, observation)
            if fitted is not None:
                self._pairs.append(fitted)
        self._fitted_through = observation.index

    def _dense_near(self, ids: np.ndarray, observation: Observation,
                    last_residual: tuple[int, EpipolarResidual] | None) -> np.ndarray | None:
        """(len(ids),) the last dense residual (``_counted``, of an earlier frame than ``observation``'s) near each
        track of sorted ``ids`` where it was in that frame, in the units of the track test's distances (tracking
        pixels over ``gap`` frames; infinite where it reaches ``corroboration_floor`` of the dense threshold);
        NaN for tracks not seen then, None without dense evidence from a frame of the window or with the
        corroboration off. A frame earlier than the one tested: KLT's drift at a near edge stays where the edge
        is, and a track young enough to be born since has no pair yet (docs/experiments.md)."""
        first = observation.first
        if (self.config.track_motion.corroboration <= 0 or last_residual is None or observation.pair is None
                or not first <= last_residual[0] < observation.index):
            return None
        index, evidence = last_residual
        if not np.isfinite(evidence.threshold):
            return None
        then_ids, then = observation.window[index - first]
        _, rows, columns = np.intersect1d(ids, then_ids, assume_unique=True, return_indices=True)
        scale = evidence.residual.shape[1] / observation.tracking_shape[1]
        near = dense_near(then[columns] * scale, evidence.residual, self.config.corroboration_reach)
        values = np.full(ids.size, np.nan, dtype=np.float32)
        values[rows] = np.where(near >= self.config.corroboration_floor * evidence.threshold, np.inf,
                                near / scale * self.config.track_motion.gap / self.config.dense_gap)
        return values

    def _measurable(self, ids: np.ndarray, observation: Observation, among: np.ndarray) -> np.ndarray | None:
        """(len(ids),) bool: of the tracks of sorted ``ids`` that are ``among`` (bool) the ones asked about, those
        seen now whose image can show their parallax (``aperture_share`` at least ``aperture_share``); None with
        the check off or before a pair."""
        if self.config.aperture_share <= 0 or observation.pair is None:
            return None
        _, _, now_ids, now = observation.pair
        _, rows, columns = np.intersect1d(ids[among], now_ids, assume_unique=True, return_indices=True)
        rows = np.flatnonzero(among)[rows]
        scale = observation.gray.shape[1] / observation.tracking_shape[1]
        centre = observation.camera_matrix[:2, 2] * scale
        measurable = np.zeros(ids.size, dtype=bool)
        measurable[rows] = aperture_share(observation.gray, now[columns] * scale, centre,
                                          self.config.aperture_window) >= self.config.aperture_share
        return measurable

    def _count_flags(self, flagged: np.ndarray, alive: np.ndarray, index: int) -> np.ndarray:
        """Count the windows since the last refit (one when every frame is refitted, and at the first) for each
        living flagged track (flagged at frame ``index``); returns the ids flagged in enough windows whose last flag
        is at most ``sticky_frames`` old."""
        keep = np.isin(self._flag_ids, alive)
        fresh = np.setdiff1d(flagged[np.isin(flagged, alive)], self._flag_ids)
        ids = np.concatenate([self._flag_ids[keep], fresh])
        counts = np.concatenate([self._flag_counts[keep], np.zeros(fresh.size, dtype=np.int64)])
        last = np.concatenate([self._flag_last[keep], np.full(fresh.size, index, dtype=np.int64)])
        order = np.argsort(ids)
        ids, counts, last = ids[order], counts[order], last[order]
        now = np.isin(ids, flagged)
        # Every frame's refit would have seen the skipped frames' windows, each mostly the same frames as this one's.
        windows = 1 if self._counted_through is None else min(max(index - self._counted_through, 1),
                                                                self.config.sticky_windows)
        counts[now] += windows
        self._counted_through = index
        last[now] = index
        self._flag_ids, self._flag_counts, self._flag_last = ids, counts, last
        return ids[(counts >= self.config.sticky_windows) & (index - last <= self.config.sticky_frames)]

    def _fit_pair(self, ids1: np.ndarray, x1: np.ndarray, ids2: np.ndarray, x2: np.ndarray, observation: Observation,
                  frames: int | None = None) -> tuple[np.ndarray, PairEvidence] | None:
        """(ids, evidence) of the tracks seen in both frames of a pair ``frames`` apart (default: ``gap``; a
        longer pair skips the planar check, see ``_flagged``) of ``observation``'s window, at its tracking size,
        guarded against a misjudged rotation whatever its K is (core/track_motion.py: in a turn even a calibrated
        K let a near house pass for a mover; docs/experiments.md, ``max_rotation_deg``)."""
        config = self.config.track_motion.for_width(observation.tracking_shape[1])
        K = observation.camera_matrix
        if frames is not None:
            config = replace(config, max_rotation_deg=rotation_limit(self.config.track_motion, frames))
        both, i1, i2 = np.intersect1d(ids1, ids2, assume_unique=True, return_indices=True)
        evidence = pair_evidence(x1[i1], x2[i2], config, K, guarded=True, planar_check=frames is None)
        return None if evidence is None else (both, evidence)
