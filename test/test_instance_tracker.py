"""Weight-free region proposals and the tracker that keeps their ids over time."""

from __future__ import annotations

import numpy as np

from moseg_ros.frontend.instances import (InstanceTracker, compact_ids, kept_apart, mask_iou_matrix, nearest_seed,
                                          propose_regions, same_motion)


def boxes(shape: tuple[int, int], *rects: tuple[int, int, int, int]) -> np.ndarray:
    """Regions 1..R as (y, x, h, w) rectangles."""
    regions = np.zeros(shape, dtype=np.int32)
    for label, (y, x, h, w) in enumerate(rects, start=1):
        regions[y:y + h, x:x + w] = label
    return regions


class TestCompactIds:
    def test_known_values(self):
        ids, compact = compact_ids(np.array([[7, -1], [3, 7]]))
        assert ids.tolist() == [0, 3, 7]
        assert compact.tolist() == [[2, 0], [1, 2]] and compact.dtype == np.int32

    def test_a_map_without_none_numbers_from_one(self):
        ids, compact = compact_ids(np.array([[5, 9]]))
        assert ids.tolist() == [0, 5, 9] and compact.tolist() == [[1, 2]]

    def test_hashed_ids_beyond_the_table_number_the_same(self):
        small = np.array([[7, 0], [3, 7]])
        ids, compact = compact_ids(small * 10_000_019)  # beyond DENSE_IDS: ranked instead of tabled
        assert ids.tolist() == [0, 30_000_057, 70_000_133]
        np.testing.assert_array_equal(compact, compact_ids(small)[1])


class TestMaskIouMatrix:
    def test_known_values(self):
        a = boxes((20, 20), (0, 0, 10, 10), (12, 12, 4, 4))
        b = boxes((20, 20), (0, 5, 10, 10))
        iou = mask_iou_matrix(a, b, 2, 1)
        assert iou.shape == (2, 1)
        np.testing.assert_allclose(iou[:, 0], [50 / 150, 0.0])


class TestProposeRegions:
    def test_small_specks_are_dropped_and_regions_numbered_from_one(self):
        evidence = np.zeros((40, 40), dtype=bool)
        evidence[5:20, 5:20] = True
        evidence[30, 30] = True
        regions = propose_regions(evidence, min_area=50)
        assert set(np.unique(regions)) == {0, 1} and (regions[5:20, 5:20] == 1).sum() > 200


class TestInstanceTracker:
    SHAPE = (60, 80)

    def test_a_moving_region_keeps_its_id(self):
        tracker = InstanceTracker()
        first = tracker.update(boxes(self.SHAPE, (10, 10, 20, 20), (40, 50, 10, 20)))
        # The regions come back in the other order and shifted by 3 px.
        second = tracker.update(boxes(self.SHAPE, (40, 53, 10, 20), (13, 13, 20, 20)))
        assert second[20, 20] == first[20, 20] and second[45, 60] == first[45, 60]
        assert second[20, 20] != second[45, 60]
        assert tracker.ages == {int(first[20, 20]): 2, int(first[45, 60]): 2}

    def test_a_new_region_gets_a_new_id_and_a_gone_one_is_forgotten(self):
        tracker = InstanceTracker()
        first = tracker.update(boxes(self.SHAPE, (10, 10, 20, 20)))
        second = tracker.update(boxes(self.SHAPE, (40, 50, 10, 20)))  # no overlap: another object
        assert second[45, 60] not in (0, first[20, 20])
        assert tracker.ages == {int(second[45, 60]): 1}

    def test_ids_are_never_reused(self):
        tracker = InstanceTracker()
        seen = set()
        for step in range(5):
            labels = tracker.update(boxes(self.SHAPE, (0, 20 * (step % 2), 10, 10)))
            seen.add(int(labels.max()))
        assert len(seen) == 5

    def test_reset_and_size_change_start_over(self):
        tracker = InstanceTracker()
        tracker.update(boxes(self.SHAPE, (10, 10, 20, 20)))
        other = tracker.update(boxes((30, 40), (10, 10, 10, 10)))
        assert other.max() == 2  # no match across sizes: a new id
        tracker.reset()
        assert tracker.update(boxes(self.SHAPE, (10, 10, 20, 20))).max() == 1 and tracker.ages == {1: 1}

    def test_the_flow_keeps_the_id_of_a_region_that_moved_off_its_old_place(self):
        first_frame = boxes(self.SHAPE, (10, 5, 20, 20))
        moved = boxes(self.SHAPE, (10, 35, 20, 20))  # 30 px right: no overlap with where it was
        flow = np.zeros((*self.SHAPE, 2), dtype=np.float32)
        flow[..., 0] = -30  # this frame -> the one before
        tracker = InstanceTracker()
        first = tracker.update(first_frame)
        assert tracker.update(moved, flow)[20, 45] == first[20, 15] and tracker.ages == {int(first[20, 15]): 2}
        blind = InstanceTracker()
        blind.update(first_frame)
        assert blind.update(moved)[20, 45] != first[20, 15]

    def test_nothing_in_nothing_out(self):
        tracker = InstanceTracker()
        labels = tracker.update(np.zeros(self.SHAPE, dtype=np.int32))
        assert labels.shape == self.SHAPE and not labels.any() and tracker.ages == {}


