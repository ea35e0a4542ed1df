"""Weight-free region proposals and the tracker that keeps their ids over time."""

from __future__ import annotations

import numpy as np

from moseg_ros.frontend.instances import InstanceTracker, compact_ids, mask_iou_matrix, propose_regions


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
