"""The weight-free motion front-end: hulls of linked moving tracks, and regions that cover the mover only."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from conftest import oncoming_street_flow, pan_follow_flow, textured_frames
from moseg_ros.core.track_tests.cheirality import guessed_camera_matrix
from moseg_ros.core.track_tests.settings import TrackMotionConfig
from moseg_ros.core.flow_field import away_from_border
from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.motion import MotionFrontEnd
from moseg_ros.frontend.motion_config import MotionFrontEndConfig
from moseg_ros.frontend.observe import Observation, resized_to_width
from moseg_ros.frontend.track_evidence import dense_near
from moseg_ros.synth.scenarios import render_sequence


def block_truth(index: int, height: int = 188, width: int = 621, speed: int = 3) -> np.ndarray:
    truth = np.zeros((height, width), dtype=bool)
    y = height // 6 + speed * index
    truth[y:y + height // 3, width // 4:width // 4 + width // 8] = True
    return truth


class TestResizedToWidth:
    def test_shape_and_type_of_a_kitti_frame(self):
        gray = np.random.default_rng(0).integers(0, 256, (370, 1226)).astype(np.uint8)
        small = resized_to_width(gray, 640)
        assert small.shape == (193, 640) and small.dtype == np.uint8

    def test_a_frame_not_larger_is_returned_as_is(self):
        gray = np.zeros((100, 300), np.uint8)
        assert resized_to_width(gray, 640) is gray

    def test_four_times_smaller_is_two_pyramid_halvings(self):
        gray = np.random.default_rng(1).integers(0, 256, (400, 1600)).astype(np.uint8)
        assert np.array_equal(resized_to_width(gray, 400), cv2.pyrDown(cv2.pyrDown(gray)))

    def test_smooth_content_matches_the_area_average(self):
        """A smooth frame shrunk by the pyramid and a linear step reads as INTER_AREA's average does."""
        y, x = np.mgrid[0:370, 0:1226]
        gray = (127 + 60 * np.sin(x / 40.0) * np.cos(y / 30.0)).astype(np.uint8)
        area = cv2.resize(gray, (640, 193), interpolation=cv2.INTER_AREA).astype(float)
        assert np.abs(resized_to_width(gray, 640).astype(float) - area).mean() < 1.0


