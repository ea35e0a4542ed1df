"""The per-track epipolar, cheirality, ground and footing tests, and the dense cheirality test: static points at any
parallax pass, independent movers fail."""

from __future__ import annotations

import dataclasses
import warnings

import cv2
import numpy as np
import pytest

from conftest import oncoming_street_flow, pan_follow_flow
from moseg_ros.core.baseline import sampson_pixels
from moseg_ros.core.flow_field import pixel_grid
from moseg_ros.core.robust import row_medians
from moseg_ros.core.track_motion import depth_moving, moving_tracks, pair_evidence
from moseg_ros.core.track_tests.epipolar import pair_residual, pair_residuals
from moseg_ros.core.track_tests.cheirality import (Parallax, behind_infinity, dense_parallax, far_behind,
                                                   guessed_camera_matrix, signed_parallax)
from moseg_ros.core.track_tests.columns import _band_below, footing_columns
from moseg_ros.core.track_tests.epipolar import beyond_allowance, may_be_planar
from moseg_ros.core.track_tests.footing import footing_allowance, footing_excess, nearer_than_road
from moseg_ros.core.track_tests.ground import (aperture_share, decided_ratios, ground_floor, ground_parallax_ratio,
                                               ground_slope, standing_rows, standing_shortfall)
from moseg_ros.core.track_tests.settings import REFERENCE_WIDTH, TrackMotionConfig
from moseg_ros.frontend.motion_config import MotionFrontEndConfig

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


class TestForWidth:
    def test_the_strong_shortfall_in_proportion_to_the_width_and_nothing_else(self):
        config = TrackMotionConfig()
        assert config.for_width(REFERENCE_WIDTH) == config
        half = config.for_width(REFERENCE_WIDTH // 2)
        assert half.shortfall_strong_px == pytest.approx(config.shortfall_strong_px / 2)
        assert dataclasses.replace(half, shortfall_strong_px=config.shortfall_strong_px) == config


class TestPairResidual:
    def test_static_points_at_strong_parallax_fit_and_the_mover_does_not(self):
        tracks, mover = street()
        distance = pair_residual(tracks[:, 0], tracks[:, 2])
        assert distance.shape == (len(mover),) and distance.dtype == np.float32
        assert np.median(distance[~mover]) < 0.5
        assert np.median(distance[mover]) > 3.0

    def test_too_few_points_give_none(self):
        tracks, _ = street()
        assert pair_residual(tracks[:10, 0], tracks[:10, 2]) is None

    def test_a_still_camera_makes_every_motion_the_residual(self):
        """Median motion below min_parallax_px: the camera's motion is the identity (no F, no sign)."""
        rng = np.random.default_rng(3)
        x1 = rng.uniform([0, 0], [600, 200], (200, 2))
        x2 = x1 + rng.normal(0, 0.05, x1.shape)
        x2[:20] += [4.0, 0.0]  # a walker in front of a camera on a tripod
        evidence = pair_evidence(x1, x2, TrackMotionConfig(), K)
        assert evidence.signed is None and evidence.ground is None and evidence.footing is None
        distance = evidence.distance
        assert np.allclose(distance[:20], 4.0, atol=0.3) and np.median(distance[20:]) < 0.1


class TestBeyondAllowance:
    def test_shape_dtype_and_known_values(self):
        x1 = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 0.0]])
        x2 = np.array([[100.0, 0.0], [10.0, 20.0], [3.0, 4.0]])
        out = beyond_allowance(np.array([4.0, 0.5, 1.0]), x2 - x1, 0.03)
        assert out.shape == (3,) and out.dtype == np.float32
        np.testing.assert_allclose(out, [1.0, 0.0, 0.85], atol=1e-6)

    def test_a_dense_flow_takes_its_own_length_off_each_pixel(self):
        residual = np.full((2, 3), 2.0)
        flow = np.zeros((2, 3, 2))
        flow[0, 0] = (30.0, 40.0)  # 50 px: 1.5 px off at 0.03
        flow[1, 2] = (0.0, 100.0)  # 3 px off: none left
        out = beyond_allowance(residual, flow, 0.03)
        assert out.shape == (2, 3) and out.dtype == np.float32
        np.testing.assert_allclose(out, [[0.5, 2.0, 2.0], [2.0, 2.0, 0.0]], atol=1e-6)

    def test_no_allowance_leaves_the_distance(self):
        distance = np.array([0.2, 3.0])
        x1 = np.zeros((2, 2))
        np.testing.assert_array_equal(beyond_allowance(distance, x1 + 50.0, 0.0), distance.astype(np.float32))

    def test_pair_evidence_takes_it_off_every_track_under_f(self):
        tracks, _ = street()
        x1, x2 = tracks[:, 0], tracks[:, 2]
        whole = pair_evidence(x1, x2, dataclasses.replace(TrackMotionConfig(), epipole_allowance=0.0), K).distance
        less = pair_evidence(x1, x2, dataclasses.replace(TrackMotionConfig(), epipole_allowance=0.03), K).distance
        displacement = np.linalg.norm(x2 - x1, axis=1)
        np.testing.assert_allclose(less, np.maximum(whole - 0.03 * displacement, 0), atol=1e-5)

    def test_near_static_tracks_off_their_lines_by_a_small_angle_are_forgiven_and_the_mover_is_not(self):
        """The epipolar lines of near static points turned by 1.2 degrees (an epipole fitted a little off, KLT
        drifting along a reflection): without the allowance a third of them move; with it none, while the block
        crossing the road still does."""
        tracks, mover = street()
        x1, x2 = tracks[:, 0].astype(np.float64), tracks[:, 2].astype(np.float64)
        step = x2 - x1
        near = ~mover & (np.linalg.norm(step, axis=1) > 40) & (np.linalg.norm(step, axis=1) < 200)
        angle = np.deg2rad(1.2)
        turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        x2[near] = x1[near] + step[near] @ turn.T
        flagged = {}
        for allowance in (0.0, 0.03):
            config = dataclasses.replace(TrackMotionConfig(), epipole_allowance=allowance)
            flagged[allowance] = moving_tracks(pair_evidence(x1, x2, config, K).distance[:, None], config)
        assert near.sum() > 30
        assert flagged[0.0][near].mean() > 0.25 and not flagged[0.03][near].any()
        assert flagged[0.03][mover].mean() >= 0.85 and not flagged[0.03][~mover].any()


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


class TestRowMedians:
    def test_known_values_ignore_nan(self):
        values = np.array([[3.0, 1.0, 2.0], [4.0, np.nan, 1.0], [np.nan, np.nan, 5.0], [np.nan] * 3])
        np.testing.assert_array_equal(row_medians(values), [2.0, 2.5, 5.0, np.nan])

    def test_matches_numpy_nanmedian(self):
        rng = np.random.default_rng(0)
        values = rng.normal(size=(500, 7)).astype(np.float32)
        values[rng.random(values.shape) < 0.4] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # numpy's all-NaN-slice warning
            expected = np.nanmedian(values, axis=1)
        result = row_medians(values)
        assert result.dtype == np.float32 and result.shape == (500,)
        np.testing.assert_array_equal(result, expected)

    @pytest.mark.parametrize("shape", [(0, 3), (4, 0)])
    def test_empty_rows_or_columns(self, shape):
        result = row_medians(np.zeros(shape, dtype=np.float32))
        assert result.shape == (shape[0],) and np.isnan(result).all()


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

    def test_an_uncorroborated_distance_flags_only_when_evident(self):
        # The median is 0.3 px, so the threshold is the 1 px floor and 3 px is evident.
        residuals = np.array([[0.2], [0.3], [0.2], [0.3], [0.3], [1.6], [1.6], [1.6], [3.5]], dtype=np.float32)
        dense = np.array([0, 0, 0, 0, 0, 1.2, np.nan, 0.2, 0.0], dtype=np.float32)
        config = TrackMotionConfig(factor=3.0, floor_px=1.0, corroboration=0.75, evident_factor=3.0)
        assert np.flatnonzero(moving_tracks(residuals, config, dense=dense)).tolist() == [5, 6, 8]
        assert np.flatnonzero(moving_tracks(residuals, dataclasses.replace(config, corroboration=0.0),
                                            dense=dense)).tolist() == [5, 6, 7, 8]
        signed = np.full((9, 1), 5.0, dtype=np.float32)
        signed[1] = -4.0  # behind infinity: cheirality needs no corroboration
        assert np.flatnonzero(moving_tracks(residuals, config, signed=signed,
                                            dense=np.zeros(9, np.float32))).tolist() == [1, 8]

    def test_a_shortfall_flags_where_most_pairs_fall_short_and_where_measurable(self):
        # Every distance at 0.2 px: only the ground's tests decide. Margins short of the ground where the tracks
        # stand (``standing_shortfall``): short in both pairs, in one of two (far short in it: the median of the
        # two would be positive), in none, the ratio test's (0.3) alone, undecided.
        residuals = np.full((5, 2), 0.2, dtype=np.float32)
        ground = np.array([[0.5, 0.5], [0.5, 0.5], [0.8, 0.8], [0.2, 0.2], [np.nan, np.nan]], dtype=np.float32)
        shortfall = np.array([[2, 3], [5, -0.5], [-1, -1], [-0.5, -0.5], [np.nan, np.nan]], dtype=np.float32)
        config = TrackMotionConfig(ground_ratio=0.3)
        assert np.flatnonzero(moving_tracks(residuals, config, ground=ground)).tolist() == [3]
        assert np.flatnonzero(moving_tracks(residuals, config, ground=ground, shortfall=shortfall)).tolist() == [0, 3]
        measurable = np.array([False, True, True, True, True])
        assert np.flatnonzero(moving_tracks(residuals, config, ground=ground, shortfall=shortfall,
                                            measurable=measurable)).tolist() == [3]
        assert np.flatnonzero(moving_tracks(residuals, config, shortfall=shortfall)).tolist() == [0]

    @pytest.mark.parametrize("shape", [(0, 3), (4, 0)])
    def test_nothing_measured_flags_nothing(self, shape):
        assert not moving_tracks(np.full(shape, np.nan, dtype=np.float32)).any()


