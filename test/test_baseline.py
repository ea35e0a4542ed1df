"""core/baseline.dynamic_instances: which instances move, from per-pixel evidence."""

import numpy as np

from moseg_ros.core.baseline import DENSE_IDS, dynamic_instances


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