class TestMotionFrontEnd:
    def test_the_sliding_block_becomes_one_region_and_the_pan_none(self):
        front_end = MotionFrontEnd(MotionFrontEndConfig(tracks=MotionFrontEndConfig().tracks))
        ious, outside = [], []
        ids = set()
        for i, frame in enumerate(textured_frames(10)):
            labels = front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
            assert labels.shape == frame.shape[:2] and labels.dtype == np.int32
            if i >= 3:
                truth = block_truth(i)
                found = labels > 0
                ious.append((found & truth).sum() / (found | truth).sum())
                outside.append((found & ~truth).mean())
                ids |= set(np.unique(labels[truth & found]).tolist())
        assert np.mean(ious) > 0.6, ious
        assert np.mean(outside) < 0.02
        assert len(ids) == 1  # one object, one id over the frames

    def test_moving_tracks_lie_on_the_block(self):
        front_end = MotionFrontEnd()
        for frame in textured_frames(6):
            front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
        xy = np.rint(front_end.moving_track_points).astype(int)
        assert len(xy) > 10
        # A corner on the block's outline is the block's too: its KLT window holds the block's texture.
        outline = cv2.dilate(block_truth(5).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        assert outline[xy[:, 1], xy[:, 0]].mean() > 0.9

    def test_the_long_pair_comes_once_the_window_outgrows_the_short_pairs(self):
        config = MotionFrontEndConfig(dense=False)
        front_end = MotionFrontEnd(config)
        spans = []
        for frame in textured_frames(10):
            observation = front_end.observe(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
            spans.append(observation.long_span if observation.long_pair is not None else None)
        gap, window = config.track_motion.gap, config.window_length
        assert spans == [None] * (gap + 1) + list(range(gap + 1, window)) + [window - 1] * (10 - window)

    def test_a_mover_that_stops_is_let_go_once_its_flags_are_sticky_frames_old(self):
        def flagged_pixels(sticky_frames: int) -> list[int]:
            front_end = MotionFrontEnd(MotionFrontEndConfig(dense=False, sticky_frames=sticky_frames))
            counts = []
            for frame in textured_frames(30, stop=8):
                front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
                counts.append(int(front_end.moving.sum()))
            return counts

        default = flagged_pixels(MotionFrontEndConfig().sticky_frames)
        assert min(default[3:9]) > 3000  # the moving block (188 / 3 x 621 / 8 = 4774 px) is found
        assert max(default[-6:]) == 0  # and let go after it parks
        assert min(flagged_pixels(10_000)[-6:]) > 3000  # flags held while the tracks live would keep it

    def test_a_late_dense_mask_keeps_only_what_still_moves(self):
        """The block's dense mask of frame 7, applied two frames after the block parked (frame 8): with
        ``late_dense_px`` the frame's flow, which rides with the background there, drops it; without, it is carried
        along, and so it is where the depth tests flagged it (their movers' flow follows the epipolar geometry).
        Applied on time nothing changes."""
        def dense_share(late_dense_px: float, depth: bool = False) -> tuple[float, float]:
            config = MotionFrontEndConfig(sticky_frames=0, memory_frames=0, object_flow=None,
                                          late_dense_px=late_dense_px)
            front_end = MotionFrontEnd(config)
            frames = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in textured_frames(11, stop=8)]
            for frame in frames[:7]:
                front_end.update(frame)
            late = front_end.refit(front_end.observe(frames[7]))
            on_time = block_truth(7)
            front_end.apply(late)
            shares = [float(front_end.moving[on_time].mean())]
            for frame in frames[8:]:
                front_end.observe(frame)
            front_end.apply(replace(late, flagged=np.zeros(0, dtype=np.int64),
                                    dense_depth=late.dense if depth else late.dense_depth))
            return shares[0], float(front_end.moving.mean())

        trimmed, kept = dense_share(0.3), dense_share(0.0)
        assert trimmed[0] == kept[0] > 0.5  # on time: the block's dense mask, the same either way
        assert kept[1] > 0.5 * trimmed[0] * block_truth(7).mean() and trimmed[1] < 0.2 * kept[1]
        assert dense_share(0.3, depth=True)[1] == kept[1]

    def test_a_late_dense_mask_of_a_planar_scene_is_tested_against_the_homography(self):
        """The pan over a flat texture is a homography, and the F of its tracks is degenerate: one of its family
        takes the sliding block in. The block's dense mask of frame 7, applied at frame 9 while it still slides,
        is kept against the frame's homography (``dense_planar``); against that F it would be dropped."""
        config = MotionFrontEndConfig(sticky_frames=0, memory_frames=0, object_flow=None)
        front_end = MotionFrontEnd(config)
        frames = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in textured_frames(10, mover_speed_px=1)]
        for frame in frames[:7]:
            front_end.update(frame)
        late = front_end.refit(front_end.observe(frames[7]))
        for frame in frames[8:]:
            front_end.observe(frame)
        assert late.dense_planar and late.dense is not None

        def kept(planar: bool) -> float:
            front_end.apply(replace(late, flagged=np.zeros(0, dtype=np.int64), dense_planar=planar))
            return float(front_end.moving[block_truth(9, speed=1)].mean())

        assert kept(True) > 0.75
        assert kept(False) < 0.05

    def test_the_dense_flow_back_to_the_previous_frame_checks_the_tracks(self):
        def checked(dense_gap: int) -> list[float]:
            front_end = MotionFrontEnd(MotionFrontEndConfig(dense_gap=dense_gap))
            shares = []
            for frame in textured_frames(5):
                front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
                shares.append(front_end.observer._points.flow_checked)  # the tracker's own count
            return shares

        assert min(checked(1)[1:]) > 0.5  # the pan's DIS flow confirms most background tracks
        assert max(checked(2)) == 0.0  # a flow two frames back is no check of one frame's tracking

    def test_reset_forgets_the_stream(self):
        front_end = MotionFrontEnd()
        for frame in textured_frames(4):
            front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
        front_end.reset()
        labels = front_end.update(cv2.cvtColor(textured_frames(1)[0], cv2.COLOR_RGB2GRAY))
        assert not labels.any() and len(front_end.moving_track_points) == 0


class TestStickyFlags:
    """A track flagged in ``sticky_windows`` windows stays flagged for ``sticky_frames`` frames; a refit that comes
    several frames after the one before counts its flags for the windows it stands in for."""

    ALIVE = np.arange(6)

    @staticmethod
    def _sticky(refits: list[tuple[int, list[int]]]) -> list[list[int]]:
        front_end = MotionFrontEnd(MotionFrontEndConfig(dense=False))
        tracks = front_end.evidence.tracks
        return [tracks._count_flags(np.array(flagged, dtype=np.int64), TestStickyFlags.ALIVE, index).tolist()
                for index, flagged in refits]

    def test_refitting_every_frame_a_flag_sticks_from_its_second_window(self):
        assert self._sticky([(2, [1]), (3, []), (4, [1]), (5, [])]) == [[], [], [1], [1]]

    def test_the_first_refit_of_a_stream_counts_one_window(self):
        assert self._sticky([(5, [1]), (6, [])]) == [[], []]

    def test_a_refit_three_frames_after_the_last_counts_as_two_windows(self):
        assert self._sticky([(2, [3]), (5, [1]), (8, [])]) == [[], [1], [1]]

    def test_a_sticky_flag_is_let_go_after_sticky_frames(self):
        frames = MotionFrontEndConfig().sticky_frames
        assert self._sticky([(2, []), (5, [1]), (5 + frames, []), (6 + frames, [])]) == [[], [1], [1], []]