class TestDepthMoving:
    def test_only_the_depth_tests_part_of_moving_tracks(self):
        # Track 0 by its epipolar distance alone, 1 behind infinity, 2 short of the ground's ratio, 3 nearer than
        # the road under it (footing), 4 by nothing.
        residuals = np.array([[3.0], [0.2], [0.2], [0.2], [0.2]], dtype=np.float32)
        signed = np.array([[5.0], [-4.0], [5.0], [5.0], [5.0]], dtype=np.float32)
        ground = np.array([[0.9], [0.9], [0.1], [0.9], [0.9]], dtype=np.float32)
        footing = np.array([[0.0], [0.0], [0.0], [3.0], [0.0]], dtype=np.float32)
        tests = dict(signed=signed, ground=ground, footing=footing)
        assert np.flatnonzero(moving_tracks(residuals, **tests)).tolist() == [0, 1, 2, 3]
        assert np.flatnonzero(depth_moving(5, **tests)).tolist() == [1, 2, 3]

    def test_without_depth_tests_nothing(self):
        assert depth_moving(3).tolist() == [False, False, False]


def test_a_planar_pan_uses_the_homography_so_the_mover_stands_out():
    """Every static point on one plane: F is degenerate and one of its family fits the mover too; the
    homography does not."""
    rng = np.random.default_rng(1)
    x1 = rng.uniform([0, 0], [600, 200], (300, 2))
    x2 = x1 + [-2.0, 0.0]
    x2[:30] = x1[:30] + [0.0, 3.0]
    distance = pair_residual(x1, x2 + rng.normal(0, 0.1, x2.shape))
    assert np.median(distance[:30]) > 2.0 and np.median(distance[30:]) < 0.3


class TestMayBePlanar:
    """The quick homography screen that spares the full fit where no plane can compete with F."""

    @staticmethod
    def _pan(n: int = 400):
        rng = np.random.default_rng(4)
        x1 = rng.uniform([0, 0], [600, 200], (n, 2))
        return x1, x1 + [-2.0, 0.0] + rng.normal(0, 0.1, (n, 2))

    def test_a_pan_may_be_planar(self):
        x1, x2 = self._pan()
        assert may_be_planar(x1, x2, np.ones(len(x1), dtype=bool))

    def test_a_street_with_depth_is_not(self):
        tracks, mover = street()
        x1, x2 = tracks[~mover, 0].astype(np.float64), tracks[~mover, 2].astype(np.float64)
        assert not may_be_planar(x1, x2, np.ones(len(x1), dtype=bool))

    def test_the_screen_off_or_without_a_quick_model_leaves_it_to_the_full_fit(self, monkeypatch):
        tracks, mover = street()
        x1, x2 = tracks[~mover, 0].astype(np.float64), tracks[~mover, 2].astype(np.float64)
        inliers = np.ones(len(x1), dtype=bool)
        assert may_be_planar(x1, x2, inliers, TrackMotionConfig(homography_screen=0.0))
        monkeypatch.setattr(cv2, "findHomography", lambda *args: (None, None))
        assert may_be_planar(x1, x2, inliers)

    def test_the_screened_street_gives_the_same_evidence_as_the_full_fit(self):
        tracks, _ = street()
        screened = pair_evidence(tracks[:, 0], tracks[:, 2], TrackMotionConfig(), K)
        full = pair_evidence(tracks[:, 0], tracks[:, 2], TrackMotionConfig(homography_screen=0.0), K)
        np.testing.assert_array_equal(screened.distance, full.distance)
        np.testing.assert_array_equal(screened.signed, full.signed)


def car_ahead(frames: int = 6, seed: int = 0):
    """Tracks of the street above with, instead of the crossing block, a car 8-10 m ahead in the next lane
    driving in the camera's own direction at twice its speed: it pulls away along the epipolar lines, so its
    Sampson distance is ~0, but it lies 'behind infinity' (negative parallax). Returns tracks (N, F, 2), is_car (N,)."""
    rng = np.random.default_rng(seed)
    tracks, _ = street(n_mover=0, frames=frames, seed=seed)
    car = np.column_stack([rng.uniform(1.5, 3.5, 40), rng.uniform(-0.5, 1, 40), rng.uniform(8, 10, 40)])
    velocity = 2.0 * np.array([0.05, 0.0, 1.0])
    car_tracks = np.stack([project(car + velocity * t, np.array([0.05 * t, 0.0, 1.0 * t])) for t in range(frames)],
                          axis=1) + rng.normal(0, 0.2, (40, frames, 2))
    return np.vstack([tracks, car_tracks]).astype(np.float32), np.r_[np.zeros(len(tracks), bool), np.ones(40, bool)]


def _window_evidence(tracks, K, config=TrackMotionConfig()):
    residuals = np.full((len(tracks), tracks.shape[1] - 2), np.nan, np.float32)
    signed = np.full_like(residuals, np.nan)
    for m in range(residuals.shape[1]):
        distance, parallax, *_ = pair_evidence(tracks[:, m], tracks[:, m + 2], config, K)
        residuals[:, m] = distance
        if parallax is not None:
            signed[:, m] = parallax
    return residuals, signed


class TestCheirality:
    def test_the_car_pulling_away_ahead_is_caught_by_cheirality_and_missed_by_the_residual(self):
        tracks, car = car_ahead()
        residuals, signed = _window_evidence(tracks, K)
        assert not moving_tracks(residuals)[car].any()  # inside the epipolar plane: no residual
        flagged = moving_tracks(residuals, signed=signed)
        assert flagged[car].mean() > 0.9 and flagged[~car].mean() < 0.01

    def test_a_guessed_camera_matrix_gives_the_same_decision(self):
        tracks, car = car_ahead(seed=1)
        residuals, signed = _window_evidence(tracks, guessed_camera_matrix((240, 640)))
        flagged = moving_tracks(residuals, signed=signed)
        assert flagged[car].mean() > 0.9 and flagged[~car].mean() < 0.01

    def test_static_points_at_strong_parallax_have_positive_parallax(self):
        tracks, _ = street(n_mover=0)
        parallax = pair_evidence(tracks[:, 0], tracks[:, 2], TrackMotionConfig(), K).signed
        assert parallax.shape == (len(tracks),) and np.mean(parallax > -1.0) > 0.99
        assert np.percentile(parallax, 90) > 5.0  # near points: strong parallax, and of the right sign

    def test_a_pure_rotation_decides_no_sign(self):
        rng = np.random.default_rng(2)
        x1 = rng.uniform([0, 0], [640, 240], (300, 2))
        angle = np.deg2rad(1.0)
        rotation = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
        moved = (K @ rotation @ np.linalg.inv(K) @ np.c_[x1, np.ones(300)].T).T
        x2 = moved[:, :2] / moved[:, 2:] + rng.normal(0, 0.1, (300, 2))
        evidence = pair_evidence(x1, x2, TrackMotionConfig(), K)
        assert evidence is not None and evidence[1] is None  # the homography branch: no translation, no sign


def test_guarded_pairs_that_turn_too_much_sign_only_what_is_far_behind_infinity():
    tracks, _ = street(n_mover=0)
    strict = TrackMotionConfig(max_rotation_deg=0.0)  # every real pair turns a little
    unguarded = pair_evidence(tracks[:, 0], tracks[:, 2], strict, K, guarded=False)
    assert unguarded.signed is not None and np.isfinite(unguarded.signed).all()
    turned = pair_evidence(tracks[:, 0], tracks[:, 2], strict, K, guarded=True)
    assert np.isnan(turned.signed).all()  # no static track lies far behind infinity, and no other is signed
    assert turned.ground is None and turned.footing is None  # no epipole row: no ground or footing test
    never = TrackMotionConfig(max_rotation_deg=0.0, behind_share=np.inf)
    assert pair_evidence(tracks[:, 0], tracks[:, 2], never, K, guarded=True).signed is None


