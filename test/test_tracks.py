"""KLT point tracks: ids persist, positions follow the true motion, dead points are replaced."""

from __future__ import annotations

import cv2
import numpy as np

from conftest import textured_frames
from moseg_ros.frontend.tracks import PointTracker, TrackerConfig, landing


def test_points_follow_the_pan_and_keep_their_ids():
    tracker = PointTracker(TrackerConfig(max_points=300))
    frames = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in textured_frames(6)]
    tracker.update(frames[0])
    first = dict(zip(tracker.ids.tolist(), tracker.points))
    assert len(first) == 300
    for frame in frames[1:]:
        tracker.update(frame)
    survivors = [i for i in tracker.ids.tolist() if i in first]
    moved = np.array([tracker.points[tracker.ids.tolist().index(i)] - first[i] for i in survivors])
    background = moved[np.abs(moved[:, 1]) < 1.0]  # the sliding block moves down; the texture pans left
    assert len(background) > 150
    assert np.allclose(np.median(background, axis=0), [-10.0, 0.0], atol=0.2)  # 5 frames x 2 px
    assert len(tracker.ids) == len(np.unique(tracker.ids)) == 300  # dead points were replaced by new ids


def test_reset_forgets_every_point():
    tracker = PointTracker()
    tracker.update(cv2.cvtColor(textured_frames(1)[0], cv2.COLOR_RGB2GRAY))
    tracker.reset()
    assert tracker.ids.size == 0 and tracker.points.shape == (0, 2)


def _tracked(frames: list[np.ndarray], backward: np.ndarray | None, **settings) -> tuple[PointTracker, list[float]]:
    tracker = PointTracker(TrackerConfig(max_points=300, **settings))
    checked = []
    for i, frame in enumerate(frames):
        tracker.update(frame, backward if i else None)
        checked.append(tracker.flow_checked)
    return tracker, checked


class TestDenseBackwardCheck:
    FRAMES = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in textured_frames(5)]
    # The pan's backward flow (2 px right per frame), given at half size in half-size pixels.
    PAN_BACK = np.broadcast_to(np.float32([1.0, 0.0]), (94, 311, 2)).copy()

    def test_a_flow_that_agrees_stands_in_for_the_klt_backward_pass(self):
        alone, _ = _tracked(self.FRAMES, None)
        shared, checked = _tracked(self.FRAMES, self.PAN_BACK)
        assert min(checked[1:]) > 0.7  # the background; the sliding block goes back to KLT
        assert np.array_equal(shared.ids, alone.ids)
        assert np.percentile(np.abs(shared.points - alone.points), 95) < 0.1  # KLT refined the flow's guess

    def test_a_flow_that_disagrees_leaves_the_check_to_klt(self):
        alone, _ = _tracked(self.FRAMES, None)
        shared, checked = _tracked(self.FRAMES, np.zeros_like(self.PAN_BACK))
        assert max(checked) == 0.0
        assert np.array_equal(shared.ids, alone.ids)  # a guess 2 px off is within the finest levels' reach
        assert np.percentile(np.abs(shared.points - alone.points), 95) < 0.1

    def test_off_when_the_tolerance_is_zero(self):
        _, checked = _tracked(self.FRAMES, self.PAN_BACK, flow_check_px=0.0)
        assert max(checked) == 0.0


class TestGuessFromTheBackwardFlow:
    FRAMES = TestDenseBackwardCheck.FRAMES
    PAN_BACK = TestDenseBackwardCheck.PAN_BACK

    def test_a_right_flow_lands_where_the_full_search_does(self):
        alone, _ = _tracked(self.FRAMES, None)
        guided, _ = _tracked(self.FRAMES, self.PAN_BACK, flow_check_px=0.0)  # KLT's own backward pass
        common, a, g = np.intersect1d(alone.ids, guided.ids, return_indices=True)
        assert len(common) > 250
        assert np.percentile(np.abs(alone.points[a] - guided.points[g]), 95) < 0.1

    def test_the_search_starts_from_the_guess(self):
        # 30 px off (15 half-size px): beyond what the finest two levels of a 21 px window reach, so a tracker
        # that ignored the guess would keep its points and one that uses it loses them.
        alone, _ = _tracked(self.FRAMES, None)
        astray, _ = _tracked(self.FRAMES, self.PAN_BACK + np.float32([15.0, 0.0]))
        assert len(np.intersect1d(alone.ids, astray.ids)) < 0.5 * len(alone.ids)

    def test_shape_of_what_comes_back(self):
        guided, _ = _tracked(self.FRAMES[:2], self.PAN_BACK)
        assert guided.points.shape == (300, 2) and guided.points.dtype == np.float32 and guided.ids.shape == (300,)