class TestCatchUp:
    """A refit that skips frames (a background worker slower than the camera) fits their track pairs too, up to
    ``catch_up_pairs`` of them, newest first."""

    @staticmethod
    def _pairs(every: int, catch_up_pairs: int) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
        front_end = MotionFrontEnd(MotionFrontEndConfig(dense=False, catch_up_pairs=catch_up_pairs))
        for index, frame in enumerate(textured_frames(9)):
            observation = front_end.observe(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
            if index % every == 0:
                flagged = front_end.refit(observation).flagged
        return [(ids, evidence.distance) for ids, evidence in front_end.evidence.tracks._pairs], flagged

    def test_catching_up_on_every_skipped_frame_holds_the_pairs_of_refitting_every_frame(self):
        every_frame, flagged_every = self._pairs(1, 0)
        skipping, flagged_skipping = self._pairs(4, 8)
        config = MotionFrontEndConfig()
        assert len(every_frame) == len(skipping) == config.window_length - config.track_motion.gap
        for (ids, distance), (ids_skipping, distance_skipping) in zip(every_frame, skipping):
            np.testing.assert_array_equal(ids, ids_skipping)
            np.testing.assert_allclose(distance, distance_skipping)
        assert flagged_skipping.size > 10 and np.isin(flagged_skipping, flagged_every).all()

    @pytest.mark.parametrize("catch_up_pairs, expected", [(0, 1), (1, 2), (2, 3), (8, 4)])
    def test_a_refit_after_skipped_frames_fits_at_most_catch_up_pairs_of_theirs(self, catch_up_pairs, expected):
        front_end = MotionFrontEnd(MotionFrontEndConfig(dense=False, catch_up_pairs=catch_up_pairs))
        observations = [front_end.observe(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)) for frame in textured_frames(6)]
        front_end.refit(observations[0])
        front_end.refit(observations[-1])  # frames 2-4 had pairs and were skipped
        assert len(front_end.evidence.tracks._pairs) == expected
        with_own = self._pairs(1, catch_up_pairs)[0]  # refitting every frame, nothing is skipped
        assert len(with_own) == MotionFrontEndConfig().window_length - MotionFrontEndConfig().track_motion.gap

    def test_an_observation_whose_window_holds_only_its_pair_fits_only_that_pair(self):
        front_end = MotionFrontEnd(MotionFrontEndConfig(dense=False, catch_up_pairs=8))
        observations = [front_end.observe(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)) for frame in textured_frames(6)]
        last = observations[-1]
        front_end.refit(replace(last, window=last.window[-1 - last.gap:]))
        assert len(front_end.evidence.tracks._pairs) == 1


class TestDenseCheirality:
    """The refit's dense mask holds the body of an object the camera pans after (zero flow: no residual)."""

    @staticmethod
    def _refit(degrees: float, share: float = TrackMotionConfig().behind_share):
        backward, is_car, K = pan_follow_flow(degrees=degrees)
        forward = -backward  # smooth flows: consistent enough for the forward-backward check
        gray = np.random.default_rng(0).integers(0, 255, is_car.shape).astype(np.uint8)
        config = MotionFrontEndConfig(dense_width=is_car.shape[1],
                                      track_motion=TrackMotionConfig(behind_share=share))
        observation = Observation(1, K, (backward, forward), gray, is_car.shape)
        return MotionFrontEnd(config).refit(observation).dense, is_car

    def test_the_followed_body_is_in_the_dense_mask(self):
        dense, is_car = self._refit(0.5)
        assert dense[is_car].mean() > 0.9 and dense[~is_car].mean() < 0.02

    def test_a_pair_turning_more_than_a_degree_keeps_the_followed_body(self):
        """The pair's K is camera_info's: the front-end guards every K against a misjudged rotation."""
        dense, is_car = self._refit(2.0)  # still in the image: behind by all of the rotation
        assert dense[is_car].mean() > 0.9 and dense[~is_car].mean() < 0.02
        dense, is_car = self._refit(2.0, share=np.inf)  # such pairs unsigned
        assert dense[is_car].mean() < 0.1


class TestDenseCheiralityAnchor:
    """A smooth region behind infinity counts only where it reaches pixels whose flow is reliable: a followed
    car's smooth body, filled from its textured rim, is in the dense mask; a patch of the same flow in the middle
    of a blank sky, farther than ``texture_reach`` from any texture (DIS's flow there is interpolation), is not."""

    @staticmethod
    def _refit(**settings):
        backward, is_car, K = pan_follow_flow(degrees=0.5)
        gray = np.random.default_rng(0).integers(0, 255, is_car.shape).astype(np.uint8)
        body = np.zeros_like(is_car)
        body[53:87, 133:197] = True  # the car's smooth body inside a 3-pixel textured rim
        gray[body] = 100
        sky = np.zeros_like(is_car)
        sky[5:115, 215:315] = True
        gray[sky] = 200
        patch = np.zeros_like(is_car)
        patch[40:80, 245:285] = True  # 30 px or more from the sky's edge: beyond the reach
        backward[patch] = 0.0
        config = MotionFrontEndConfig(dense_width=is_car.shape[1], **settings)
        observation = Observation(1, K, (backward, -backward), gray, is_car.shape)
        return MotionFrontEnd(config).refit(observation).dense, is_car, patch

    def test_the_followed_smooth_body_is_in_and_the_sky_patch_is_not(self):
        dense, is_car, patch = self._refit()
        assert dense[is_car].mean() > 0.9 and dense[patch].mean() < 0.05

    def test_without_the_texture_check_the_sky_patch_is_in(self):
        dense, is_car, patch = self._refit(min_texture=0.0)
        assert dense[is_car].mean() > 0.9 and dense[patch].mean() > 0.9


