"""The per-track epipolar test: static tracks at any parallax pass, tracks on an independent mover fail."""

from __future__ import annotations

import numpy as np
import pytest

from moseg_ros.core.track_motion import TrackMotionConfig, moving_tracks, pair_residual, pair_residuals

K = np.array([[500.0, 0, 320], [0, 500, 120], [0, 0, 1]])


def project(points: np.ndarray, camera_position: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of world points seen by a camera at ``camera_position`` looking down +z."""
    relative = (points - camera_position) @ K.T
    return relative[:, :2] / relative[:, 2:]


def street(n_static: int = 400, n_mover: int = 30, frames: int = 6, seed: int = 0):
    """Tracks of a camera driving forward (and a little sideways) past static points 4-60 m away, and of a
    block crossing the road 12 m ahead (off the epipolar lines). Returns tracks (N, F, 2), is_mover (N,)."""
    rng = np.random.default_rng(seed)
    static = np.column_stack([rng.uniform(-12, 12, n_static), rng.uniform(-3, 2, n_static),
                              rng.uniform(4, 60, n_static)])
    mover = np.column_stack([rng.uniform(-1, 1, n_mover), rng.uniform(-1, 0.5, n_mover),
                             rng.uniform(11.5, 12.5, n_mover)])
    tracks = []
    for t in range(frames):
        camera = np.array([0.05 * t, 0.0, 1.0 * t])
        moved = mover + np.array([0.6 * t, 0.0, 1.0 * t])  # crosses at 6 m/s while keeping its distance
        tracks.append(np.vstack([project(static, camera), project(moved, camera)]))
    tracks = np.stack(tracks, axis=1) + rng.normal(0, 0.2, (n_static + n_mover, frames, 2))
    return tracks.astype(np.float32), np.r_[np.zeros(n_static, bool), np.ones(n_mover, bool)]


class TestPairResidual:
    def test_static_points_at_strong_parallax_fit_and_the_mover_does_not(self):
        tracks, mover = street()
        distance = pair_residual(tracks[:, 0], tracks[:, 2])
        assert distance.shape == (len(mover),) and distance.dtype == np.float32
        assert np.median(distance[~mover]) < 0.5
        assert np.median(distance[mover]) > 3.0

    def test_too_few_points_or_no_parallax_give_none(self):
        tracks, _ = street()
        assert pair_residual(tracks[:10, 0], tracks[:10, 2]) is None
        assert pair_residual(tracks[:, 0], tracks[:, 0] + 0.1) is None


class TestPairResiduals:
    def test_shape_and_unseen_tracks_are_nan(self):
        tracks, _ = street(frames=6)
        visible = np.ones(tracks.shape[:2], dtype=bool)
        visible[0, 3:] = False
        tracks[0, 3:] = np.nan
        residuals = pair_residuals(tracks, visible, TrackMotionConfig(gap=2))
        assert residuals.shape == (tracks.shape[0], 4)
        assert np.isnan(residuals[0, 1:]).all() and not np.isnan(residuals[0, 0])
        assert not np.isnan(residuals[1:]).any()


class TestMovingTracks:
    def test_flags_the_mover_and_not_the_static_street(self):
        tracks, mover = street()
        visible = np.ones(tracks.shape[:2], dtype=bool)
        flagged = moving_tracks(pair_residuals(tracks, visible))
        assert flagged[mover].mean() > 0.9
        assert flagged[~mover].mean() < 0.01

    def test_threshold_is_the_larger_of_factor_times_median_and_floor(self):
        residuals = np.array([[0.2], [0.3], [0.3], [0.95], [1.2], [np.nan]], dtype=np.float32)
        assert moving_tracks(residuals, TrackMotionConfig(factor=3.0, floor_px=1.0)).tolist() == [
            False, False, False, False, True, False]
        assert moving_tracks(residuals, TrackMotionConfig(factor=2.0, floor_px=0.5)).tolist() == [
            False, False, False, True, True, False]

    def test_median_over_pairs_forgives_one_bad_pair(self):
        residuals = np.array([[0.1, 0.2, 9.0], [0.2, 0.1, 0.2], [0.3, 0.2, 0.1]], dtype=np.float32)
        assert not moving_tracks(residuals).any()

    @pytest.mark.parametrize("shape", [(0, 3), (4, 0)])
    def test_nothing_measured_flags_nothing(self, shape):
        assert not moving_tracks(np.full(shape, np.nan, dtype=np.float32)).any()


def test_a_planar_pan_uses_the_homography_so_the_mover_stands_out():
    """Every static point on one plane: F is degenerate and one of its family fits the mover too; the
    homography does not."""
    rng = np.random.default_rng(1)
    x1 = rng.uniform([0, 0], [600, 200], (300, 2))
    x2 = x1 + [-2.0, 0.0]
    x2[:30] = x1[:30] + [0.0, 3.0]
    distance = pair_residual(x1, x2 + rng.normal(0, 0.1, x2.shape))
    assert np.median(distance[:30]) > 2.0 and np.median(distance[30:]) < 0.3