class TestLanding:
    SHAPE = (100, 200)

    def test_smoke_and_shape(self):
        points = np.float32([[10.0, 20.0], [150.5, 80.25]])
        out = landing(np.zeros((50, 100, 2), np.float32), points, self.SHAPE)
        assert out.shape == (2, 2) and np.array_equal(out, points)

    def test_a_constant_flow_is_inverted_exactly(self):
        back = np.broadcast_to(np.float32([1.5, -0.5]), (50, 100, 2)).copy()  # 3, -1 px at full size
        points = np.float32([[10.0, 20.0], [150.0, 80.0]])
        assert np.allclose(landing(back, points, self.SHAPE), points - [3.0, -1.0], atol=1e-4)

    def test_a_zoom_is_inverted_within_a_fraction_of_a_pixel(self):
        # Current -> previous shrinks about the origin by 10 %: q + b(q) = 0.9 q, so p lands at q = p / 0.9.
        ys, xs = np.mgrid[0:100, 0:200].astype(np.float32)
        back = -0.1 * np.dstack([xs, ys])
        points = np.float32([[50.0, 30.0], [120.0, 70.0], [170.0, 85.0]])
        exact = points / 0.9
        errors = [np.abs(landing(back, points, self.SHAPE, rounds) - exact).max() for rounds in (1, 2, 3)]
        assert errors[0] > errors[1] > errors[2]
        assert errors[1] < 0.25  # two rounds, the tracker's: 0.1 % of a 190 px vector

class TestSeedWidth:
    # White squares on black: their corners are the only corners, at known places.
    TOPS = [(20 + 60 * (i % 6), 30 + 70 * (i // 6)) for i in range(12)]

    def _image(self) -> np.ndarray:
        image = np.zeros((200, 400), np.uint8)
        for x, y in self.TOPS:
            image[y:y + 16, x:x + 16] = 255
        return image

    def _corners(self) -> np.ndarray:
        return np.float32([(x + dx, y + dy) for x, y in self.TOPS for dx in (0, 15) for dy in (0, 15)])

    def _distances(self, seed_width: int) -> np.ndarray:
        tracker = PointTracker(TrackerConfig(max_points=48, min_distance=5, quality=0.01, seed_width=seed_width))
        tracker.update(self._image())
        gaps = np.linalg.norm(tracker.points[:, None] - self._corners()[None], axis=2)
        return gaps.min(axis=1)

    def test_full_size_finds_the_corners(self):
        assert np.all(self._distances(0) <= 1.5)

    def test_half_size_corners_land_on_the_full_size_corners(self):
        distances = self._distances(200)
        assert len(distances) >= 40 and np.all(distances <= 2.0)

    def test_spacing_holds_in_full_size_pixels(self):
        tracker = PointTracker(TrackerConfig(max_points=2000, min_distance=8, quality=0.001, seed_width=200))
        tracker.update(cv2.cvtColor(textured_frames(1)[0], cv2.COLOR_RGB2GRAY))
        nearest = np.sort(np.linalg.norm(tracker.points[:, None] - tracker.points[None], axis=2), axis=1)[:, 1]
        assert len(tracker.points) > 100 and nearest.min() >= 8 - 2 * 1.6

    def _seeded(self, shrunk: np.ndarray | None) -> PointTracker:
        tracker = PointTracker(TrackerConfig(max_points=48, min_distance=5, quality=0.01, seed_width=200))
        tracker.update(self._image(), shrunk=shrunk)
        return tracker

    def test_the_callers_shrunk_frame_gives_the_same_corners(self):
        shrunk = cv2.resize(self._image(), (200, 100), interpolation=cv2.INTER_AREA)
        alone, shared = self._seeded(None), self._seeded(shrunk)
        np.testing.assert_array_equal(shared.points, alone.points)
        np.testing.assert_array_equal(shared.ids, alone.ids)

    def test_corners_are_found_on_the_callers_shrunk_frame(self):
        # A blank frame of the seeding size has no corners: it is the one searched, not a second shrink of gray.
        assert len(self._seeded(np.zeros((100, 200), np.uint8)).points) == 0

    def test_a_shrunk_frame_of_another_size_is_not_used(self):
        assert len(self._seeded(np.zeros((50, 100), np.uint8)).points) == len(self._seeded(None).points) > 40


class TestSampled:
    def test_shape_and_units_of_a_half_size_flow(self):
        from moseg_ros.frontend.tracks import _sampled

        flow = np.broadcast_to(np.float32([1.0, -2.0]), (50, 100, 2)).copy()
        values = _sampled(flow, np.float32([[0, 0], [150.5, 60.25], [199, 99]]), (100, 200))
        assert values.shape == (3, 2) and np.allclose(values, [[2.0, -4.0]] * 3)

    def test_bilinear_between_pixels(self):
        from moseg_ros.frontend.tracks import _sampled

        flow = np.zeros((10, 10, 2), np.float32)
        flow[..., 0] = np.arange(10, dtype=np.float32)[None, :]  # u = x
        assert np.allclose(_sampled(flow, np.float32([[3.25, 4.0]]), (10, 10)), [[3.25, 0.0]])