@pytest.mark.parametrize("seed", [0, 1])
def test_the_front_end_coasts_a_passing_car_whose_evidence_drops_out(seed):
    """The synthetic oncoming car as it passes the camera (frames 13-15): its tracks die of its growth and its flow
    fails the forward-backward check; coasting keeps it in every one of those frames (in seed 1, at frame 15, only
    with the dense flow's move: its last similarity takes it off the image)."""
    sequence = render_sequence("oncoming", seed=seed, n_frames=16, width=621, height=188)
    car = next(obj for obj, name in sequence.object_names.items() if name.startswith("car_oncoming"))

    def covered(config: MotionFrontEndConfig) -> list[float]:
        front_end, shares = MotionFrontEnd(config, DenseFlow("balanced")), []
        for frame in sequence.frames:
            labels = front_end.update(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY))
            truth = frame.instances == car
            shares.append(float((labels[truth] > 0).mean()))
        return shares

    coasting, without = covered(MotionFrontEndConfig()), covered(MotionFrontEndConfig(coast_frames=0))
    assert min(coasting[13:]) > 0.4 and min(without[13:]) < 0.1, (coasting[13:], without[13:])


class TestDenseFooting:
    """The refit's dense mask holds a car that drives towards the camera, which only the footing test sees."""

    @staticmethod
    def _refit(dense_footing: bool = True, oncoming: bool = True, smooth_car: bool = False, **settings):
        backward, is_parked, is_oncoming, K = oncoming_street_flow(oncoming=oncoming)
        gray = np.random.default_rng(0).integers(0, 255, is_parked.shape).astype(np.uint8)
        if smooth_car:
            gray[is_oncoming] = 90
        config = MotionFrontEndConfig(dense_width=is_parked.shape[1], dense_footing=dense_footing, **settings)
        observation = Observation(1, K, (backward, -backward), gray, is_parked.shape)
        return MotionFrontEnd(config).refit(observation).dense, is_parked, is_oncoming

    def test_the_oncoming_car_is_in_the_dense_mask_and_the_parked_one_is_not(self):
        dense, is_parked, is_oncoming = self._refit()
        # Its columns next to the focus of expansion have too little parallax to decide (``ground_min_px``).
        assert dense[is_oncoming].mean() > 0.5 and not dense[is_parked].any() and dense.mean() < 0.05

    def test_without_it_the_oncoming_car_is_not(self):
        dense, _, is_oncoming = self._refit(dense_footing=False)
        assert dense[is_oncoming].mean() < 0.05

    def test_a_parked_car_in_its_place_is_not(self):
        dense, _, is_oncoming = self._refit(oncoming=False)
        assert dense[is_oncoming].mean() < 0.05

    def test_only_where_the_flow_is_reliable(self):
        """A smooth car whose flow is too long to trust away from texture (``smooth_max_flow``; the panes of near
        parked cars' windows on KITTI 07) is left out, as the residual test leaves it out; textured, or with the
        texture check off, it is in."""
        untrusted = {"smooth_max_flow": 0.1, "texture_reach": 2}
        dense, _, is_oncoming = self._refit(smooth_car=True, **untrusted)
        assert dense[is_oncoming].mean() < 0.25  # its rim: the 5x5 texture window reaches the road
        dense, _, is_oncoming = self._refit(**untrusted)
        assert dense[is_oncoming].mean() > 0.5
        dense, _, is_oncoming = self._refit(smooth_car=True, min_texture=0.0, **untrusted)
        assert dense[is_oncoming].mean() > 0.5


def test_the_far_oncoming_car_is_flagged_from_its_first_frames(monkeypatch):
    """The synthetic oncoming car of seed 1 while it is far (frames 3-7): its footing lies near the horizon, where
    nothing static overhangs the road under it by more than a sliver of its depth, so the footing's allowance
    (``footing_allowance``) is the road's tolerance and little more, and the dense test's least excess is a fifth of
    a pixel; a flat allowance of 1.4 and a quarter of a pixel (before) left it unflagged in frames 3-4 and at 0.43
    of it in frame 7."""
    import moseg_ros.methods.moving_objects as moving_objects
    from moseg_ros.pipeline import Pipeline, PipelineConfig

    sequence = render_sequence("oncoming", seed=1, n_frames=16, width=621, height=188)
    car = next(obj for obj, name in sequence.object_names.items() if name.startswith("car_oncoming"))

    def covered() -> list[float]:
        with Pipeline(PipelineConfig()) as pipeline:
            masks = [pipeline.process(frame.rgb, frame.stamp_ns).masks.dynamic for frame in sequence.frames[:8]]
        return [float((mask > 0)[frame.instances == car].mean()) for mask, frame in zip(masks, sequence.frames)]

    allowed = covered()
    default = moving_objects.front_end_config
    flat = TrackMotionConfig(footing_margin=0.4, footing_overhang=0.0)
    monkeypatch.setattr(moving_objects, "front_end_config",
                        lambda config: replace(default(config), track_motion=flat, dense_footing_px=0.25))
    before = covered()
    assert min(allowed[3:5]) > 0.6 and min(allowed[5:8]) > 0.8, allowed
    assert max(before[3:5]) < 0.05 and before[7] < 0.5, before