def _at_infinity(n: int = 40, frames: int = 6, seed: int = 1) -> np.ndarray:
    """Tracks (n, frames, 2) of points at infinity under pan_follow's rotation, with 0.2 px of noise: their
    parallax is the noise, and about half of them come out just behind infinity."""
    rng = np.random.default_rng(seed)
    rays = np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.2, 0.2, n), np.ones(n)])
    tracks = []
    for t in range(frames):
        angle = -np.deg2rad(1.0) * t
        R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
        seen = rays @ R.T @ K.T
        tracks.append(seen[:, :2] / seen[:, 2:])
    return (np.stack(tracks, axis=1) + rng.normal(0, 0.2, (n, frames, 2))).astype(np.float32)


def test_guarded_only_tracks_far_behind_infinity_are_behind_it():
    tracks, car = pan_follow()
    tracks, car = np.concatenate([tracks, _at_infinity()]), np.r_[car, np.zeros(40, bool)]
    loose = TrackMotionConfig(max_rotation_deg=10.0)  # a pair within the rotation limit
    unguarded = pair_evidence(tracks[:, 0], tracks[:, 2], loose, K, guarded=False)
    guarded = pair_evidence(tracks[:, 0], tracks[:, 2], loose, K, guarded=True)
    ahead = unguarded.signed >= 0
    assert np.array_equal(guarded.signed[ahead], unguarded.signed[ahead])
    slightly = ~ahead & ~car  # static tracks that the noise puts just behind infinity: taken as at infinity
    assert slightly.sum() > 5 and (guarded.signed[slightly] == 0).all()
    assert np.array_equal(guarded.signed[car], unguarded.signed[car])  # the followed car: all of the rotation


def test_a_turned_pair_still_signs_the_car_the_camera_pans_after():
    tracks, car = pan_follow()  # turns 1 degree a frame
    strict = TrackMotionConfig(max_rotation_deg=0.5)
    evidence = pair_evidence(tracks[:, 0], tracks[:, 2], strict, K, guarded=True)
    assert (evidence.signed[car] < -strict.cheir_px).mean() > 0.9
    assert np.isnan(evidence.signed[~car]).mean() > 0.99


class TestFarBehind:
    C, S = np.cos(0.02), np.sin(0.02)
    ROTATION = K @ np.array([[C, 0, S], [0, 1, 0], [-S, 0, C]]) @ np.linalg.inv(K)

    def test_shape_and_dtype(self):
        x1 = np.random.default_rng(0).uniform(0, 300, (7, 2))
        out = far_behind(x1, np.zeros(7), self.ROTATION, 0.5)
        assert out.shape == (7,) and out.dtype == bool

    def test_known_values_at_the_principal_point(self):
        centre = np.array([[K[0, 2], K[1, 2]]])
        motion = K[0, 0] * np.tan(0.02)  # the rotation moves the principal point f tan(angle) sideways
        assert far_behind(centre, np.array([-0.6 * motion]), self.ROTATION, 0.5)[0]
        assert not far_behind(centre, np.array([-0.4 * motion]), self.ROTATION, 0.5)[0]
        assert not far_behind(centre, np.array([2.0]), self.ROTATION, 0.5)[0]


def road(frames: int = 6, seed: int = 0, sideways: float = 0.0):
    """Tracks of a camera 1.5 m above a flat road driving 1 m a frame (and ``sideways`` m a frame to the
    right): points on the road 6.5-40 m ahead, on static boxes standing on it at the roadside, and on a car
    10-11 m ahead that the camera follows at its own speed (its image does not move). Returns tracks
    (N, F, 2) and the masks (N,) of road points and of the followed car."""
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(-8, 8, 300), np.full(300, 1.5), rng.uniform(6.5, 40, 300)])
    side = rng.choice([-1.0, 1.0], 200)
    boxes = np.column_stack([side * rng.uniform(3, 8, 200), rng.uniform(-1.0, 1.5, 200), rng.uniform(8, 30, 200)])
    car = np.column_stack([rng.uniform(-1, 1, 40), rng.uniform(0.3, 1.5, 40), rng.uniform(10, 11, 40)])
    tracks = []
    for t in range(frames):
        camera = np.array([sideways * t, 0.0, 1.0 * t])
        tracks.append(np.vstack([project(ground, camera), project(boxes, camera), project(car + camera, camera)]))
    tracks = np.stack(tracks, axis=1) + rng.normal(0, 0.2, (540, frames, 2))
    is_road, is_car = np.zeros(540, bool), np.zeros(540, bool)
    is_road[:300], is_car[500:] = True, True
    return tracks.astype(np.float32), is_road, is_car


def _parallax(x1, x2):
    F, inliers = cv2.findFundamentalMat(x1.astype(np.float64), x2.astype(np.float64), cv2.USAC_MAGSAC, 1.0,
                                        0.999, 1000)
    return signed_parallax(x1.astype(np.float64), x2.astype(np.float64), F, inliers.ravel() > 0, K)


class TestSignedParallax:
    def test_gain_and_epipole_of_a_forward_drive(self):
        tracks, _, _ = road()
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        assert parallax.signed.shape == parallax.gain.shape == (540,) and parallax.gain.dtype == np.float32
        assert (parallax.gain > 0).all()
        assert parallax.epipole_row == pytest.approx(K[1, 2], abs=3.0)  # straight ahead: the principal row

    def test_the_epipole_row_is_the_earlier_image_s(self):
        """Driving along the earlier camera's axis while pitching 1 degree: the epipole of the earlier image
        is its principal point; the later image's lies f tan(1 degree) = 8.7 px away."""
        rng = np.random.default_rng(4)
        points = np.column_stack([rng.uniform(-10, 10, 400), rng.uniform(-3, 1.5, 400), rng.uniform(5, 40, 400)])
        pitch = np.deg2rad(1.0)
        R = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
        earlier = points @ K.T
        later = (points - [0.0, 0.0, 1.0]) @ R.T @ K.T
        x1, x2 = earlier[:, :2] / earlier[:, 2:], later[:, :2] / later[:, 2:]
        parallax = _parallax(x1 + rng.normal(0, 0.1, x1.shape), x2 + rng.normal(0, 0.1, x2.shape))
        assert parallax.epipole_row == pytest.approx(K[1, 2], abs=2.0)

    def test_a_sideways_drive_has_no_forward_epipole(self):
        tracks, _, _ = road(sideways=2.0)
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        assert parallax is not None and parallax.epipole_row is None


class TestGroundParallaxRatio:
    def test_road_points_sit_on_the_floor_and_the_followed_car_far_below_it(self):
        tracks, is_road, is_car = road()
        ratio = ground_parallax_ratio(tracks[:, 0], _parallax(tracks[:, 0], tracks[:, 2]))
        assert ratio.shape == (540,) and ratio.dtype == np.float32
        assert 0.8 < np.nanmedian(ratio[is_road]) < 2.0  # the floor is the road's, read conservatively low
        assert np.nanmin(ratio[~is_car]) > TrackMotionConfig().ground_ratio
        assert abs(np.nanmedian(ratio[is_car])) < 0.1 and np.isfinite(ratio[is_car]).mean() > 0.5

    def test_points_above_the_epipole_are_not_decided(self):
        tracks, _, _ = road()
        ratio = ground_parallax_ratio(tracks[:, 0], _parallax(tracks[:, 0], tracks[:, 2]))
        assert np.isnan(ratio[tracks[:, 0, 1] < K[1, 2] - 3]).all()

    def test_no_ratio_without_a_forward_motion_or_enough_tracks(self):
        tracks, _, _ = road(sideways=2.0)
        assert ground_parallax_ratio(tracks[:, 0], _parallax(tracks[:, 0], tracks[:, 2])) is None
        tracks, _, _ = road()
        full = _parallax(tracks[:, 0], tracks[:, 2])
        few = Parallax(full.signed[::25], full.gain[::25], full.epipole_row, full.rotation, full.translation,
                       full.focal)
        assert ground_parallax_ratio(tracks[::25, 0], few) is None


