"""How published instances follow the true movers (moseg_ros.eval.identities)."""

from __future__ import annotations

import numpy as np

from moseg_ros.eval.identities import INSTANCE_SHARE, InstanceFollow, instance_holdings


def majority_instances(published, truth, objects):
    return instance_holdings(published, truth, objects)[0]


class TestMajorityInstances:
    def test_known_values(self):
        truth = np.array([1, 1, 1, 1, 2, 2, 2, 5, 5])
        published = np.array([7, 7, 3, 0, 3, 3, 0, 0, 0])
        held = majority_instances(published, truth, np.array([1, 2, 5]))
        assert held.tolist() == [7, 3, 0]  # object 5 lies in no instance

    def test_a_sliver_below_the_share_is_no_instance(self):
        samples = 20
        truth = np.ones(samples, dtype=np.int64)
        published = np.zeros(samples, dtype=np.int64)
        published[:int(INSTANCE_SHARE * samples) - 1] = 4
        assert majority_instances(published, truth, np.array([1])).tolist() == [0]
        published[:int(INSTANCE_SHARE * samples)] = 4
        assert majority_instances(published, truth, np.array([1])).tolist() == [4]

    def test_maps_of_any_shape_and_no_objects(self):
        truth = np.zeros((4, 5), dtype=np.int32)
        truth[1:3, 1:4] = 2
        published = np.where(truth == 2, 2 ** 31 - 5, 0)  # an id beyond the dense table
        assert majority_instances(published, truth, np.array([2])).tolist() == [2 ** 31 - 5]
        assert majority_instances(published, truth, np.zeros(0, dtype=np.int64)).shape == (0,)


class TestInstanceFollow:
    def test_switches_count_changes_of_id_and_not_gaps(self):
        follow = InstanceFollow()
        truth = np.array([1, 1])
        for instance in (5, 5, 0, 5, 6, 6, 5):
            follow.add(np.array([instance, instance]), truth, np.array([1]))
        assert follow.switches[1] == 2 and follow.shared[1] == 0

    def test_one_instance_holding_two_movers_is_shared_by_both(self):
        follow = InstanceFollow()
        truth = np.array([1, 1, 2, 2, 3, 3])
        follow.add(np.array([8, 8, 8, 8, 9, 9]), truth, np.array([1, 2, 3]))
        assert [follow.shared[obj] for obj in (1, 2, 3)] == [1, 1, 0] and sum(follow.switches.values()) == 0

    def test_a_mover_over_two_instances_is_split(self):
        follow = InstanceFollow()
        truth = np.ones(10, dtype=np.int64)
        follow.add(np.array([3] * 6 + [4] * 3 + [0]), truth, np.array([1]))  # 4 holds 0.3: a part of its own
        follow.add(np.array([3] * 9 + [4]), truth, np.array([1]))  # 4 holds 0.1: a sliver
        assert follow.split[1] == 1 and follow.switches[1] == 0


class TestInstanceHoldings:
    def test_known_values(self):
        truth = np.array([1, 1, 1, 1, 1, 2, 2])
        held, parts = instance_holdings(np.array([5, 5, 5, 6, 6, 0, 0]), truth, np.array([1, 2]))
        assert held.tolist() == [5, 0] and parts.tolist() == [2, 0]
        held, parts = instance_holdings(np.zeros(7, dtype=np.int64), truth, np.array([1, 2]))
        assert held.tolist() == [0, 0] and parts.tolist() == [0, 0]