def test_the_pairs_are_fitted_with_the_settings_for_the_tracking_width(monkeypatch):
    import moseg_ros.frontend.track_evidence as motion

    widths = []
    fit = motion.pair_evidence

    def recorded(x1, x2, config, *args, **kwargs):
        widths.append(config.shortfall_strong_px)
        return fit(x1, x2, config, *args, **kwargs)

    monkeypatch.setattr(motion, "pair_evidence", recorded)
    front_end = MotionFrontEnd()
    for frame in textured_frames(4):  # 621 px wide: half of KITTI's
        front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
    assert widths and set(widths) == {TrackMotionConfig().shortfall_strong_px * 621 / 1242}


class TestDepthEvidence:
    """``MotionFrontEnd.depth()``: the pixels whose evidence came from the depth tests (object_fusion's exemption)."""

    def test_the_far_oncoming_car_is_depth_evidence_and_little_else(self):
        sequence = render_sequence("oncoming", seed=1, n_frames=8, width=621, height=188)
        car = next(obj for obj, name in sequence.object_names.items() if name.startswith("car_oncoming"))
        front_end = MotionFrontEnd()
        on_car, off_car = [], []
        for frame in sequence.frames:
            front_end.update(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY))
            assert front_end.depth().shape == frame.instances.shape
            on_car.append(int((front_end.depth() & (frame.instances == car)).sum()))
            off_car.append(int((front_end.depth() & (frame.instances != car)).sum()))
        assert min(on_car[2:5]) > 200, on_car
        assert sum(off_car) < 0.1 * sum(on_car), off_car

    def test_the_sliding_blocks_evidence_is_its_epipolar_distance_not_depth(self):
        front_end = MotionFrontEnd()
        for frame in textured_frames(8):
            labels = front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
        assert (labels > 0).sum() > 3000 and not front_end.depth().any()

    def test_the_window_frame_is_the_regions_with_the_flow_back_and_the_tracks_at_the_dense_size(self):
        front_end = MotionFrontEnd(MotionFrontEndConfig(dense_width=320))
        frames = textured_frames(3)
        for frame in frames:
            labels = front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
        window_frame = front_end.window_frame(labels)
        assert window_frame.labels is labels and window_frame.flow.shape == (*labels.shape, 2)
        assert window_frame.track_points.shape == (window_frame.track_ids.size, 2)
        assert window_frame.track_points[:, 0].max() < labels.shape[1]


class TestAwayFromBorder:
    def test_shape_and_known_values(self):
        points = np.array([[5.0, 5.0], [2.0, 10.0], [17.0, 10.0], [10.0, 2.9], [10.0, 17.0]])
        inside = away_from_border(points, (20, 20), 3.0)  # x and y must lie in [3, 16]
        assert inside.shape == (5,) and inside.dtype == bool
        assert inside.tolist() == [True, False, False, False, False]

    def test_no_margin_keeps_the_image(self):
        points = np.array([[0.0, 0.0], [19.0, 9.0], [20.0, 5.0]])
        assert away_from_border(points, (10, 20), 0.0).tolist() == [True, True, False]