def road_with_far_end(seed: int = 3, noise_px: float = 0.5):
    """``road`` (6 frames) plus 100 road points 60-200 m ahead, a few pixels below the epipole, tracked with
    ``noise_px`` of noise: where the floor's parallax is a pixel or two. Returns tracks (N, 6, 2), is_car and
    is_far (N,)."""
    tracks, _, is_car = road(seed=seed)
    rng = np.random.default_rng(seed)
    far = np.column_stack([rng.uniform(-8, 8, 100), np.full(100, 1.5), rng.uniform(60, 200, 100)])
    far_tracks = np.stack([project(far, np.array([0.0, 0.0, 1.0 * t])) for t in range(6)], axis=1)
    far_tracks += rng.normal(0, noise_px, far_tracks.shape)
    tracks = np.vstack([tracks, far_tracks.astype(np.float32)])
    return tracks, np.r_[is_car, np.zeros(100, bool)], np.r_[np.zeros(540, bool), np.ones(100, bool)]


class TestDecidedRatios:
    def test_only_ratios_over_a_floor_of_enough_noise_sigmas_are_decided(self):
        tracks, _, _ = road_with_far_end()
        x1 = tracks[:, 0].astype(np.float64)
        parallax = _parallax(tracks[:, 0], tracks[:, 5])
        config = TrackMotionConfig()
        ground = ground_parallax_ratio(x1, parallax, config)
        floor = ground_floor(x1, parallax, config)
        decided = decided_ratios(ground, floor, config, noise=0.5)
        assert decided.shape == (640,) and decided.dtype == np.float32
        np.testing.assert_array_equal(np.isfinite(decided), floor >= config.ground_ratio_noise * 0.5)
        np.testing.assert_array_equal(decided[np.isfinite(decided)], ground[np.isfinite(decided)])
        assert np.isnan(decided_ratios(ground, floor, config, noise=np.inf)).all()

    def test_the_noisy_far_end_is_not_flagged_and_the_followed_car_still_is(self):
        tracks, is_car, is_far = road_with_far_end()
        evidence = pair_evidence(tracks[:, 0], tracks[:, 5], TrackMotionConfig(), K)
        ratio = TrackMotionConfig().ground_ratio
        assert not (evidence.ground[is_far] < ratio).any()
        assert np.isfinite(evidence.ground[is_car]).mean() > 0.5 and (evidence.ground[is_car] < ratio).sum() > 20
        ungated = pair_evidence(tracks[:, 0], tracks[:, 5], dataclasses.replace(TrackMotionConfig(),
                                                                                 ground_ratio_noise=0.0), K)
        assert (ungated.ground[is_far] < ratio).any()  # what the noise does without the gate

    def test_quiet_tracks_keep_the_ratio_near_the_horizon(self):
        """The same far end tracked with a tenth of the noise: its floor of a pixel or two is decided."""
        tracks, _, is_far = road_with_far_end(noise_px=0.05)
        evidence = pair_evidence(tracks[:, 0], tracks[:, 5], TrackMotionConfig(), K)
        assert np.isfinite(evidence.ground[is_far]).sum() > 5
        assert not (evidence.ground[is_far] < TrackMotionConfig().ground_ratio).any()


class TestGroundShortfall:
    def test_the_road_and_the_static_boxes_are_never_short_and_the_followed_car_is(self):
        tracks, is_road, is_car = road()
        x1 = tracks[:, 0]
        parallax = _parallax(x1, tracks[:, 2])
        ground = ground_parallax_ratio(x1, parallax)
        margin = standing_shortfall(x1, parallax, ground)
        assert margin.shape == (540,) and margin.dtype == np.float32
        # The floor is read conservatively low, so the road is at most a little short of it and the static boxes,
        # nearer than the road, never; the car the camera follows keeps still: short by its whole floor.
        assert np.nanmax(margin[~is_car]) < 0.0
        assert np.mean(margin[is_car] > 0) > 0.9

    def test_the_floor_has_the_ratio_s_decisions(self):
        tracks, _, _ = road()
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        floor = ground_floor(tracks[:, 0], parallax)
        ratio = ground_parallax_ratio(tracks[:, 0], parallax)
        np.testing.assert_array_equal(np.isnan(floor), np.isnan(ratio))
        assert np.nanmin(floor) >= TrackMotionConfig().ground_min_px
        assert np.isnan(floor[tracks[:, 0, 1] < K[1, 2] - 3]).all()  # above the epipole

    def test_none_without_a_forward_motion(self):
        tracks, _, _ = road(sideways=2.0)
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        assert standing_shortfall(tracks[:, 0], parallax, None) is None and ground_floor(tracks[:, 0], parallax) is None

    def test_a_pair_gives_it_beside_the_ratio(self):
        tracks, _, is_car = road()
        evidence = pair_evidence(tracks[:, 0], tracks[:, 2], TrackMotionConfig(), K)
        assert evidence.shortfall is not None and evidence.shortfall.shape == (540,)
        assert np.nanmedian(evidence.shortfall[is_car]) > 0.0  # short of the ground where it stands


class TestApertureShare:
    @staticmethod
    def _edges(vertical: bool) -> np.ndarray:
        image = np.zeros((101, 101), dtype=np.uint8)
        if vertical:
            image[:, 50:] = 200  # an edge running up and down: its gradient points along x
        else:
            image[50:, :] = 200
        return image

    def test_shape_and_range(self):
        rng = np.random.default_rng(0)
        image = rng.integers(0, 255, (60, 80)).astype(np.uint8)
        points = rng.uniform(0, 80, (25, 2))
        share = aperture_share(image, points, np.array([40.0, 30.0]), 7)
        assert share.shape == (25,) and ((share >= 0) & (share <= 1 + 1e-6)).all()

    def test_an_edge_along_the_line_hides_the_motion_along_it_and_one_across_shows_it(self):
        centre = np.array([50.0, 50.0])
        # A vertical edge above and below the centre, a horizontal one left and right of it: each runs along
        # its line from the centre (a kerb near the horizon, seen from the focus of expansion).
        vertical = aperture_share(self._edges(vertical=True), np.array([[50.0, 20.0], [50.0, 80.0]]), centre, 7)
        horizontal = aperture_share(self._edges(vertical=False), np.array([[20.0, 50.0], [80.0, 50.0]]), centre, 7)
        np.testing.assert_allclose(vertical, 0.0, atol=1e-6)
        np.testing.assert_allclose(horizontal, 0.0, atol=1e-6)
        across = aperture_share(self._edges(vertical=True), np.array([[50.0, 50.0]]), np.array([0.0, 50.0]), 7)
        np.testing.assert_allclose(across, 1.0, atol=1e-6)

    def test_a_corner_shows_motion_both_ways(self):
        image = np.zeros((101, 101), dtype=np.uint8)
        image[50:, 50:] = 200
        share = aperture_share(image, np.array([[50.0, 50.0]]), np.array([0.0, 50.0]), 7)
        assert 0.3 < share[0] < 0.7


def test_the_followed_car_is_caught_by_the_ground_and_missed_by_residual_and_cheirality():
    tracks, _, is_car = road()
    residuals = np.full((540, 4), np.nan, np.float32)
    signed, ground, shortfall = (np.full_like(residuals, np.nan) for _ in range(3))
    for m in range(4):
        distance, parallax, ratio, _, short = pair_evidence(tracks[:, m], tracks[:, m + 2], TrackMotionConfig(), K)
        residuals[:, m], signed[:, m], ground[:, m], shortfall[:, m] = distance, parallax, ratio, short
    assert not moving_tracks(residuals, signed=signed)[is_car].any()  # parallax ~0: neither test sees it
    # The ratio decides where the floor's parallax stands out of the pairs' noise, the shortfall the rest.
    by_ratio = moving_tracks(residuals, signed=signed, ground=ground)
    assert by_ratio[is_car].mean() > 0.8 and by_ratio[~is_car].mean() < 0.01
    flagged = moving_tracks(residuals, signed=signed, ground=ground, shortfall=shortfall)
    assert flagged[is_car].mean() > 0.9 and flagged[~is_car].mean() < 0.01


def pan_follow(frames: int = 6, seed: int = 0):
    """Tracks of a camera that drives right 0.2 m a frame and pans right 1 degree a frame to keep a car
    that moves with it still in the image (DAVIS's car-roundabout): static points 5-60 m away, and the car
    (60 of 400 tracks) 8-9 m ahead, whose image does not move. Against the rotation the car moves opposite to
    the parallax of every static point: behind infinity. Returns tracks (N, F, 2), is_car (N,)."""
    rng = np.random.default_rng(seed)
    static = np.column_stack([rng.uniform(-25, 25, 340), rng.uniform(-3, 2, 340), rng.uniform(5, 60, 340)])
    car = np.column_stack([rng.uniform(-1.5, 1.5, 60), rng.uniform(-0.5, 1, 60), rng.uniform(8, 9, 60)])
    tracks = []
    for t in range(frames):
        angle = -np.deg2rad(1.0) * t
        R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
        seen = (static - np.array([0.2 * t, 0.0, 0.0])) @ R.T @ K.T
        held = car @ K.T
        tracks.append(np.vstack([seen[:, :2] / seen[:, 2:], held[:, :2] / held[:, 2:]]))
    tracks = np.stack(tracks, axis=1) + rng.normal(0, 0.2, (400, frames, 2))
    return tracks.astype(np.float32), np.r_[np.zeros(340, bool), np.ones(60, bool)]


