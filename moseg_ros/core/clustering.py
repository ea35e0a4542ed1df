"""Spectral clustering, co-regularized multi-view spectral clustering, the number of motions, and the error metric.

* Spectral clustering (Ng, Jordan, Weiss 2001): the top-K eigenvectors of S = D^-1/2 A D^-1/2, rows normalized,
  k-means.
* Co-regularized multi-view spectral clustering (Kumar, Rai, Daumé, NIPS 2011, pairwise form): alternately, for
  each view v, U_v = top-K eigenvectors of S_v + λ Σ_{w≠v} U_w U_wᵀ (the minimizer of
  tr(U_vᵀ L_v U_v) − λ Σ_w tr(U_v U_vᵀ U_w U_wᵀ)); then k-means on the row-normalized concatenation of the U_v
  (as in Xu et al. 2018).
* Number of motions: the largest eigengap of the (mean) normalized affinity; or, for sparsified affinities whose
  spectra decay without a gap, the largest K whose every cluster is nearly cut off from the rest in every view
  (cluster conductance φ(C) = cut(C, V∖C) / vol(C) ≤ τ; Shi and Malik 2000, the normalized-cut term of one cluster).
* Misclassification rate: the fraction of items whose cluster is wrong under the best one-to-one matching of
  clusters to labels (Hungarian algorithm, scipy.optimize.linear_sum_assignment).
"""

from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg
from scipy.cluster.vq import kmeans2
from scipy.optimize import linear_sum_assignment

_DENSE_MAX = 300
"""Up to this many items eigenproblems are solved densely; above, by Lanczos on the sparse affinity."""


def normalized_affinity(affinity: np.ndarray) -> np.ndarray:
    """Symmetrically normalized affinity S = D^-1/2 A D^-1/2, D = diag(Σ_j a_ij).

    Args:
        affinity: (N, N) finite, non-negative affinity A.

    Returns:
        (N, N) float64 S; isolated items (zero degree) get zero rows.
    """
    a = np.asarray(affinity, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"affinity must be square, got {a.shape}")
    if np.any(a < 0) or not np.all(np.isfinite(a)):
        raise ValueError("affinity must be finite and non-negative")
    d = a.sum(axis=1)
    inv_sqrt = np.where(d > 0, 1.0 / np.sqrt(np.maximum(d, 1e-300)), 0.0)
    return inv_sqrt[:, None] * a * inv_sqrt[None, :]


def top_eigenvectors(sym: np.ndarray, k: int, low_rank: np.ndarray | None = None,
                     weight: float = 0.0) -> np.ndarray:
    """(N, k) eigenvectors of the k largest eigenvalues of sym + weight · low_rank low_rankᵀ.

    Small problems use dense LAPACK (eigh); large ones ARPACK Lanczos (eigsh) on the sparse ``sym`` plus the
    low-rank term as an operator, which is several times faster once the affinity has been sparsified.

    Args:
        sym: (N, N) symmetric matrix.
        k: number of eigenvectors.
        low_rank: optional (N, r) factor of a symmetric low-rank term.
        weight: its weight.

    Returns:
        (N, k) eigenvectors, eigenvalues descending.
    """
    n = sym.shape[0]
    if n <= _DENSE_MAX or k >= n - 1:
        return _dense_top_eigenvectors(sym, k, low_rank, weight)
    sparse = scipy.sparse.csr_matrix(sym)
    if low_rank is None:
        op = sparse
    else:
        op = scipy.sparse.linalg.LinearOperator(
            (n, n), matvec=lambda x: sparse @ x + weight * (low_rank @ (low_rank.T @ x)),
            matmat=lambda x: sparse @ x + weight * (low_rank @ (low_rank.T @ x)), dtype=np.float64)
    v0 = np.full(n, 1.0 / np.sqrt(n))
    try:
        val, vec = scipy.sparse.linalg.eigsh(op, k=k, which="LA", tol=1e-8, v0=v0,
                                             ncv=min(n, max(2 * k + 1, 20)))
    except scipy.sparse.linalg.ArpackNoConvergence:
        # Lanczos stalls on clusters of equal eigenvalues (e.g. many components of a graph); LAPACK does not.
        return _dense_top_eigenvectors(sym, k, low_rank, weight)
    return vec[:, np.argsort(val)[::-1]]


