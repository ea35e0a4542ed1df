"""Ordered residual kernel and sparsification on planted structures (moseg_ros.core.affinity)."""

import numpy as np
import pytest

from moseg_ros.core import affinity
from moseg_ros.core.hypotheses import ResidualBlock


def _planted_blocks(rng: np.random.Generator, sizes: list[int], n_blocks: int = 4,
                    hyps_per_group: int = 30) -> tuple[list[ResidualBlock], np.ndarray]:
    """Items of group g have small residuals only under hypotheses of group g."""
    labels = np.repeat(np.arange(len(sizes)), sizes)
    blocks = []
    for _ in range(n_blocks):
        hyp_group = np.repeat(np.arange(len(sizes)), hyps_per_group)
        small = labels[:, None] == hyp_group[None, :]
        res = np.where(small, rng.uniform(0, 1, small.shape), rng.uniform(5, 50, small.shape))
        blocks.append(ResidualBlock(np.arange(len(labels)), res))
    return blocks, labels


def test_ork_recovers_planted_blocks():
    rng = np.random.default_rng(0)
    blocks, labels = _planted_blocks(rng, [20, 15, 10])
    a = affinity.ordered_residual_kernel(blocks, len(labels), inlier_fraction=0.2, prior=0.0)
    same = labels[:, None] == labels[None, :]
    assert np.allclose(a, a.T)
    assert a[~same].max() == 0.0  # the t = 18 smallest residuals never leave an item's own group
    assert a[same].min() > 0.1
    assert np.allclose(np.diag(a), 1.0)


def test_ork_normalizes_by_co_occurrence_and_skips_absent_items():
    rng = np.random.default_rng(1)
    blocks, labels = _planted_blocks(rng, [6, 6], n_blocks=2)
    partial = ResidualBlock(blocks[1].items[:6], blocks[1].residuals[:6])  # group 1 absent in the 2nd block
    a = affinity.ordered_residual_kernel([blocks[0], partial], 12, inlier_fraction=0.5, prior=0.0)
    # Within group 0: two co-occurrences; within group 1 one; both normalized to the same value 1.
    assert a[0, 1] == pytest.approx(1.0)
    assert a[6, 7] == pytest.approx(1.0)
    damped = affinity.ordered_residual_kernel([blocks[0], partial], 12, inlier_fraction=0.5, prior=1.0)
    assert damped[0, 1] == pytest.approx(2.0 / 3.0)
    assert damped[6, 7] == pytest.approx(1.0 / 2.0)


def test_relative_inliers_follow_own_model_reference():
    # Items 0, 1 static (fit each other's models), item 2 alone; models owned by items 0, 1, 2.
    res = np.array([[0.1, 0.3, 40.0], [0.2, 0.05, 30.0], [25.0, 20.0, 0.2]])
    block = ResidualBlock(np.arange(3), res, owners=np.arange(3))
    ref = affinity.own_residual_reference(block, noise_floor=0.25)
    assert ref.tolist() == [0.25, 0.25, 0.25]
    a = affinity.ordered_residual_kernel([block], 3, inlier_ratio=4.0, noise_floor=0.25, prior=0.0)
    assert a[0, 1] == pytest.approx(1.0)
    assert a[0, 2] == 0.0 and a[1, 2] == 0.0


def test_entropy_sparsification_keeps_the_strong_neighbours():
    rng = np.random.default_rng(2)
    labels = np.repeat([0, 1], [10, 10])
    a = np.where(labels[:, None] == labels[None, :], 0.8, 0.3) + rng.uniform(0, 0.05, (20, 20))
    a = (a + a.T) / 2
    s = affinity.sparsify_entropy(a, alpha=10.0)
    assert np.allclose(s, s.T)
    assert s[labels[:, None] != labels[None, :]].max() == 0.0
    assert (s[labels[:, None] == labels[None, :]] > 0).mean() > 0.4


def test_knn_sparsification_keeps_k_per_row():
    a = np.random.default_rng(3).uniform(0, 1, (12, 12))
    a = (a + a.T) / 2
    s = affinity.sparsify_knn(a, 3)
    assert np.allclose(s, s.T)
    assert np.all((s > 0).sum(axis=1) >= 3)


def test_bad_parameters_raise():
    with pytest.raises(ValueError, match="inlier_fraction"):
        affinity.ork_inliers(np.zeros((2, 3)), 0.0)
    with pytest.raises(ValueError, match="square"):
        affinity.sparsify_entropy(np.zeros((2, 3)), 5.0)