class TestNearestSeed:
    def test_known_values(self):
        seeds = np.zeros((1, 6), dtype=np.int32)
        seeds[0, 0], seeds[0, 5] = 4, 9
        assert nearest_seed(seeds).tolist() == [[4, 4, 4, 9, 9, 9]]

    def test_shape_and_seeds_keep_their_values(self):
        seeds = np.zeros((20, 30), dtype=np.int32)
        seeds[2, 3], seeds[15, 25] = 1, 2
        nearest = nearest_seed(seeds)
        assert nearest.shape == (20, 30) and nearest[2, 3] == 1 and nearest[15, 25] == 2
        assert nearest[0, 0] == 1 and nearest[19, 29] == 2


class TestKeptApart:
    SHAPE = (40, 60)

    def test_a_region_that_took_in_two_is_split_between_them(self):
        before = boxes(self.SHAPE, (10, 5, 20, 20), (10, 35, 20, 20))
        joined = boxes(self.SHAPE, (10, 5, 20, 50))  # the two grew into one
        split = kept_apart(joined, before, np.array([False, True, True]), 0.5)
        assert set(np.unique(split)) == {0, 1, 2}
        assert (split[before == 1] == 1).all() and (split[before == 2] == 2).all()
        assert (split > 0).sum() == (joined > 0).sum()  # the same pixels, only numbered apart
        assert (split[:, :30] != 2).all() and (split[:, 30:] != 1).all()  # each gap pixel to the nearer one

    def test_regions_not_eligible_or_mostly_elsewhere_are_not_kept_apart(self):
        before = boxes(self.SHAPE, (10, 5, 20, 20), (10, 35, 20, 20))
        joined = boxes(self.SHAPE, (10, 5, 20, 50))
        np.testing.assert_array_equal(kept_apart(joined, before, np.array([False, True, False]), 0.5), joined)
        half = boxes(self.SHAPE, (10, 5, 20, 35))  # holds a quarter of the second region only
        np.testing.assert_array_equal(kept_apart(half, before, np.array([False, True, True]), 0.5), half)

    def test_nothing_in_nothing_out(self):
        empty = np.zeros(self.SHAPE, dtype=np.int32)
        assert not kept_apart(empty, empty, np.array([False]), 0.5).any()

    def test_two_parts_that_move_alike_join_and_two_movers_stay_apart(self):
        before = boxes(self.SHAPE, (10, 5, 20, 20), (10, 35, 20, 20))
        joined = boxes(self.SHAPE, (10, 5, 20, 50))
        flow = np.zeros((*self.SHAPE, 2), dtype=np.float32)
        flow[:, :, 0] = -10.0  # one car, its front and back: alike
        flow[:, 30:, 0] = -11.5
        np.testing.assert_array_equal(kept_apart(joined, before, np.array([False, True, True]), 0.5, flow, 0.3),
                                      joined)
        flow[:, 30:, 0] = 4.0  # a cyclist crossing the other way
        split = kept_apart(joined, before, np.array([False, True, True]), 0.5, flow, 0.3)
        assert set(np.unique(split)) == {0, 1, 2}


class TestSameMotion:
    def test_known_values(self):
        flows = np.array([[-10.0, 0.0], [-11.5, 0.5], [4.0, 0.0], [0.2, 0.1], [0.0, 0.0]])
        # 1 px apart at most, or 0.3 of the faster one: the car's parts, the cyclist, two still regions.
        assert same_motion(flows, 0.3).tolist() == [0, 0, 2, 3, 3]

    def test_groups_are_connected_components(self):
        flows = np.array([[10.0, 0.0], [12.5, 0.0], [15.5, 0.0]])  # each alike to the next, not the first to last
        assert same_motion(flows, 0.2).tolist() == [0, 0, 0]
        assert same_motion(flows[:1], 0.2).tolist() == [0]


class TestInstanceTrackerKeepsApart:
    SHAPE = (40, 80)

    def _run(self, tracker):
        """Two boxes 4 px a frame closer for three frames, then joined: the ids of the last frame's two halves."""
        for step in range(3):
            tracker.update(boxes(self.SHAPE, (10, 5 + 4 * step, 20, 20), (10, 50 - 4 * step, 20, 20)))
        before = tracker.update(boxes(self.SHAPE, (10, 17, 20, 20), (10, 38, 20, 20)))
        joined = tracker.update(boxes(self.SHAPE, (10, 19, 20, 42)))
        return before, joined

    def test_two_regions_seen_apart_keep_their_ids_when_they_join(self):
        before, joined = self._run(InstanceTracker(keep_apart_after=3))
        assert joined[20, 22] == before[20, 22] and joined[20, 55] == before[20, 55]
        assert joined[20, 22] != joined[20, 55]

    def test_without_it_the_joined_region_takes_one_id(self):
        _, joined = self._run(InstanceTracker())
        assert joined[20, 22] == joined[20, 55]

    def test_regions_seen_for_fewer_frames_are_joined(self):
        _, joined = self._run(InstanceTracker(keep_apart_after=5))
        assert joined[20, 22] == joined[20, 55]
