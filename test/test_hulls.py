"""Regions from flagged tracks (frontend/regions.py): linked groups, their hulls, connected regions that touch."""

from __future__ import annotations

import numpy as np

from moseg_ros.frontend.hulls import hull_mask, linked_groups, reach_triangles, touching


class TestLinkedGroups:
    def test_groups_of_linked_points_and_minus_one_for_small_ones(self):
        square = np.array([[0, 0], [8, 0], [8, 8], [0, 8]], dtype=np.float32)
        group = linked_groups(np.vstack([square, square + 60, [[100, 10], [104, 12]]]), 12, 4)
        assert group.shape == (10,) and group.dtype == np.int64
        assert len(set(group[:4])) == 1 and len(set(group[4:8])) == 1 and group[0] != group[4]
        assert (group[:8] >= 0).all() and (group[8:] == -1).all()

    def test_fewer_points_than_a_group(self):
        assert (linked_groups(np.zeros((3, 2), np.float32), 5, 4) == -1).all()


class TestHullMask:
    def test_four_corners_fill_their_square(self):
        points = np.array([[10, 10], [30, 10], [30, 30], [10, 30]], dtype=np.float32)
        mask = hull_mask(points, (50, 50), link_px=25, min_group=4)
        assert mask.dtype == bool and mask.shape == (50, 50)
        assert mask[10:31, 10:31].all() and mask.sum() == 21 * 21

    def test_far_groups_stay_apart_and_small_groups_are_dropped(self):
        square = np.array([[0, 0], [8, 0], [8, 8], [0, 8]], dtype=np.float32)
        points = np.vstack([square + 5, square + 60, [[100, 10], [104, 12]]])
        mask = hull_mask(points, (80, 120), link_px=12, min_group=4)
        assert mask[5:14, 5:14].all() and mask[60:69, 60:69].all()
        assert not mask[20:55, 20:55].any() and not mask[:, 90:].any()

    def test_fewer_points_than_a_group_give_an_empty_mask(self):
        assert not hull_mask(np.zeros((3, 2), np.float32), (10, 10), 5, 4).any()

    SQUARE = np.array([[10, 10], [30, 10], [30, 30], [10, 30]], dtype=np.float32)

    def test_a_hull_crowded_by_static_points_is_not_drawn(self):
        static = np.array([[15, 15], [20, 20], [25, 25], [15, 25], [25, 15]], dtype=np.float32)
        assert not hull_mask(self.SQUARE, (50, 50), 25, 4, static, purity=0.5).any()  # 4 of 9 points move
        assert hull_mask(self.SQUARE, (50, 50), 25, 4, static[:4], purity=0.5).sum() == 21 * 21  # 4 of 8
        assert hull_mask(self.SQUARE, (50, 50), 25, 4, static, purity=0.0).sum() == 21 * 21

    def test_static_points_outside_the_hull_do_not_count(self):
        outside = np.array([[40, 40], [5, 45], [45, 5], [2, 2], [35, 20], [20, 35]], dtype=np.float32)
        assert hull_mask(self.SQUARE, (50, 50), 25, 4, outside, purity=0.5).sum() == 21 * 21

    def test_a_hull_on_the_image_border_is_clipped(self):
        points = np.array([[40, 40], [50, 40], [50, 50], [40, 50]], dtype=np.float32)  # x, y = 50: outside
        static = np.array([[45, 45], [49, 49]], dtype=np.float32)
        mask = hull_mask(points, (50, 50), 25, 4, static, purity=0.5)
        assert mask[40:, 40:].all() and mask.sum() == 10 * 10


    # An L of points 10 px apart: the convex hull bridges the bay (x, y in 30..50) that the reach leaves empty.
    ELL = np.array([[x, y] for x in range(10, 51, 10) for y in range(10, 51, 10) if x <= 20 or y <= 20],
                   dtype=np.float32)

    def test_a_reach_leaves_the_bay_of_an_outline_that_the_convex_hull_bridges(self):
        convex = hull_mask(self.ELL, (60, 60), 15, 4)
        reach = hull_mask(self.ELL, (60, 60), 15, 4, reach_px=15)
        ys, xs = np.mgrid[0:60, 0:60]
        bay = (xs >= 27) & (ys >= 27) & (xs + ys <= 65)  # inside the hull's diagonal side, off the L and its corner
        assert convex[bay].all() and not reach[bay].any()
        assert reach[10:51, 10:21].all() and reach[10:21, 10:51].all()

    def test_a_reach_shorter_than_every_side_draws_nothing_and_a_line_its_convex_hull(self):
        assert not hull_mask(self.ELL, (60, 60), 15, 4, reach_px=5).any()
        line = np.array([[10, 10], [20, 10], [30, 10], [40, 10]], dtype=np.float32)
        assert hull_mask(line, (60, 60), 15, 4, reach_px=15).sum() == hull_mask(line, (60, 60), 15, 4).sum() == 31


class TestReachTriangles:
    def test_shape_and_every_triangle_of_a_grid_within_reach(self):
        grid = np.array([[x, y] for x in (0, 10, 20) for y in (0, 10, 20)], dtype=np.float64)
        triangles = reach_triangles(grid, 15.0)
        assert triangles.shape == (8, 3, 2)  # two a cell: sides 10, 10 and 14.1
        assert reach_triangles(grid, 12.0).shape == (0, 3, 2)

    def test_the_long_sides_of_a_far_point_are_left_out(self):
        points = np.array([[0, 0], [10, 0], [0, 10], [10, 10], [60, 5]], dtype=np.float64)
        triangles = reach_triangles(points, 15.0)
        assert len(triangles) == 2 and triangles[..., 0].max() == 10

    def test_collinear_points_span_no_triangle(self):
        assert reach_triangles(np.array([[0, 0], [1, 1], [2, 2], [3, 3]], dtype=np.float64), 5.0) is None


class TestTouching:
    def test_only_the_regions_a_seed_touches(self):
        candidates = np.zeros((20, 20), bool)
        candidates[2:6, 2:6] = candidates[12:16, 12:16] = True
        seeds = np.zeros((20, 20), bool)
        seeds[5, 5] = seeds[0, 19] = True  # one on the first region, one on nothing
        kept = touching(candidates, seeds)
        assert kept.shape == (20, 20) and kept.dtype == bool
        assert kept[2:6, 2:6].all() and kept.sum() == 16

    def test_diagonal_neighbours_are_one_region_and_no_seed_keeps_nothing(self):
        candidates = np.eye(6, dtype=bool)
        seeds = np.zeros((6, 6), bool)
        seeds[0, 0] = True
        assert np.array_equal(touching(candidates, seeds), candidates)
        assert not touching(candidates, np.zeros_like(seeds)).any()
