"""The front-end's memory (frontend/memory.py): masks carried along the flow, remembered evidence, coasting."""

from __future__ import annotations

import cv2
import numpy as np

from conftest import textured_frames
from moseg_ros.frontend.memory import NO_EVIDENCE, Coast, carried, coasted, remembered
from moseg_ros.frontend.motion import MotionFrontEnd
from moseg_ros.frontend.motion_config import MotionFrontEndConfig


class TestCarried:
    def test_a_mask_follows_the_flows_after_its_frame(self):
        mask = np.zeros((30, 40), bool)
        mask[10:20, 10:20] = True
        step = np.zeros((30, 40, 2), np.float32)
        step[..., 0] = -3.0  # each frame's pixel came from 3 px to the left: content moves right
        moved = carried(mask, 4, ((4, step), (5, step), (6, step)))  # frame 4's own flow is not applied
        assert moved.shape == mask.shape and moved.dtype == bool
        assert moved[10:20, 16:26].all() and moved.sum() == mask.sum()

    def test_no_later_flow_leaves_it_as_it_is(self):
        mask = np.eye(8, dtype=bool)
        assert np.array_equal(carried(mask, 3, ((2, np.ones((8, 8, 2), np.float32)),)), mask)

    def test_a_refit_applied_frame_after_frame_is_carried_as_from_its_own_frame(self):
        """The front-end carries the last frame's carried mask one flow on; applying the refit only at the last
        frame warps it from its own frame: both give the same mask (no memory, so nothing else differs)."""
        frames = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in textured_frames(8)]

        def moving_at_the_end(every_frame: bool) -> np.ndarray:
            front_end = MotionFrontEnd(MotionFrontEndConfig(memory_frames=0))
            refit = None
            for i, frame in enumerate(frames):
                observation = front_end.observe(frame)
                if i == 3:
                    refit = front_end.refit(observation)
                    assert refit.dense is not None and refit.dense.any()
                if refit is not None and (every_frame or i == len(frames) - 1):
                    front_end.apply(refit)
            return front_end.moving

        stepwise = moving_at_the_end(True)
        assert stepwise.any() and np.array_equal(stepwise, moving_at_the_end(False))


class TestRemembered:
    """The moving evidence of the frames before, carried along the flow while fresh evidence drops out."""

    SHAPE = (40, 60)

    @classmethod
    def _block(cls, x0: int) -> np.ndarray:
        mask = np.zeros(cls.SHAPE, dtype=bool)
        mask[10:20, x0:x0 + 10] = True
        return mask

    @classmethod
    def _shift(cls, dx: float) -> np.ndarray:
        """The backward flow (this frame -> the one before) of an image moved ``dx`` px right since then."""
        flow = np.zeros((*cls.SHAPE, 2), dtype=np.float32)
        flow[..., 0] = -dx
        return flow

    def test_shape_dtype_and_fresh_evidence_is_age_zero(self):
        age = remembered(self._block(5), None, None, np.zeros((0, 2)), 1, 3)
        assert age.shape == self.SHAPE and age.dtype == np.uint8
        assert (age[self._block(5)] == 0).all() and (age[~self._block(5)] == NO_EVIDENCE).all()

    def test_a_region_that_drops_out_is_carried_along_the_flow_for_the_frames_asked(self):
        first = remembered(self._block(5), None, None, np.zeros((0, 2)), 2, 3)
        nothing = np.zeros(self.SHAPE, dtype=bool)
        second = remembered(nothing, first, self._shift(4), np.zeros((0, 2)), 2, 3)
        assert (second[self._block(9)] == 1).all() and (second[~self._block(9)] == NO_EVIDENCE).all()
        third = remembered(nothing, second, self._shift(4), np.zeros((0, 2)), 2, 3)
        assert (third[self._block(13)] == 2).all()
        assert (remembered(nothing, third, self._shift(4), np.zeros((0, 2)), 2, 3) == NO_EVIDENCE).all()

    def test_fresh_evidence_restarts_the_age_and_no_memory_keeps_only_it(self):
        first = remembered(self._block(5), None, None, np.zeros((0, 2)), 1, 3)
        second = remembered(self._block(9), first, self._shift(4), np.zeros((0, 2)), 1, 3)
        assert (second[self._block(9)] == 0).all()
        off = remembered(np.zeros(self.SHAPE, dtype=bool), first, self._shift(4), np.zeros((0, 2)), 0, 3)
        assert (off == NO_EVIDENCE).all()

    def test_static_tracks_inside_stop_what_is_carried(self):
        first = remembered(self._block(5), None, None, np.zeros((0, 2)), 1, 3)
        nothing = np.zeros(self.SHAPE, dtype=bool)
        static = np.array([[10.0, 12.0], [12.0, 15.0], [15.0, 18.0]])  # inside the carried block at x 9-18
        assert (remembered(nothing, first, self._shift(4), static, 1, 3) == NO_EVIDENCE).all()
        assert (remembered(nothing, first, self._shift(4), static[:2], 1, 3)[self._block(9)] == 1).all()
        assert (remembered(nothing, first, self._shift(4), static, 1, 0)[self._block(9)] == 1).all()

    def test_the_front_end_forgets_it_on_reset(self):
        front_end = MotionFrontEnd(MotionFrontEndConfig(memory_frames=1))
        front_end.regions._memory = (0, np.zeros(self.SHAPE, dtype=np.uint8))
        front_end.reset()
        assert front_end.regions._memory is None