def _dense_top_eigenvectors(sym: np.ndarray, k: int, low_rank: np.ndarray | None, weight: float) -> np.ndarray:
    n = sym.shape[0]
    full = sym if low_rank is None else sym + weight * (low_rank @ low_rank.T)
    _, vec = scipy.linalg.eigh(full, subset_by_index=[n - k, n - 1], driver="evr")
    return vec[:, ::-1]


def row_normalize(u: np.ndarray) -> np.ndarray:
    """Rows of an (N, d) matrix scaled to unit length, u_i / ||u_i|| -> (N, d) (zero rows stay zero)."""
    return u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)


def kmeans(points: np.ndarray, k: int, rng: np.random.Generator, *, n_init: int = 10) -> np.ndarray:
    """Best of n_init k-means++ runs (scipy kmeans2) by within-cluster sum of squares Σ_i ||p_i − c_(label i)||².

    Args:
        points: (N, d) points.
        k: number of clusters.
        rng: random generator for the seeds.
        n_init: restarts.

    Returns:
        (N,) int labels in [0, k) (a cluster may be empty).
    """
    best, best_cost = None, np.inf
    for _ in range(n_init):
        with warnings.catch_warnings():
            # A restart that loses a cluster only costs more; the best restart is kept.
            warnings.filterwarnings("ignore", message="One of the clusters is empty")
            centres, labels = kmeans2(points, k, minit="++", seed=rng)
        cost = float(np.sum((points - centres[labels]) ** 2))
        if cost < best_cost:
            best, best_cost = labels, cost
    return best


def _check_k(n: int, k: int) -> None:
    if not 1 <= k <= n:
        raise ValueError(f"number of clusters must be in [1, {n}], got {k}")


def spectral_clustering(affinity: np.ndarray, k: int, rng: np.random.Generator, *, n_init: int = 10) -> np.ndarray:
    """Normalized spectral clustering (Ng, Jordan, Weiss 2001): k-means on the row-normalized top-k
    eigenvectors of S = D^-1/2 A D^-1/2.

    Args:
        affinity: (N, N) non-negative symmetric affinity.
        k: number of clusters, in [1, N].
        rng: random generator for k-means.

    Returns:
        (N,) int labels in [0, k).
    """
    s = normalized_affinity(affinity)
    _check_k(s.shape[0], k)
    if k == 1:
        return np.zeros(s.shape[0], dtype=np.int64)
    return kmeans(row_normalize(top_eigenvectors(s, k)), k, rng, n_init=n_init)


def coregularized_embedding(affinities: Sequence[np.ndarray], k: int, *, lam: float = 0.01,
                            n_iter: int = 5) -> list[np.ndarray]:
    """Co-regularized spectral embeddings, one per view (Kumar et al. 2011, pairwise).

    U_v = top-k eigenvectors of S_v + λ Σ_{w≠v} U_w U_wᵀ, alternated over the views n_iter times.

    Args:
        affinities: V (N, N) affinities of the same items.
        k: embedding dimension (number of clusters).
        lam: co-regularization weight λ.
        n_iter: alternation rounds over all views.

    Returns:
        V (N, k) embeddings U_v (the plain spectral embedding for a single view).
    """
    if len(affinities) == 0:
        raise ValueError("need at least one affinity")
    s = [normalized_affinity(a) for a in affinities]
    n = s[0].shape[0]
    if any(si.shape != (n, n) for si in s):
        raise ValueError("all affinities must have the same (N, N) shape")
    _check_k(n, k)
    u = [top_eigenvectors(si, k) for si in s]
    if len(s) == 1:
        return u
    for _ in range(n_iter):
        for v in range(len(s)):
            # Σ_{w≠v} U_w U_wᵀ = G Gᵀ with G the side-by-side U_w: kept as a factor, never formed densely.
            factor = np.concatenate([u[w] for w in range(len(s)) if w != v], axis=1)
            u[v] = top_eigenvectors(s[v], k, factor, lam)
    return u