def test_a_mover_holding_a_sixth_of_the_tracks_does_not_veto_the_sign():
    tracks, car = pan_follow()
    undecided = TrackMotionConfig(cheir_consensus=0.9)  # the car's votes (15 %) used to leave the pair unsigned
    residuals, signed = _window_evidence(tracks, K, undecided)
    assert np.isnan(signed).all() and not moving_tracks(residuals, undecided, signed)[car].any()
    residuals, signed = _window_evidence(tracks, K)
    assert not moving_tracks(residuals)[car].any()  # the still car lies on its epipolar lines
    flagged = moving_tracks(residuals, signed=signed)
    assert flagged[car].mean() > 0.9 and flagged[~car].mean() < 0.01


def _dense_fundamental(to_previous):
    h, w = to_previous.shape[:2]
    ys, xs = np.mgrid[0:h:4, 0:w:4]
    here = np.c_[xs.ravel(), ys.ravel()].astype(np.float64)
    there = here + to_previous[::4, ::4].reshape(-1, 2)
    F, _ = cv2.findFundamentalMat(here, there, cv2.USAC_MAGSAC, 0.5, 0.999, 1000)
    return F


class TestBehindInfinity:
    def test_the_body_of_the_followed_car_is_behind_infinity_and_the_background_is_not(self):
        to_previous, is_car, K_flow = pan_follow_flow()
        valid = np.ones(is_car.shape, bool)
        behind = behind_infinity(dense_parallax(to_previous, valid, _dense_fundamental(to_previous), K_flow), valid)
        assert behind.shape == is_car.shape and behind.dtype == bool
        assert behind[is_car].mean() > 0.95 and behind[~is_car].mean() < 0.01

    def test_unreliable_pixels_are_never_flagged(self):
        to_previous, is_car, K_flow = pan_follow_flow()
        valid = np.ones(is_car.shape, bool)
        valid[:, 160:] = False
        behind = behind_infinity(dense_parallax(to_previous, valid, _dense_fundamental(to_previous), K_flow), valid)
        assert not behind[:, 160:].any() and behind[is_car & valid].mean() > 0.95

    def test_no_mask_when_the_vote_cannot_decide(self):
        to_previous, is_car, K_flow = pan_follow_flow()
        unanimous = TrackMotionConfig(cheir_consensus=1.0)  # the car votes against: never unanimous
        assert dense_parallax(to_previous, np.ones(is_car.shape, bool), _dense_fundamental(to_previous), K_flow,
                              unanimous) is None

    def test_a_pair_that_turns_more_than_allowed_keeps_only_what_is_far_behind_infinity(self):
        to_previous, is_car, K_flow = pan_follow_flow()  # turns 1 degree
        F, valid = _dense_fundamental(to_previous), np.ones(is_car.shape, bool)
        behind = behind_infinity(dense_parallax(to_previous, valid, F, K_flow, max_rotation_deg=0.5), valid,
                                 guarded=True)
        assert behind[is_car].mean() > 0.95 and behind[~is_car].mean() < 0.01  # still: all of the rotation
        never = TrackMotionConfig(behind_share=np.inf)
        assert dense_parallax(to_previous, valid, F, K_flow, never, max_rotation_deg=0.5) is None
        assert dense_parallax(to_previous, valid, F, K_flow, never, max_rotation_deg=1.5) is not None


def cut_car_street_flow(height: int = 120, width: int = 320):
    """The dense flow (current -> previous frame) of a camera 1.5 m above a flat road that drove 1 m forward, past
    the rear face of a car parked 5.75 m ahead on the right (x 1-3.5 m) and cut by the image's lower edge, with
    a number plate 1.15 m nearer on it, and towards a car 16 m ahead in the left lane that drove 1 m towards it.
    Returns to_previous (H, W, 2), is_parked (H, W) (face and plate), is_oncoming (H, W), K."""
    K_flow = np.array([[300.0, 0.0, width / 2], [0.0, 300.0, height / 2], [0.0, 0.0, 1.0]])
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([xs, ys, np.ones_like(xs)], axis=-1) @ np.linalg.inv(K_flow).T
    with np.errstate(divide="ignore"):
        depth = np.minimum(np.where(rays[..., 1] > 0, 1.5 / rays[..., 1], np.inf), 200.0)
    faces = []
    for (x0, x1), (y0, y1), z in (((1.0, 3.5), (0.0, 1.5), 5.75), ((1.2, 2.0), (0.6, 0.9), 4.6),
                                  ((-3.5, -1.7), (0.0, 1.5), 16.0)):
        x, y = rays[..., 0] * z, rays[..., 1] * z
        face = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1) & (z < depth)
        depth[face] = z
        faces.append(face)
    world = rays * depth[..., None]
    world[..., 2] += 1.0
    world[faces[2], 2] += 1.0
    seen = world @ K_flow.T
    to_previous = (seen[..., :2] / seen[..., 2:] - np.stack([xs, ys], axis=-1)).astype(np.float32)
    return to_previous, faces[0] | faces[1], faces[2], K_flow


class TestFootingAllowance:
    def test_shape_follows_the_rows(self):
        assert footing_allowance(np.zeros((4, 5)), 0.0, 100.0).shape == (4, 5)
        assert footing_allowance(np.zeros(3, dtype=np.uint16), 0.0, 100.0).shape == (3,)

    def test_known_values(self):
        config = TrackMotionConfig(footing_margin=0.3, footing_overhang=1.0)
        # At and above the epipole row the margin alone; a focal length below it, one overhang more.
        np.testing.assert_allclose(footing_allowance(np.array([40.0, 50.0, 150.0, 250.0]), 50.0, 200.0, config),
                                   [1.3, 1.3, 1.8, 2.3], rtol=1e-6)

    def test_the_overhang_share_scales_with_the_setting(self):
        rows = np.array([60.0, 90.0])
        flat = footing_allowance(rows, 50.0, 100.0, TrackMotionConfig(footing_margin=0.4, footing_overhang=0.0))
        twice = footing_allowance(rows, 50.0, 100.0, TrackMotionConfig(footing_margin=0.3, footing_overhang=2.0))
        np.testing.assert_allclose(flat, [1.4, 1.4])
        np.testing.assert_allclose(twice, [1.5, 2.1], rtol=1e-6)


class TestNearerThanRoad:
    def _near(self, to_previous, K_flow, valid=None, config=TrackMotionConfig()):
        valid = np.ones(to_previous.shape[:2], bool) if valid is None else valid
        parallax = dense_parallax(to_previous, valid, _dense_fundamental(to_previous), K_flow, config)
        return nearer_than_road(parallax, valid, config)

    def test_shape_and_kind(self):
        to_previous, _, _, K_flow = oncoming_street_flow()
        near = self._near(to_previous, K_flow)
        assert near.shape == to_previous.shape[:2] and near.dtype == bool

    def test_the_oncoming_car_is_nearer_than_the_road_and_nothing_static_is(self):
        to_previous, is_parked, is_oncoming, K_flow = oncoming_street_flow()
        near = self._near(to_previous, K_flow)
        # Its lowest rows are as near as the road under them up to the margin; the face above is not.
        assert near[is_oncoming].mean() > 0.9
        assert not near[~is_oncoming].any()

    def test_the_same_car_parked_is_not(self):
        to_previous, _, _, K_flow = oncoming_street_flow(oncoming=False)
        assert not self._near(to_previous, K_flow).any()

    def test_the_residual_and_cheirality_tests_do_not_see_it(self):
        to_previous, _, is_oncoming, K_flow = oncoming_street_flow()
        valid = np.ones(is_oncoming.shape, bool)
        F = _dense_fundamental(to_previous)
        assert not behind_infinity(dense_parallax(to_previous, valid, F, K_flow), valid)[is_oncoming].any()
        here = pixel_grid(*valid.shape)[is_oncoming]
        assert np.median(sampson_pixels(F, here, here + to_previous[is_oncoming])) < 0.1  # in the epipolar plane

    def test_unreliable_pixels_are_never_flagged(self):
        to_previous, _, is_oncoming, K_flow = oncoming_street_flow()
        valid = np.ones(is_oncoming.shape, bool)
        valid[:, :160] = False  # the oncoming car's half
        near = self._near(to_previous, K_flow, valid)
        assert near is not None and not near.any()

    def test_the_least_excess_is_in_the_flows_own_pixels(self):
        to_previous, _, is_oncoming, K_flow = oncoming_street_flow()
        valid = np.ones(is_oncoming.shape, bool)
        parallax = dense_parallax(to_previous, valid, _dense_fundamental(to_previous), K_flow)
        default = nearer_than_road(parallax, valid)  # the track test's footing_px
        assert np.array_equal(default, nearer_than_road(parallax, valid, excess_px=TrackMotionConfig().footing_px))
        assert nearer_than_road(parallax, valid, excess_px=0.25)[is_oncoming].sum() >= default[is_oncoming].sum()
        assert not nearer_than_road(parallax, valid, excess_px=50.0).any()  # more than the car's whole parallax

    def test_a_near_car_cut_by_the_image_edge_is_not_nearer_than_its_own_bumper(self):
        to_previous, is_parked, is_oncoming, K_flow = cut_car_street_flow()
        valid = np.ones(is_parked.shape, bool)
        parallax = dense_parallax(to_previous, valid, _dense_fundamental(to_previous), K_flow)
        # The face's last rows above the image's edge pass for road, and under the margin alone the plate reads
        # nearer than them; the clearance guards it, and so does the overhang's share of the allowance.
        flat = dataclasses.replace(TrackMotionConfig(), footing_overhang=0.0)
        unguarded = nearer_than_road(parallax, valid, flat)
        assert unguarded[is_parked].sum() > 50 and unguarded[is_oncoming].mean() > 0.9
        clearance = MotionFrontEndConfig().dense_footing_clearance
        for config in (flat, TrackMotionConfig()):
            near = nearer_than_road(parallax, valid, config, clearance=clearance)
            assert not near[is_parked].any() and near[is_oncoming].mean() > 0.9
            assert not near[~is_oncoming].any()
        assert not nearer_than_road(parallax, valid)[is_parked].any()

    def test_none_when_the_camera_does_not_drive_along_its_axis(self):
        to_previous, _, _, K_flow = oncoming_street_flow(lateral=3.0)  # 3 m sideways to 1 m forward
        assert self._near(to_previous, K_flow) is None


