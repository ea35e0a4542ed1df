"""core/baseline: the per-pixel two-view distances and dynamic_instances (which instances move, from per-pixel
evidence)."""

import numpy as np

from moseg_ros.core import geometry
from moseg_ros.core.baseline import DENSE_IDS, dynamic_instances, homography_distance, sampson_pixels


def correspondences(n: int = 500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) float32 pixels of a 640x360 frame and their matches a few pixels away."""
    rng = np.random.default_rng(seed)
    points = (rng.random((n, 2)) * (640, 360)).astype(np.float32)
    return points, points + rng.normal(0, 3, (n, 2)).astype(np.float32)


class TestHomographyDistance:
    H = np.array([[1.02, 0.01, -4.0], [-0.015, 0.99, 2.5], [2e-5, -1e-5, 1.0]])

    def test_shape_and_dtype(self):
        points, matches = correspondences()
        distance = homography_distance(self.H, points, matches)
        assert distance.shape == (500,) and distance.dtype == np.float32

    def test_exact_matches_are_at_zero(self):
        points, _ = correspondences()
        h = geometry.to_homogeneous(points.astype(np.float64)) @ self.H.T
        matches = (h[:, :2] / h[:, 2:]).astype(np.float32)
        assert homography_distance(self.H, points, matches).max() < 1e-3

    def test_equals_the_batched_symmetric_transfer_error(self):
        points, matches = correspondences()
        batched = np.sqrt(0.5 * geometry.homography_transfer_error(self.H[None], points, matches)[0])
        np.testing.assert_allclose(homography_distance(self.H, points, matches), batched, rtol=1e-4, atol=1e-3)


class TestSampsonPixels:
    def test_equals_the_batched_sampson_distance(self):
        points, matches = correspondences(seed=1)
        F = np.array([[0.0, -1e-3, 0.2], [1e-3, 0.0, -0.4], [-0.2, 0.4, 1e-3]])
        batched = np.sqrt(geometry.sampson_distance(F[None], points, matches)[0])
        np.testing.assert_allclose(sampson_pixels(F, points, matches), batched, rtol=1e-4, atol=1e-3)


class TestDynamicInstances:
    @staticmethod
    def scene(moving_id: int, static_id: int, none: int = 0):
        """A 20x30 map: ``moving_id`` in the left block (all its pixels moving), ``static_id`` in the right block
        (one pixel in ten moving), ``none`` elsewhere (with moving pixels that belong to no instance)."""
        instances = np.full((20, 30), none, dtype=np.int64)
        instances[2:12, 2:12], instances[2:12, 15:25] = moving_id, static_id
        moving = np.zeros((20, 30), dtype=bool)
        moving[2:12, 2:12] = True
        moving[2:12, 15:25:10] = True
        moving[15:, :] = True
        return instances, moving

    def test_smoke_nothing_moves(self):
        instances, _ = self.scene(3, 4)
        ids = dynamic_instances(instances, np.zeros_like(instances, dtype=bool), np.ones(instances.shape, bool))
        assert ids.dtype == np.int32 and ids.size == 0

    def test_the_moving_instance_and_only_it(self):
        instances, moving = self.scene(3, 4)
        valid = np.ones(instances.shape, bool)
        assert dynamic_instances(instances, moving, valid).tolist() == [3]
        # The static block's tenth is below the default share; at a tenth it counts.
        assert dynamic_instances(instances, moving, valid, min_fraction=0.1).tolist() == [3, 4]
        # Too few reliable pixels: undecided.
        valid[2:12, 2:11] = False  # 10 reliable pixels left, under min_pixels
        assert dynamic_instances(instances, moving, valid).tolist() == []

    def test_ids_beyond_a_table_and_negative_background(self):
        """Ids far above ``DENSE_IDS`` (a segmenter's hashes) are counted without a table up to them; ids <= 0 are
        no instance, whatever moves there."""
        for big in (DENSE_IDS + 1, 2**31 - 1):
            instances, moving = self.scene(big, 7, none=-1)
            assert dynamic_instances(instances, moving, np.ones(instances.shape, bool)).tolist() == [big]
            instances, moving = self.scene(7, big, none=-5)
            assert dynamic_instances(instances, moving, np.ones(instances.shape, bool), 0.1).tolist() == [7, big]