class TestTrackBorder:
    """Flagged tracks near the image's border are not drawn; the same block inside is."""

    @staticmethod
    def _moving_tracks(track_border: float, x: int) -> int:
        front_end = MotionFrontEnd(MotionFrontEndConfig(dense=False, track_border=track_border))
        for frame in textured_frames(6, height=400, block_x=x):
            front_end.update(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))
        return len(front_end.moving_track_points)

    def test_a_block_at_the_left_border_is_drawn_only_without_the_band(self):
        # The block is 77 px wide at the left edge; a band of 13 % of the width (80 px) holds all of it.
        assert self._moving_tracks(0.0, 0) > 10 and self._moving_tracks(0.13, 0) == 0
        assert self._moving_tracks(0.13, 621 // 4) > 10  # away from the border it is drawn


class TestDenseHysteresis:
    """Of the last refit's dense mask, the regions that touch this refit's are kept: a mover whose residual
    falls under the threshold over most of its body for a frame stays whole, a lone blob is not repeated."""

    @staticmethod
    def _two_refits(hysteresis: bool):
        backward, _, K = pan_follow_flow(degrees=0.5)
        gray = np.random.default_rng(0).integers(0, 255, backward.shape[:2]).astype(np.uint8)
        body = np.zeros(backward.shape[:2], bool)
        body[60:100, 20:100] = True  # away from the followed car that pan_follow_flow holds
        blob = np.zeros_like(body)
        blob[25:45, 230:260] = True
        front_end = MotionFrontEnd(MotionFrontEndConfig(dense_width=backward.shape[1],
                                                        dense_hysteresis=hysteresis))
        masks = []
        for index, moving in ((1, body | blob), (2, np.zeros_like(body))):
            flow = backward.copy()
            flow[moving, 1] += 3.0  # off the epipolar lines: the residual test flags these pixels
            if index == 2:
                flow[75:85, 50:70, 1] += 3.0  # a part of the body only
            observation = Observation(index, K, (flow, -flow), gray, body.shape, backward=((index, flow),))
            masks.append(front_end.refit(observation).dense)
        return masks, body, blob

    def test_the_body_is_kept_and_the_blob_is_not(self):
        (first, second), body, blob = self._two_refits(True)
        assert first[body].mean() > 0.6 and first[blob].mean() > 0.6
        assert second[body].mean() > 0.7 and not second[blob].any()  # the body as the first refit had it

    def test_without_it_only_this_refits_evidence(self):
        (_, second), body, _ = self._two_refits(False)
        assert second[body].mean() < 0.1


class TestBorder:
    """Matches that land near the earlier frame's border are no evidence (DIS extrapolates there; KITTI 07's
    corner flagged the band entering the view in a turn), and the rest of the frame is decided as before."""

    @staticmethod
    def _refit(border_fraction: float):
        backward, is_car, K = pan_follow_flow(degrees=2.0)
        w = backward.shape[1]
        landing = np.arange(w) + backward[..., 0]
        near_border = (landing < 0.05 * w) | (landing > 0.95 * (w - 1))  # within 5 % of the earlier frame's sides
        backward[near_border & ~is_car, 1] += 3.0  # a wrong match, off its epipolar line
        gray = np.random.default_rng(0).integers(0, 255, is_car.shape).astype(np.uint8)
        base = MotionFrontEndConfig(dense_width=w)
        config = replace(base, dense_baseline=replace(base.dense_baseline, border_fraction=border_fraction))
        observation = Observation(1, K, (backward, -backward), gray, is_car.shape)
        return MotionFrontEnd(config).refit(observation).dense, near_border, is_car

    def test_the_default_leaves_the_band_out_and_keeps_the_mover(self):
        dense, near_border, is_car = self._refit(MotionFrontEndConfig().dense_baseline.border_fraction)
        assert near_border.mean() > 0.03 and not dense[near_border].any()
        assert dense[is_car].mean() > 0.9

    def test_without_it_the_wrong_matches_are_flagged(self):
        dense, near_border, _ = self._refit(0.0)
        assert dense[near_border].mean() > 0.3


class TestTextureReach:
    """The dense residual counts where DIS can see texture within ``texture_reach`` pixels and the flow is
    small: the smooth body of a mover (its flow comes from its edges), not the middle of a wide blank area,
    nor a smooth area moving fast (DIS does not carry a large motion into it)."""

    @staticmethod
    def _refit(reach: int, body_step: float = 3.0):
        h, w = 160, 320
        gray = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (h, w)).astype(np.uint8), (3, 3), 0)
        backward = np.zeros((h, w, 2), np.float32)
        backward[..., 0] = 2.0  # the camera pans: every pixel came from 2 px to the right
        body = np.zeros((h, w), bool)
        body[40:80, 40:80] = True  # a smooth object moving down
        blank = np.zeros((h, w), bool)
        blank[20:140, 160:300] = True  # a blank wall whose flow DIS extrapolates wrongly
        for region, step in ((body, body_step), (blank, 3.0)):
            gray[region] = 128
            backward[region] = (0.0, -step)
        config = MotionFrontEndConfig(dense_width=w, dense_cheir_px=0.0, texture_reach=reach)
        observation = Observation(1, guessed_camera_matrix((h, w)), (backward, -backward), gray, (h, w))
        return MotionFrontEnd(config).refit(observation).dense, body, blank

    def test_the_smooth_body_is_filled_from_its_edges(self):
        dense, body, _ = self._refit(12)
        assert dense[body].mean() > 0.75
        narrow, _, _ = self._refit(0)
        assert narrow[body].mean() < 0.3

    def test_the_middle_of_a_wide_blank_area_stays_out(self):
        dense, _, blank = self._refit(12)
        middle = np.zeros_like(blank)
        middle[40:120, 180:280] = True  # farther than the reach from any texture
        assert not dense[middle].any() and dense[blank & ~middle].mean() > 0.3

    def test_a_smooth_area_moving_fast_is_not_filled(self):
        fast, body, _ = self._refit(12, body_step=MotionFrontEndConfig().smooth_max_flow + 4.0)
        assert fast[body].mean() < 0.3