def oncoming_street(frames: int = 6, seed: int = 0):
    """Tracks of a camera 1.5 m above a flat road driving 1 m a frame down a street between two walls
    (x = +-6 m), past a car parked 15 m ahead on the right, towards a car in the left lane that drives 1 m a
    frame towards it from 16 m (its front face, in the epipolar plane). Static points the parked car hides in
    any frame are left out. Returns tracks (N, F, 2) and the masks (N,) of the parked and oncoming car's
    points."""
    rng = np.random.default_rng(seed)
    road = np.column_stack([rng.uniform(-6, 6, 900), np.full(900, 1.5), rng.uniform(6.5, 40, 900)])
    side = rng.choice([-6.0, 6.0], 200)
    walls = np.column_stack([side, rng.uniform(-2, 1.5, 200), rng.uniform(8, 40, 200)])
    static = np.vstack([road, walls])
    corners = np.array([[3.0, 0.0, 15.0], [4.8, 1.5, 15.0]])
    hidden = np.zeros(len(static), bool)
    for t in range(frames):
        camera = np.array([0.0, 0.0, 1.0 * t])
        (left, top), (right, bottom) = project(corners, camera)
        seen = project(static, camera)
        hidden |= ((seen[:, 0] > left - 2) & (seen[:, 0] < right + 2) & (seen[:, 1] > top - 2)
                   & (seen[:, 1] < bottom + 2) & (static[:, 2] > 15.0))
    static = static[~hidden]
    parked = np.column_stack([rng.uniform(3, 4.8, 40), rng.uniform(0, 1.5, 40), np.full(40, 15.0)])
    oncoming = np.column_stack([rng.uniform(-3.5, -1.7, 40), rng.uniform(0, 1.5, 40), np.full(40, 16.0)])
    tracks = []
    for t in range(frames):
        camera = np.array([0.0, 0.0, 1.0 * t])
        tracks.append(np.vstack([project(static, camera), project(parked, camera),
                                 project(oncoming - [0.0, 0.0, 1.0 * t], camera)]))
    n = len(static)
    tracks = np.stack(tracks, axis=1) + rng.normal(0, 0.2, (n + 80, frames, 2))
    is_parked, is_oncoming = np.zeros(n + 80, bool), np.zeros(n + 80, bool)
    is_parked[n:n + 40], is_oncoming[n + 40:] = True, True
    return tracks.astype(np.float32), is_parked, is_oncoming


class TestFootingExcess:
    def test_shape_and_undecided_points(self):
        tracks, _, _ = oncoming_street()
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        excess = footing_excess(tracks[:, 0], parallax, None)
        assert excess.shape == (len(tracks),) and excess.dtype == np.float32
        assert np.isnan(excess[tracks[:, 0, 1] < parallax.epipole_row]).all()  # above the horizon
        assert np.isfinite(excess).mean() > 0.3

    def test_static_points_stay_under_their_footing_and_the_oncoming_car_does_not(self):
        tracks, is_parked, is_oncoming = oncoming_street()
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        excess = footing_excess(tracks[:, 0], parallax, ground_parallax_ratio(tracks[:, 0], parallax))
        limit = TrackMotionConfig().footing_px
        assert not (excess[~is_oncoming & ~is_parked] > limit).any()
        # Beside its edge the band sees the road behind the parked car: a few of its tracks, in one pair.
        assert np.mean(excess[is_parked] > limit) < 0.2
        # The road under the oncoming car holds few tracks: those of its tracks whose column shows no road clearly
        # below the car's lowest track (``footing_clearance``) are not decided.
        decided = np.isfinite(excess[is_oncoming])
        assert decided.mean() > 0.3 and (excess[is_oncoming][decided] > 3 * limit).all()

    def test_no_excess_without_a_forward_motion(self):
        tracks, _, _ = road(sideways=2.0)
        assert footing_excess(tracks[:, 0], _parallax(tracks[:, 0], tracks[:, 2]), None) is None

    def test_points_above_a_followed_car_are_not_nearer_than_it(self):
        """The followed car (inverse depth ~0, flagged by the ground test) is no footing for the road seen
        above it."""
        tracks, is_road, is_car = road()
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        ground = ground_parallax_ratio(tracks[:, 0], parallax)
        excess = footing_excess(tracks[:, 0], parallax, ground)
        above_car = is_road & (tracks[:, 0, 1] < tracks[is_car, 0, 1].max())
        assert above_car.sum() > 20 and not (excess[above_car] > TrackMotionConfig().footing_px).any()

    def test_a_parked_van_cut_by_the_image_edge_has_no_footing_beside_its_edge(self):
        """The road seen beside the van's edge lies behind it, and its own ground contact is below the image:
        with no clearance the edge's tracks look nearer than that road; with it they are not decided."""
        tracks, is_van = cut_van()
        x1 = tracks[:, 0]
        parallax = _parallax(x1, tracks[:, 2])
        ground = ground_parallax_ratio(x1, parallax)
        limit = TrackMotionConfig().footing_px
        unguarded = footing_excess(x1, parallax, ground, TrackMotionConfig(footing_clearance=0.0))
        excess = footing_excess(x1, parallax, ground)
        assert (unguarded[is_van] > limit).sum() >= 2
        assert not (excess[is_van] > limit).any() and not (excess[~is_van] > limit).any()

    def test_the_column_matches_a_brute_force_one(self):
        rng = np.random.default_rng(5)
        x = rng.uniform(0, 100, (300, 2))
        x[:40, 0] = 50.0  # a column holding many candidates, and ties
        candidates, tested = np.arange(0, 300, 2), np.arange(300)
        index, under = _band_below(x, candidates, tested, 10.0)
        for point in tested:
            expected = candidates[(x[candidates, 1] > x[point, 1]) & (np.abs(x[candidates, 0] - x[point, 0]) < 10.0)]
            assert sorted(index[point][under[point]].tolist()) == sorted(expected.tolist())
        assert _band_below(x, candidates[:0], tested, 10.0) is None


def _forward_drive(static: np.ndarray, movers: np.ndarray, mover_step: np.ndarray, frames: int, seed: int):
    """Tracks (N, F, 2) float32 of ``static`` then ``movers`` points (moving ``mover_step`` a frame) seen by a
    camera driving 1 m a frame down +z, with 0.2 px noise."""
    rng = np.random.default_rng(seed)
    points = np.vstack([static, movers])
    moving = np.r_[np.zeros(len(static)), np.ones(len(movers))][:, None]
    tracks = np.stack([project(points + moving * t * mover_step, np.array([0.0, 0.0, 1.0 * t]))
                       for t in range(frames)], axis=1)
    return (tracks + rng.normal(0, 0.2, tracks.shape)).astype(np.float32)


def walls(rng, n: int = 200) -> np.ndarray:
    """Points on two walls (x = +-6 m), 8-40 m ahead."""
    return np.column_stack([rng.choice([-6.0, 6.0], n), rng.uniform(-2, 1.5, n), rng.uniform(8, 40, n)])


