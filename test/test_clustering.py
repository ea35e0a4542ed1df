"""Spectral, co-regularized clustering, number of motions and the error metric (moseg_ros.core.clustering)."""

import numpy as np
import pytest
import scipy.sparse.linalg

from moseg_ros.core import clustering


def _blocks(rng: np.random.Generator, sizes: list[int], within: float, across: float) -> np.ndarray:
    labels = np.repeat(np.arange(len(sizes)), sizes)
    a = np.where(labels[:, None] == labels[None, :], within, across) * rng.uniform(0.5, 1.0, (len(labels),) * 2)
    return (a + a.T) / 2


def test_spectral_clustering_recovers_planted_blocks():
    rng = np.random.default_rng(0)
    sizes = [40, 25, 15]
    truth = np.repeat(np.arange(3), sizes)
    pred = clustering.spectral_clustering(_blocks(rng, sizes, 1.0, 0.05), 3, rng)
    assert clustering.misclassification_rate(pred, truth) == 0.0


def test_large_sparse_problem_uses_the_same_answer():
    rng = np.random.default_rng(1)
    sizes = [300, 150, 100]
    a = _blocks(rng, sizes, 1.0, 0.0) * (rng.uniform(size=(550, 550)) < 0.1)
    a = np.maximum(a, a.T)
    truth = np.repeat(np.arange(3), sizes)
    assert clustering.misclassification_rate(clustering.spectral_clustering(a, 3, rng), truth) == 0.0


def test_lanczos_that_does_not_converge_falls_back_to_lapack(monkeypatch):
    rng = np.random.default_rng(2)
    sym = clustering.normalized_affinity(_blocks(rng, [200, 150], 1.0, 0.01))
    factor = rng.normal(size=(350, 2))
    expected = clustering.top_eigenvectors(sym, 2, factor, 0.1)

    def stalls(*args, **kwargs):
        raise scipy.sparse.linalg.ArpackNoConvergence("no convergence", np.zeros(0), np.zeros((350, 0)))

    monkeypatch.setattr(scipy.sparse.linalg, "eigsh", stalls)
    got = clustering.top_eigenvectors(sym, 2, factor, 0.1)
    np.testing.assert_allclose(np.abs(got.T @ expected), np.eye(2), atol=1e-6)  # same subspace, any sign


def test_coregularization_fuses_complementary_views():
    # View 1 separates groups {0} | {1, 2}; view 2 separates {0, 1} | {2}: only together are 3 groups visible.
    rng = np.random.default_rng(2)
    truth = np.repeat(np.arange(3), [30, 30, 30])
    v1 = np.where((truth[:, None] == 0) == (truth[None, :] == 0), 1.0, 0.02)
    v2 = np.where((truth[:, None] == 2) == (truth[None, :] == 2), 1.0, 0.02)
    noise = rng.uniform(0.8, 1.0, (90, 90))
    v1, v2 = v1 * (noise + noise.T) / 2, v2 * (noise + noise.T) / 2
    pred = clustering.coregularized_spectral_clustering([v1, v2], 3, rng, lam=0.1)
    assert clustering.misclassification_rate(pred, truth) == 0.0
    assert clustering.misclassification_rate(clustering.spectral_clustering(v1, 3, rng), truth) > 0.1


def test_number_of_motions_from_the_eigengap():
    rng = np.random.default_rng(3)
    for sizes in ([30, 30], [20, 20, 20, 20], [50, 10, 10]):
        assert clustering.estimate_n_motions([_blocks(rng, sizes, 1.0, 0.01)], k_min=1, k_max=6) == len(sizes)
    assert clustering.estimate_n_motions([np.ones((5, 5))], k_min=1) == 1
    assert clustering.estimate_n_motions([np.eye(2)], k_min=1) == 2


def test_cluster_conductance_hand_example():
    # Two pairs joined by one edge of weight 0.5: each pair has volume 2·1 + 0.5 and loses 0.5 of it.
    a = np.array([[0, 1, 0, 0], [1, 0, 0.5, 0], [0, 0.5, 0, 1], [0, 0, 1, 0]], dtype=float) + np.eye(4)
    assert clustering.cluster_conductance(a, np.array([0, 0, 1, 1])) == pytest.approx([0.2, 0.2])
    # {0} has its only edge outside; {1, 2, 3} has volume 1.5 + 1.5 + 1 = 4 and loses the edge of weight 1.
    assert clustering.cluster_conductance(a, np.array([0, 1, 1, 1])) == pytest.approx([1.0, 0.25])
    assert clustering.cluster_conductance(np.eye(2), np.array([0, 1])).tolist() == [1.0, 1.0]  # no edges: 1


def test_unknown_number_of_clusters_by_conductance():
    rng = np.random.default_rng(4)
    for sizes in ([60, 40], [40, 30, 20, 15]):
        truth = np.repeat(np.arange(len(sizes)), sizes)
        views = [_blocks(rng, sizes, 1.0, 0.0) + 0.002 * (truth[:, None] != truth[None, :]) for _ in range(2)]
        pred = clustering.coregularized_clustering_unknown_k(views, rng, k_max=6)
        assert len(np.unique(pred)) == len(sizes)
        assert clustering.misclassification_rate(pred, truth) == 0.0
    # One dense block: no split keeps its clusters apart, so the smallest K is kept.
    one = [_blocks(rng, [80], 1.0, 0.0)] * 2
    assert len(np.unique(clustering.coregularized_clustering_unknown_k(one, rng, k_min=2, k_max=4))) == 2
    with pytest.raises(ValueError, match="max_conductance"):
        clustering.coregularized_clustering_unknown_k(one, rng, max_conductance=1.5)


def test_misclassification_rate_hand_examples():
    assert clustering.misclassification_rate([0, 0, 1, 1], [5, 5, 7, 7]) == 0.0
    assert clustering.misclassification_rate([1, 1, 0, 0], [5, 5, 7, 7]) == 0.0  # label names do not matter
    assert clustering.misclassification_rate([0, 0, 0, 1], [1, 1, 2, 2]) == pytest.approx(0.25)
    assert clustering.misclassification_rate([0, 0, 0, 0], [1, 1, 2, 2]) == pytest.approx(0.5)  # K too small
    assert clustering.misclassification_rate([0, 1, 2, 2], [1, 1, 2, 2]) == pytest.approx(0.25)  # K too large
    assert clustering.match_clusters([2, 2, 0], [1, 1, 3]) == {2: 1, 0: 3}


def test_bad_input_raises():
    with pytest.raises(ValueError, match="equal-length"):
        clustering.misclassification_rate([0, 1], [0, 1, 2])
    with pytest.raises(ValueError, match="non-negative"):
        clustering.spectral_clustering(-np.ones((3, 3)), 2, np.random.default_rng(0))
    with pytest.raises(ValueError, match="number of clusters"):
        clustering.spectral_clustering(np.ones((3, 3)), 4, np.random.default_rng(0))