def far_followed_car(frames: int = 8, seed: int = 0):
    """Track positions of a camera 1.5 m above a road driving 1 m a frame between two walls (x = +-6 m),
    following a car 1 m wide 30 m ahead at its own speed, at the focus of expansion: over two frames the road
    under the car moves about half a pixel, over seven about two and a half. Returns points (F, N, 2),
    is_car (N,) and K (640x240 image)."""
    K = np.array([[500.0, 0, 320], [0, 500, 120], [0, 0, 1]])
    rng = np.random.default_rng(seed)
    road = np.column_stack([rng.uniform(-6, 6, 600), np.full(600, 1.5), rng.uniform(8, 60, 600)])
    road = road[~((np.abs(road[:, 0]) < 0.8) & (road[:, 2] > 29))]  # hidden by the car
    walls = np.column_stack([rng.choice([-6.0, 6.0], 300), rng.uniform(-3, 1.5, 300), rng.uniform(10, 60, 300)])
    car = np.column_stack([rng.uniform(-0.5, 0.5, 40), rng.uniform(0.3, 1.5, 40), np.full(40, 30.0)])
    points = []
    for t in range(frames):
        world = np.vstack([road, walls]) - [0.0, 0.0, float(t)]
        seen = np.vstack([world, car]) @ K.T
        points.append(seen[:, :2] / seen[:, 2:] + rng.normal(0, 0.1, (len(seen), 2)))
    is_car = np.r_[np.zeros(len(road) + len(walls), bool), np.ones(40, bool)]
    return np.stack(points).astype(np.float32), is_car, K


def _refit_stream(points: np.ndarray, K: np.ndarray, long_pairs: bool) -> np.ndarray:
    """Ids the front-end's refit flags at the last of ``points``' frames (fed as observations, no dense
    flow); ``long_pairs`` False hides the window's first-to-last pair."""
    front_end = MotionFrontEnd(MotionFrontEndConfig(window_length=len(points), dense=False))
    ids = np.arange(points.shape[1])
    flagged = np.zeros(0, np.int64)
    for t in range(2, len(points)):
        first = 0 if long_pairs and t == len(points) - 1 else t - 2
        window = tuple((ids, points[k]) for k in range(first, t + 1))
        observation = Observation(t, K, None, np.zeros((240, 640), np.uint8), (240, 640), window)
        flagged = front_end.refit(observation).flagged
    return flagged


def test_the_window_s_long_pair_decides_a_followed_car_at_the_focus_of_expansion():
    points, is_car, K = far_followed_car()
    short_only = np.isin(np.arange(len(is_car)), _refit_stream(points, K, long_pairs=False))
    # Only where the car is widest and lowest does the road under it move a pixel in two frames (0.40).
    assert short_only[is_car].mean() < 0.5
    flagged = np.isin(np.arange(len(is_car)), _refit_stream(points, K, long_pairs=True))
    assert flagged[is_car].mean() > short_only[is_car].mean() + 0.25  # 0.75
    assert flagged[~is_car].mean() < 0.01


class TestDenseNear:
    def test_shape_and_known_values(self):
        residual = np.zeros((20, 30), dtype=np.float32)
        residual[10, 10] = 2.0
        residual[10, 12] = 1.0
        points = np.array([[10, 10], [12, 11], [14, 10], [25, 5], [-4, 10]], dtype=np.float32)
        near = dense_near(points, residual, reach=2)
        assert near.shape == (5,) and near.tolist() == [2.0, 2.0, 1.0, 0.0, 0.0]

    def test_no_reach_reads_the_pixel(self):
        residual = np.zeros((20, 30), dtype=np.float32)
        residual[10, 10] = 2.0
        assert dense_near(np.array([[10, 10], [11, 10]], np.float32), residual, reach=0).tolist() == [2.0, 0.0]