def _in_front_of(points: np.ndarray, near: np.ndarray, margin_px: float = 2.0) -> np.ndarray:
    """(N,) bool: points hidden at the first frame behind the bounding box of the image of ``near`` points."""
    camera = np.zeros(3)
    seen, box = project(points, camera), project(near, camera)
    (left, top), (right, bottom) = box.min(axis=0) - margin_px, box.max(axis=0) + margin_px
    return ((seen[:, 0] > left) & (seen[:, 0] < right) & (seen[:, 1] > top) & (seen[:, 1] < bottom)
            & (points[:, 2] > near[:, 2].min()))


def cut_van(seed: int = 0, bottom: float = 200.0):
    """A parked van (its rear face 8 m ahead on the left, 1.5 m wide, 2.5 m tall) whose lower part, like the road
    under it, is below the image's edge (row ``bottom``), over a road seen beside its edge and between walls.
    Returns the tracks (N, 3, 2) in view over three frames and is_van (N,)."""
    rng = np.random.default_rng(seed)
    road = np.column_stack([rng.uniform(-6, 6, 1500), np.full(1500, 1.5), rng.uniform(4, 40, 1500)])
    van = np.column_stack([rng.uniform(-3.5, -2.0, 60), rng.uniform(-1.0, 1.5, 60), np.full(60, 8.0)])
    static = np.vstack([road, walls(rng)])
    static = static[~_in_front_of(static, van)]
    tracks = _forward_drive(np.vstack([static, van]), np.zeros((0, 3)), np.zeros(3), 3, seed)
    in_view = ((tracks[..., 1] < bottom) & (tracks[..., 0] > 0)).all(axis=1)
    return tracks[in_view], np.r_[np.zeros(len(static), bool), np.ones(len(van), bool)][in_view]


def sparse_road_oncoming(seed: int = 0):
    """An oncoming car (left lane, front face 16 m ahead, 1 m a frame towards the camera) over a road that holds
    few tracks near it: a handful right under its lower edge (12.5-13.5 m), the rest nearer than 6 m or beyond
    25 m (where the car does not hide it). Returns tracks (N, 3, 2) and is_car (N,)."""
    rng = np.random.default_rng(seed)
    road = np.column_stack([rng.uniform(-6, 6, 600), np.full(600, 1.5),
                            np.where(rng.random(600) < 0.5, rng.uniform(4.5, 6, 600), rng.uniform(25, 40, 600))])
    return _oncoming_over(road, rng, seed)


def road_ahead_of_oncoming(seed: int = 0):
    """An oncoming car (as ``sparse_road_oncoming``, with its handful of road tracks right under its lower edge)
    whose road is tracked 7-9 m ahead too: that road, in the car's columns, is as near as the car looks in a
    pair two frames apart (it closes in at twice the camera's speed). Returns tracks (N, 3, 2) and is_car
    (N,)."""
    rng = np.random.default_rng(seed)
    depth = np.concatenate([rng.uniform(4.5, 6, 300), rng.uniform(7, 9, 300), rng.uniform(25, 40, 300)])
    return _oncoming_over(np.column_stack([rng.uniform(-6, 6, 900), np.full(900, 1.5), depth]), rng, seed)


def _oncoming_over(road: np.ndarray, rng: np.random.Generator, seed: int):
    """The oncoming car of ``sparse_road_oncoming`` over ``road`` points plus a handful of road tracks right under
    its lower edge (12.5-13.5 m) and the walls; points it hides are left out. Returns tracks (N, 3, 2) and
    is_car (N,)."""
    under = np.column_stack([rng.uniform(-3.4, -1.8, 6), np.full(6, 1.5), rng.uniform(12.5, 13.5, 6)])
    car = np.column_stack([rng.uniform(-3.5, -1.7, 40), rng.uniform(0, 1.5, 40), np.full(40, 16.0)])
    static = np.vstack([road, under, walls(rng)])
    static = static[~_in_front_of(static, car)]
    tracks = _forward_drive(static, car, np.array([0.0, 0.0, -1.0]), 3, seed)
    return tracks, np.r_[np.zeros(len(static), bool), np.ones(len(car), bool)]


def pole_street(seed: int = 0):
    """A thin pole (0.1 m wide, 3 m tall, 10 m ahead on the right) over a densely tracked road in front of it;
    of the road behind it, only two tracks right beside its trunk. Returns tracks (N, 3, 2) and is_pole (N,)."""
    rng = np.random.default_rng(seed)
    front = np.column_stack([rng.uniform(-6, 6, 900), np.full(900, 1.5), rng.uniform(6.5, 10, 900)])
    behind = np.column_stack([rng.uniform(-6, 6, 300), np.full(300, 1.5), rng.uniform(10, 40, 300)])
    pole = np.column_stack([rng.uniform(2.95, 3.05, 40), rng.uniform(-1.5, 1.5, 40), np.full(40, 10.0)])
    column = np.abs(project(behind, np.zeros(3))[:, 0] - project(pole[:1], np.zeros(3))[0, 0]) < 15.0
    beside = np.array([[0.312 * 12.5, 1.5, 12.5], [0.312 * 13.5, 1.5, 13.5]])  # 6 px right of the trunk
    static = np.vstack([front, behind[~column], beside, walls(rng)])
    tracks = _forward_drive(np.vstack([static, pole]), np.zeros((0, 3)), np.zeros(3), 3, seed)
    return tracks, np.r_[np.zeros(len(static), bool), np.ones(40, bool)]


def walking_away(seed: int = 0, speed: float = 0.6):
    """A pedestrian (0.5 m wide, 1.8 m tall, 12 m ahead on the right) walking away at ``speed`` of the camera's
    speed over a densely tracked road, between two walls. Returns tracks (N, 3, 2) and is_walker (N,)."""
    rng = np.random.default_rng(seed)
    road = np.column_stack([rng.uniform(-6, 6, 900), np.full(900, 1.5), rng.uniform(6.5, 40, 900)])
    walker = np.column_stack([rng.uniform(2.5, 3.0, 40), rng.uniform(-0.3, 1.45, 40), np.full(40, 12.0)])
    static = np.vstack([road, walls(rng)])
    static = static[~_in_front_of(static, walker)]
    tracks = _forward_drive(static, walker, np.array([0.0, 0.0, speed]), 3, seed)
    return tracks, np.r_[np.zeros(len(static), bool), np.ones(len(walker), bool)]