def coregularized_spectral_clustering(affinities: Sequence[np.ndarray], k: int, rng: np.random.Generator, *,
                                      lam: float = 0.01, n_iter: int = 5, n_init: int = 10) -> np.ndarray:
    """Cluster items seen in several views into k clusters: k-means on the row-normalized concatenation of
    the row-normalized co-regularized embeddings (``coregularized_embedding``).

    Args:
        affinities: V (N, N) affinities of the same items.
        k: number of clusters.
        rng: random generator for k-means.
        lam, n_iter: as ``coregularized_embedding``.
        n_init: k-means restarts.

    Returns:
        (N,) int labels in [0, k).
    """
    n = np.asarray(affinities[0]).shape[0] if len(affinities) else 0
    if k == 1 and n > 0:
        return np.zeros(n, dtype=np.int64)
    u = coregularized_embedding(affinities, k, lam=lam, n_iter=n_iter)
    joint = row_normalize(np.concatenate([row_normalize(ui) for ui in u], axis=1))
    return kmeans(joint, k, rng, n_init=n_init)


def cluster_conductance(affinity: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Conductance of each cluster, φ(C) = cut(C, V∖C) / vol(C), self-affinities excluded.

    The fraction of a cluster's edge weight that leaves it: 0 for a connected component, 1 for a cluster with
    no edge inside. A cluster without any edge (vol 0) gets 1.

    Args:
        affinity: (N, N) non-negative symmetric affinity.
        labels: (N,) cluster labels in [0, K).

    Returns:
        (K,) conductances in [0, 1].
    """
    a = np.asarray(affinity, dtype=np.float64)
    labels = np.asarray(labels)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or labels.shape != a.shape[:1]:
        raise ValueError(f"affinity must be (N, N) and labels (N,), got {a.shape} and {labels.shape}")
    off = a - np.diag(np.diag(a))
    onehot = np.eye(int(labels.max()) + 1)[labels]
    within = np.einsum("ic,ij,jc->c", onehot, off, onehot)
    volume = onehot.T @ off.sum(axis=1)
    return np.where(volume > 0, 1.0 - within / np.maximum(volume, 1e-300), 1.0)


def coregularized_clustering_unknown_k(affinities: Sequence[np.ndarray], rng: np.random.Generator, *,
                                       k_min: int = 2, k_max: int = 6, max_conductance: float = 0.035,
                                       lam: float = 0.01, n_iter: int = 5, n_init: int = 10) -> np.ndarray:
    """Co-regularized clustering with the number of clusters chosen by cluster conductance.

    K = k_min, k_min + 1, ... is tried in turn and the last K is kept whose clusters all have conductance
    <= max_conductance in every view (each motion a nearly separate component of every sparsified graph);
    the search stops at the first K that fails. Sparsified affinities have no eigengap (their spectra decay
    smoothly), but a wrong split of one motion cuts many of its edges. The error changes little over a broad range
    of τ, and stays below that of the eigengap of the unsparsified kernels (docs/experiments.md,
    ``max_conductance``).

    Args:
        affinities: V (N, N) sparsified affinities.
        rng: random generator for k-means.
        k_min: smallest K (always accepted).
        k_max: largest K tried.
        max_conductance: τ, the largest conductance a cluster may have in any view.

    Returns:
        (N,) labels in [0, K).
    """
    if not 0.0 <= max_conductance <= 1.0:
        raise ValueError(f"max_conductance must be in [0, 1], got {max_conductance}")
    n = np.asarray(affinities[0]).shape[0] if len(affinities) else 0
    k_max = min(k_max, n)
    _check_k(n, k_min)
    best = coregularized_spectral_clustering(affinities, k_min, rng, lam=lam, n_iter=n_iter, n_init=n_init)
    for k in range(k_min + 1, k_max + 1):
        labels = coregularized_spectral_clustering(affinities, k, rng, lam=lam, n_iter=n_iter, n_init=n_init)
        labels = np.unique(labels, return_inverse=True)[1]  # k-means may leave a cluster empty
        if max(cluster_conductance(a, labels).max() for a in affinities) > max_conductance:
            break
        best = labels
    return best


def affinity_spectrum(affinities: Sequence[np.ndarray], n_values: int) -> np.ndarray:
    """Largest eigenvalues of the mean normalized affinity (1/V) Σ_v D_v^-1/2 A_v D_v^-1/2 of the views.

    Args:
        affinities: V (N, N) affinities of the same items.
        n_values: how many eigenvalues (at most N).

    Returns:
        (min(n_values, N),) eigenvalues, descending.
    """
    s = sum(normalized_affinity(a) for a in affinities) / len(affinities)
    n = s.shape[0]
    n_values = min(n_values, n)
    if n <= _DENSE_MAX or n_values >= n - 1:
        return scipy.linalg.eigh(s, eigvals_only=True, subset_by_index=[n - n_values, n - 1])[::-1]
    val = scipy.sparse.linalg.eigsh(scipy.sparse.csr_matrix(s), k=n_values, which="LA", tol=1e-8,
                                    v0=np.full(n, 1.0 / np.sqrt(n)), ncv=min(n, max(2 * n_values + 1, 20)),
                                    return_eigenvectors=False)
    return np.sort(val)[::-1]


def estimate_n_motions(affinities: Sequence[np.ndarray], *, k_min: int = 2, k_max: int = 6,
                       tie_tolerance: float = 0.0) -> int:
    """Number of motions by the largest eigengap λ_k − λ_{k+1} of the mean normalized affinity, k in [k_min, k_max].

    The eigenvalues of S = D^-1/2 A D^-1/2 lie in [-1, 1] with one eigenvalue 1 per connected component; K
    well-separated motions give K eigenvalues near 1 and a drop after them. λ_{N+1} is taken as 0, so K = N
    (every item alone) is possible. Gaps within ``tie_tolerance`` of the largest count as ties, resolved
    towards more motions (two views that disagree about an object give exactly such a tie).

    Args:
        affinities: V (N, N) affinities of the same items.
        k_min, k_max: range of K (k_max capped at N).
        tie_tolerance: gaps this close to the largest count as ties.

    Returns:
        K.
    """
    n = np.asarray(affinities[0]).shape[0]
    k_max = min(k_max, n)
    k_min = max(1, min(k_min, k_max))
    ev = np.append(affinity_spectrum(affinities, k_max + 1), 0.0)
    gaps = ev[k_min - 1:k_max] - ev[k_min:k_max + 1]
    return int(k_min + np.flatnonzero(gaps >= gaps.max() - tie_tolerance)[-1])


def _confusion(pred: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pred = np.asarray(pred)
    truth = np.asarray(truth)
    if pred.shape != truth.shape or pred.ndim != 1:
        raise ValueError(f"pred and truth must be equal-length 1-D arrays, got {pred.shape} and {truth.shape}")
    if len(pred) == 0:
        raise ValueError("no items to score")
    p_ids, p_idx = np.unique(pred, return_inverse=True)
    t_ids, t_idx = np.unique(truth, return_inverse=True)
    confusion = np.zeros((len(p_ids), len(t_ids)), dtype=np.int64)
    np.add.at(confusion, (p_idx, t_idx), 1)
    return confusion, p_ids, t_ids


def match_clusters(pred: np.ndarray, truth: np.ndarray) -> dict[int, int]:
    """Best one-to-one map predicted cluster -> true label (maximum agreement, Hungarian algorithm).

    Args:
        pred: (N,) predicted cluster of each item.
        truth: (N,) true label of each item.

    Returns:
        {cluster: label} for the matched clusters (unmatched clusters are left out).
    """
    confusion, p_ids, t_ids = _confusion(pred, truth)
    rows, cols = linear_sum_assignment(confusion, maximize=True)
    return {int(p_ids[r]): int(t_ids[c]) for r, c in zip(rows, cols)}


def misclassification_rate(pred: np.ndarray, truth: np.ndarray) -> float:
    """Fraction of items misclassified under the best one-to-one matching of clusters to labels.

    error = 1 − Σ_(c, l) matched |c ∩ l| / N; items of clusters left unmatched (more clusters than labels)
    count as errors.

    Args:
        pred: (N,) predicted cluster of each item.
        truth: (N,) true label of each item.

    Returns:
        Error rate in [0, 1].
    """
    confusion, _, _ = _confusion(pred, truth)
    rows, cols = linear_sum_assignment(confusion, maximize=True)
    return float(1.0 - confusion[rows, cols].sum() / confusion.sum())