class TestDenseCorroboration:
    """A track's epipolar distance counts where the dense residual near it agrees: KLT drifting at a near edge
    (a tree trunk against the far street) is let go; a mover that the dense flow sees too is kept."""

    SIZE = (240, 640)
    CENTRE = np.array([320.0, 120.0])

    @classmethod
    def _scale(cls, xy: np.ndarray) -> np.ndarray:
        """Per-point expansion of a camera driving forward over a scene whose depth varies smoothly."""
        return 0.02 + 0.03 * xy[..., 1] / cls.SIZE[0] + 0.01 * np.sin(xy[..., 0] / 50.0)

    @classmethod
    def _across(cls, xy: np.ndarray) -> np.ndarray:
        """Unit vectors across the epipolar lines (perpendicular to the radial flow) at ``xy``."""
        radial = xy - cls.CENTRE
        radial /= np.maximum(np.linalg.norm(radial, axis=-1, keepdims=True), 1e-9)
        return np.stack([-radial[..., 1], radial[..., 0]], axis=-1)

    @classmethod
    def _refit(cls, corroboration: float, dense_offset: float = 1.5, floor: float = 0.25, allowance: float = 0.0):
        h, w = cls.SIZE
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        grid = np.stack([xx, yy], axis=-1)
        backward = -(grid - cls.CENTRE) * cls._scale(grid)[..., None]  # now -> the frame before
        mover = (np.abs(xx - 150) < 30) & (np.abs(yy - 170) < 30)
        backward[mover] += dense_offset * cls._across(grid[mover])
        rng = np.random.default_rng(0)
        static = rng.uniform([20, 20], [w - 20, h - 20], (600, 2))
        static = static[~((np.abs(static[:, 0] - 150) < 40) & (np.abs(static[:, 1] - 170) < 40))]
        drifting = rng.uniform([430, 40], [470, 200], (40, 2))
        on_mover = rng.uniform([125, 145], [175, 195], (40, 2))
        now = np.vstack([static, drifting, on_mover])
        before = now - 2.0 * (now - cls.CENTRE) * cls._scale(now)[:, None]  # two frames back
        drift, moving = slice(len(static), len(static) + len(drifting)), slice(len(static) + len(drifting), None)
        before[drift] += 2.0 * cls._across(now[drift])  # KLT drifting at a near edge: the dense flow does not
        before[moving] += 2.5 * cls._across(now[moving])
        ids = np.arange(len(now))
        base = MotionFrontEndConfig(dense_width=w, corroboration_floor=floor, dense_allowance=allowance)
        # No epipole or dense allowance (but in the allowance's own test) and no ground tests (this flow has no
        # ground: points below the epipole lie at any depth): the drift is also a small share of these near tracks'
        # displacement, and this class is about the corroboration alone.
        config = replace(base, track_motion=replace(base.track_motion, ground_ratio=0.0, footing_px=np.inf,
                                                    shortfall_px=np.inf, shortfall_strong_px=0.0,
                                                    corroboration=corroboration, epipole_allowance=0.0))
        K = np.array([[500.0, 0, 320], [0, 500, 120], [0, 0, 1]])
        gray = rng.integers(0, 255, cls.SIZE).astype(np.uint8)
        window = tuple((ids, points.astype(np.float32)) for points in (before, (before + now) / 2, now))
        observation = Observation(2, K, (backward.astype(np.float32), -backward.astype(np.float32)), gray, cls.SIZE,
                                  window)
        front_end = MotionFrontEnd(config)
        # The dense residual that corroborates a track test is the refit's before (the same flow here).
        front_end.refit(replace(observation, index=1, window=window[:2]))
        flagged = np.isin(ids, front_end.refit(observation).flagged)
        return flagged[:len(static)], flagged[drift], flagged[moving]

    def test_the_drifting_tracks_are_let_go_and_the_mover_is_kept(self):
        static, drifting, mover = self._refit(TrackMotionConfig().corroboration)
        assert not drifting.any()
        assert mover.mean() > 0.9 and static.mean() < 0.01

    def test_a_mover_whose_dense_residual_is_a_fraction_of_its_tracks_is_kept_by_the_floor(self):
        """0.4 px a frame against its tracks' 2.5 px over two: below three quarters of them, above a quarter of
        the dense threshold (1 px)."""
        _, drifting, mover = self._refit(TrackMotionConfig().corroboration, dense_offset=0.4)
        assert mover.mean() > 0.9 and not drifting.any()
        _, _, mover = self._refit(TrackMotionConfig().corroboration, dense_offset=0.4, floor=np.inf)
        assert not mover.any()

    def test_the_dense_residual_counts_only_beyond_the_dense_allowance(self):
        """The mover's 0.4 px a frame across its 7-8 px of flow is within 0.06 of it: as the dense mask would not
        see it, it corroborates nothing (the floor or not), and its tracks are doubted."""
        _, _, mover = self._refit(TrackMotionConfig().corroboration, dense_offset=0.4, allowance=0.06)
        assert not mover.any()
        _, _, mover = self._refit(TrackMotionConfig().corroboration, dense_offset=1.5, allowance=0.06)
        assert mover.mean() > 0.9

    def test_without_it_the_drifting_tracks_are_flagged(self):
        static, drifting, mover = self._refit(0.0)
        assert drifting.mean() > 0.9 and mover.mean() > 0.9 and static.mean() < 0.01


class TestMeasurable:
    """The ground's shortfall test takes only tracks whose image shows motion along their parallax: not the
    ones on an edge that runs towards the principal point (a kerb at the horizon)."""

    @staticmethod
    def _measurable(share: float):
        h, w = 120, 320
        gray = np.zeros((h, w), dtype=np.uint8)
        gray[60:, :160] = 200  # a horizontal edge on the principal row, left of the centre
        gray[20:40, 220:240] = 200  # a bright square whose corners show motion every way
        now = np.array([[60.0, 60.0], [100.0, 60.0], [220.0, 20.0], [239.0, 39.0]], dtype=np.float32)
        ids = np.arange(4)
        K = np.array([[300.0, 0, 160], [0, 300, 60], [0, 0, 1]])
        observation = Observation(2, K, None, gray, (h, w), ((ids, now),) * 3)
        config = MotionFrontEndConfig(dense_width=w, aperture_share=share)
        among = np.array([True, True, True, False, True, True])
        return MotionFrontEnd(config).evidence.tracks._measurable(np.arange(6), observation, among)

    def test_the_edge_along_the_parallax_is_not_measurable_and_the_corners_are(self):
        # Id 3 is on a corner but not asked about; ids 4 and 5 are not seen now: nothing to measure them by.
        assert self._measurable(0.25).tolist() == [False, False, True, False, False, False]

    def test_off_without_a_share(self):
        assert self._measurable(0.0) is None