class TestStandingRows:
    def test_a_walker_stands_on_its_lowest_track_and_the_road_nearly_where_it_is(self):
        tracks, is_walker = walking_away()
        x1 = tracks[:, 0]
        parallax = _parallax(x1, tracks[:, 2])
        rows = standing_rows(x1, parallax, ground_parallax_ratio(x1, parallax))
        assert rows.shape == (len(x1),) and rows.dtype == np.float64
        assert (rows >= x1[:, 1]).all()
        lowest = x1[is_walker, 1].max()
        assert np.median(lowest - rows[is_walker]) < 3.0 and np.median(rows[is_walker] - x1[is_walker, 1]) > 10.0
        # On the road the next tracks down are nearer by more than the same-depth share within a few rows.
        below = ~is_walker & (x1[:, 1] > parallax.epipole_row + 5)
        assert np.median(rows[below] - x1[below, 1]) < 3.0
        # Above the epipole every track stands where it is.
        above = x1[:, 1] <= parallax.epipole_row
        np.testing.assert_array_equal(rows[above], x1[above, 1])

    def test_the_walker_is_short_of_the_ground_where_it_stands_not_of_the_road_at_its_rows(self):
        tracks, is_walker = walking_away()
        config = TrackMotionConfig()
        evidence = pair_evidence(tracks[:, 0], tracks[:, 2], config, K)
        short = evidence.shortfall > 0
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        own = (ground_floor(tracks[:, 0], parallax) - parallax.signed > config.shortfall_px) & (
            evidence.ground < config.shortfall_ratio)
        assert short[is_walker].mean() > 0.7 and own[is_walker].mean() < 0.4
        # The road seen just beside the walker lies as far as the walker looks: it stands on the walker's feet.
        columns = tracks[is_walker, 0, 0]
        away = (tracks[:, 0, 0] < columns.min() - 8) | (tracks[:, 0, 0] > columns.max() + 8)
        assert not short[~is_walker & away].any()

    def test_the_margin_is_the_lesser_of_the_pixels_and_the_share_short(self):
        tracks, _ = walking_away()
        x1 = tracks[:, 0]
        parallax = _parallax(x1, tracks[:, 2])
        ground = ground_parallax_ratio(x1, parallax)
        config = TrackMotionConfig(shortfall_px=1.0, shortfall_ratio=0.6, shortfall_strong_px=0.0)
        floor = ground_floor(x1, parallax, config, rows=standing_rows(x1, parallax, ground, config))
        margin = standing_shortfall(x1, parallax, ground, config)
        assert margin.shape == (len(x1),) and margin.dtype == np.float32
        expected = np.minimum(floor - parallax.signed - 1.0, 0.6 * floor - parallax.signed)
        np.testing.assert_allclose(margin, expected, rtol=1e-5, atol=1e-4)
        np.testing.assert_array_equal(np.isnan(margin), np.isnan(floor))
        # A track near the horizon, whose own row's road is below the noise, is decided where it stands.
        assert (np.isnan(ground) & np.isfinite(margin)).any()
        assert standing_shortfall(x1, dataclasses.replace(parallax, epipole_row=None), ground, config) is None

    def test_a_strong_shortfall_needs_only_the_milder_share(self):
        tracks, _ = walking_away()
        x1 = tracks[:, 0]
        parallax = _parallax(x1, tracks[:, 2])
        ground = ground_parallax_ratio(x1, parallax)
        config = TrackMotionConfig(shortfall_px=1.0, shortfall_ratio=0.6, shortfall_strong_px=4.0,
                                   shortfall_strong_ratio=0.9)
        floor = ground_floor(x1, parallax, config, rows=standing_rows(x1, parallax, ground, config))
        short = floor - parallax.signed
        plain, strong = np.minimum(short - 1.0, short - 0.4 * floor), np.minimum(short - 4.0, short - 0.1 * floor)
        expected = np.maximum(plain, strong)
        np.testing.assert_allclose(standing_shortfall(x1, parallax, ground, config), expected, rtol=1e-5, atol=1e-4)
        assert (strong > plain).any()  # the strong measure decides somewhere in this scene

    def test_a_slower_mover_is_short_only_by_the_strong_measures(self):
        # Going away at 0.4 of the camera's speed, 12 m ahead: it keeps about 0.7 of the floor's parallax where it
        # stands (the floor is read low), above the 0.6 share, but falls short of it by 5-6 px.
        tracks, is_walker = walking_away(speed=0.4)
        strong = pair_evidence(tracks[:, 0], tracks[:, 2], TrackMotionConfig(), K)
        plain = pair_evidence(tracks[:, 0], tracks[:, 2], TrackMotionConfig(shortfall_strong_px=0.0), K)
        assert (strong.shortfall[is_walker] > 0).mean() > 0.7
        assert not (plain.shortfall[is_walker] > 0).any()
        # The road and the walls beside it stay unflagged.
        columns = tracks[is_walker, 0, 0]
        away = (tracks[:, 0, 0] < columns.min() - 8) | (tracks[:, 0, 0] > columns.max() + 8)
        assert not (strong.shortfall[~is_walker & away] > 0).any()

    def test_no_rows_moved_without_a_forward_motion(self):
        tracks, _, _ = road(sideways=2.0)
        parallax = dataclasses.replace(_parallax(tracks[:, 0], tracks[:, 2]), epipole_row=None)
        np.testing.assert_array_equal(standing_rows(tracks[:, 0], parallax, None), tracks[:, 0, 1])


class TestFootingColumns:
    def test_shared_columns_give_what_each_test_finds_itself(self):
        tracks, _ = walking_away()
        x1 = tracks[:, 0]
        parallax = _parallax(x1, tracks[:, 2])
        ground = ground_parallax_ratio(x1, parallax)
        columns = footing_columns(x1, parallax, ground)
        assert columns.tested.size > 100 and columns.index.shape == columns.under.shape
        assert columns.index.shape[0] == columns.tested.size and columns.depth.shape == (len(x1),)
        assert (x1[columns.tested, 1] > parallax.epipole_row).all()
        np.testing.assert_array_equal(footing_excess(x1, parallax, ground, columns=columns),
                                      footing_excess(x1, parallax, ground))
        np.testing.assert_array_equal(standing_rows(x1, parallax, ground, columns=columns),
                                      standing_rows(x1, parallax, ground))

    def test_without_a_footing_in_any_band_nothing_is_decided(self):
        tracks, _ = walking_away()
        x1 = tracks[:, 0]
        behind = dataclasses.replace(_parallax(x1, tracks[:, 2]), signed=-np.abs(_parallax(x1, tracks[:, 2]).signed))
        columns = footing_columns(x1, behind, None)
        assert columns.tested.size == 0 and columns.index.shape == (0, 0)
        assert np.isnan(footing_excess(x1, behind, None, columns=columns)).all()
        np.testing.assert_array_equal(standing_rows(x1, behind, None, columns=columns), x1[:, 1])


class TestFootingBase:
    def test_the_oncoming_car_over_a_sparsely_tracked_road_is_caught_only_with_the_road(self):
        tracks, is_car = sparse_road_oncoming()
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        ground = ground_parallax_ratio(tracks[:, 0], parallax)
        limit = TrackMotionConfig().footing_px
        without = footing_excess(tracks[:, 0], parallax, ground, TrackMotionConfig(footing_road_tol=0.0))
        excess = footing_excess(tracks[:, 0], parallax, ground)
        assert np.mean(without[is_car] > limit) < 0.5
        assert np.mean(excess[is_car] > limit) > 0.9 and not (excess[~is_car] > limit).any()

    def test_the_road_in_front_of_an_oncoming_car_at_its_seeming_depth_is_not_its_base(self):
        tracks, is_car = road_ahead_of_oncoming()
        x1 = tracks[:, 0]
        parallax = _parallax(x1, tracks[:, 2])
        ground = ground_parallax_ratio(x1, parallax)
        config = TrackMotionConfig()
        columns = footing_columns(x1, parallax, ground)
        # The trap: road tracks in the car's columns, below it, at the car's own inverse depth.
        car_depth = np.median(columns.depth[is_car])
        left, right = np.percentile(x1[is_car, 0], [10, 90])
        trap = (~is_car & (x1[:, 0] > left) & (x1[:, 0] < right) & (x1[:, 1] > x1[is_car, 1].max())
                & (np.abs(columns.depth / car_depth - 1.0) <= config.footing_same_depth))
        assert trap.sum() >= 5 and (np.abs(ground[trap] - 1.0) <= config.footing_road_tol).all()
        excess = footing_excess(x1, parallax, ground, config, columns=columns)
        # 70 % of the car's tracks are caught; taking the trap for the car's base caught 48 %.
        assert np.mean(excess[is_car] > config.footing_px) > 0.6 and not (excess[~is_car] > config.footing_px).any()

    def test_a_thin_pole_is_not_held_to_the_road_seen_behind_it(self):
        tracks, is_pole = pole_street()
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        ground = ground_parallax_ratio(tracks[:, 0], parallax)
        limit = TrackMotionConfig().footing_px
        tested = is_pole & (tracks[:, 0, 1] > parallax.epipole_row)
        excess = footing_excess(tracks[:, 0], parallax, ground)
        assert tested.sum() > 15 and np.isfinite(excess[tested]).all() and not (excess > limit).any()
        # Without its own trunk to stand on, the pole is held to the road seen beside the trunk.
        unrooted = footing_excess(tracks[:, 0], parallax, ground, TrackMotionConfig(footing_same_depth=0.0))
        assert np.mean(unrooted[tested] > limit) > 0.5

    def test_the_road_slope_is_the_grounds_inverse_depth_per_row(self):
        tracks, _ = pole_street()
        parallax = _parallax(tracks[:, 0], tracks[:, 2])
        # The road 1.5 m below a camera of focal 500 px is at depth 750 / row (rows below the epipole); the
        # pair is 2 m apart and signed parallax measures inverse depth in baselines.
        assert ground_slope(tracks[:, 0], parallax) == pytest.approx(2.0 / 750, rel=0.15)
        assert ground_slope(tracks[:, 0], dataclasses.replace(parallax, epipole_row=None)) is None


def test_the_oncoming_car_is_caught_by_its_footing_and_missed_by_every_other_test():
    tracks, is_parked, is_oncoming = oncoming_street()
    evidence = [pair_evidence(tracks[:, m], tracks[:, m + 2], TrackMotionConfig(), K) for m in range(4)]
    residuals, signed, ground, footing, shortfall = (np.stack(table, axis=1) for table in zip(*evidence))
    assert not moving_tracks(residuals, signed=signed, ground=ground, shortfall=shortfall)[is_oncoming].any()
    flagged = moving_tracks(residuals, signed=signed, ground=ground, footing=footing, shortfall=shortfall)
    # Not all: under the car's sparse road some columns show nothing clearly below its lowest track in any pair.
    assert flagged[is_oncoming].mean() > 0.6
    # Beside the parked car's near edge its column band sees the road behind it, and the car's own road-level
    # tracks are no longer its base: a track or two right at that edge may be flagged, never its body.
    edge = tracks[is_parked, 0, 0].min() + 2 * TrackMotionConfig().footing_band * np.ptp(tracks[:, 0, 0])
    assert flagged[is_parked].sum() <= 2 and (tracks[is_parked, 0, 0][flagged[is_parked]] <= edge).all()
    assert flagged[~is_oncoming].mean() < 0.01