class TestCoasted:
    """Lasting regions whose evidence drops out, carried by their tracks' similarity for a few frames."""

    SHAPE = (60, 80)

    @classmethod
    def _block(cls, x0: int, y0: int = 20, size: int = 10) -> np.ndarray:
        mask = np.zeros(cls.SHAPE, dtype=bool)
        mask[y0:y0 + size, x0:x0 + size] = True
        return mask

    @classmethod
    def _tracks_on(cls, x0: int, y0: int = 20, size: int = 10) -> np.ndarray:
        return np.array([[x0 + dx, y0 + dy] for dx in (2, 5, 8) for dy in (2, 5, 8)], dtype=np.float32)

    def _coast(self, moving, lasting, before, now, settled=np.zeros((0, 2)), frames=4, labels=None, evidence=None,
               flow=None):
        labels = self._block(10).astype(np.int32) * 7 if labels is None else labels
        evidence = labels > 0 if evidence is None else evidence
        return coasted(moving, labels, evidence, lasting, before, now, settled, frames, 4, 0.7, 3, flow)

    @classmethod
    def _flow_by(cls, dx: float, dy: float) -> np.ndarray:
        """The backward flow (this frame -> the one before) of everything moving by (dx, dy)."""
        return np.broadcast_to(np.array([-dx, -dy], dtype=np.float32), (*cls.SHAPE, 2)).copy()

    def test_shape_and_dtype(self):
        nothing = np.zeros(self.SHAPE, dtype=bool)
        out, coasts = self._coast(nothing, {}, self._tracks_on(10), self._tracks_on(10))
        assert out.shape == self.SHAPE and out.dtype == bool and not out.any() and coasts == {}

    def test_a_region_whose_evidence_drops_out_is_drawn_where_its_tracks_went(self):
        nothing = np.zeros(self.SHAPE, dtype=bool)
        out, coasts = self._coast(nothing, {7: Coast()}, self._tracks_on(10), self._tracks_on(10) + [6, 3])
        np.testing.assert_array_equal(out, self._block(16, 23))
        assert coasts[7].frames == 1
        np.testing.assert_allclose(coasts[7].motion, [[1, 0, 6], [0, 1, 3]], atol=1e-6)

    def test_a_looming_region_grows_with_its_tracks(self):
        before = self._tracks_on(10)
        centre = before.mean(axis=0)
        out, _ = self._coast(np.zeros(self.SHAPE, dtype=bool), {7: Coast()}, before, centre + 1.5 * (before - centre))
        assert 1.8 < out.sum() / 100 < 2.7 and out[self._block(10)].all()

    def test_without_tracks_it_moves_as_it_moved_last(self):
        last = np.array([[1, 0, 5], [0, 1, 0]], dtype=np.float64)
        nothing = np.zeros(self.SHAPE, dtype=bool)
        out, coasts = self._coast(nothing, {7: Coast(1, last)}, np.zeros((0, 2)), np.zeros((0, 2)))
        np.testing.assert_array_equal(out, self._block(15))
        assert coasts[7].frames == 2

    def test_without_tracks_it_also_goes_where_the_dense_flow_takes_it(self):
        # A passing car's side is no similarity, and its growth speeds up: the last similarity alone slides its
        # evidence off the car, the dense flow alone lags behind a looming car (DIS smooths it into the road's).
        last = np.array([[1, 0, 5], [0, 1, 0]], dtype=np.float64)
        nothing = np.zeros(self.SHAPE, dtype=bool)
        out, coasts = self._coast(nothing, {7: Coast(1, last)}, np.zeros((0, 2)), np.zeros((0, 2)),
                                  flow=self._flow_by(0, 3))
        np.testing.assert_array_equal(out, self._block(15) | self._block(10, 23))
        np.testing.assert_array_equal(coasts[7].shape, out)

    def test_with_tracks_to_fit_it_moves_by_their_similarity_alone(self):
        nothing = np.zeros(self.SHAPE, dtype=bool)
        out, _ = self._coast(nothing, {7: Coast()}, self._tracks_on(10), self._tracks_on(10) + [6, 3],
                             flow=self._flow_by(-8, 0))
        np.testing.assert_array_equal(out, self._block(16, 23))

    def test_it_goes_on_from_where_it_went_and_stops_after_the_frames_asked(self):
        nothing = np.zeros(self.SHAPE, dtype=bool)
        step = np.array([[1, 0, 5], [0, 1, 0]], dtype=np.float64)
        coast = Coast(1, step, self._block(15))
        out, coasts = self._coast(nothing, {7: coast}, np.zeros((0, 2)), np.zeros((0, 2)))
        np.testing.assert_array_equal(out, self._block(20))  # from its moved evidence, not the region drawn
        out, coasts = self._coast(nothing, {7: Coast(4, step, self._block(15))}, np.zeros((0, 2)), np.zeros((0, 2)))
        assert not out.any() and coasts[7].frames == 4

    def test_evidence_that_covers_it_stops_the_coasting(self):
        fresh = self._block(16, 23)
        out, coasts = self._coast(fresh, {7: Coast(2, None, None)}, self._tracks_on(10), self._tracks_on(10) + [6, 3])
        np.testing.assert_array_equal(out, fresh)
        assert coasts[7].frames == 0 and coasts[7].shape is None

    def test_static_tracks_inside_veto_it(self):
        settled = self._tracks_on(16, 23)[:3]
        out, coasts = self._coast(np.zeros(self.SHAPE, dtype=bool), {7: Coast()}, self._tracks_on(10),
                                  self._tracks_on(10) + [6, 3], settled)
        assert not out.any() and coasts[7].frames == 0

    def test_only_its_evidence_coasts_and_only_tracks_on_it_move_it(self):
        labels = (self._block(10) | self._block(30)).astype(np.int32) * 7  # drawn wider than its evidence
        on_it = self._tracks_on(10) + [6, 3]
        beside = self._tracks_on(30)  # the background's tracks in the drawn region do not move
        out, _ = self._coast(np.zeros(self.SHAPE, dtype=bool), {7: Coast()},
                             np.concatenate([self._tracks_on(10), self._tracks_on(30)]),
                             np.concatenate([on_it, beside]), labels=labels, evidence=self._block(10))
        np.testing.assert_array_equal(out, self._block(16, 23))
