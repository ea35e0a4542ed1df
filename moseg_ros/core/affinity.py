"""Affinities between items from their residuals: the ordered residual kernel and its sparsification.

Ordered residual kernel (ORK; Chin, Wang, Suter, NIPS 2009): within each block of hypotheses (one frame pair),
an item's inliers are the hypotheses of its ``t`` smallest residuals (t a fraction of the block; at object
level, per item, the hypotheses within a ratio of its residual under its own model), c_i ∈ {0,1}^M, and the
block's kernel is k_ij = c_iᵀ c_j / sqrt(t_i t_j). Blocks are summed over frame pairs and divided by the number
of pairs in which both items are present plus a prior (Xu, Cheong, Li, CVPR 2018, normalise by co-occurrence),
so items seen together in few pairs get no spurious certainty: with too small a prior, short trajectories are
split from long ones by when they were seen rather than by how they move (docs/experiments.md, ``prior``).

Sparsification (Lai, Wang, Chin et al., IEEE T-ITS 2017): each row keeps the entries whose probability
p_ij ∝ max_j a_ij^α − a_ij^α is below the row's entropy threshold, i.e. the entries close to the row's strongest;
the mask is symmetrized as (M + Mᵀ)/2.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from moseg_ros.core.hypotheses import ResidualBlock


def ork_inliers(residuals: np.ndarray, inlier_fraction: float, *, min_inliers: int = 1) -> tuple[np.ndarray, int]:
    """Inlier indicator of each item: its ``t = max(min_inliers, round(fraction·M))`` smallest residuals.

    Args:
        residuals: (n, M) residuals (NaN = unknown, never an inlier).
        inlier_fraction: fraction of the M hypotheses taken as each item's inliers, in (0, 1].

    Returns:
        (n, M) float32 0/1 indicator, and t.
    """
    if not 0.0 < inlier_fraction <= 1.0:
        raise ValueError(f"inlier_fraction must be in (0, 1], got {inlier_fraction}")
    n, m = residuals.shape
    t = int(min(m, max(min_inliers, round(inlier_fraction * m))))
    r = np.where(np.isnan(residuals), np.inf, residuals)
    top = np.argpartition(r, t - 1, axis=1)[:, :t] if t < m else np.broadcast_to(np.arange(m), (n, m))
    c = np.zeros((n, m), dtype=np.float32)
    np.put_along_axis(c, top, 1.0, axis=1)
    return c, t


def ork_inliers_relative(residuals: np.ndarray, reference: np.ndarray, ratio: float) -> np.ndarray:
    """Inlier indicator with a per-item t: the hypotheses whose residual is within ``ratio`` of a reference.

    c_im = r_im <= ratio · reference_i. With one hypothesis per object (object level) a fixed fraction t
    cannot fit every item: a lone moving object fits only its own model, a static one every static object's
    model. The sorted residuals are still cut at a threshold, but one relative to how well the item can be
    fitted at all (its residual under its own model, not below a noise floor).

    Args:
        residuals: (n, M) residuals (NaN = unknown, never an inlier).
        reference: (n,) positive reference residual of each item.
        ratio: how many times the reference still counts as an inlier (>= 1).

    Returns:
        (n, M) float32 0/1 indicator.
    """
    if ratio < 1.0:
        raise ValueError(f"inlier ratio must be >= 1, got {ratio}")
    r = np.where(np.isnan(residuals), np.inf, residuals)
    return (r <= ratio * np.asarray(reference, dtype=np.float64)[:, None]).astype(np.float32)


def own_residual_reference(block: ResidualBlock, noise_floor: float, energy_fraction: float = 0.0) -> np.ndarray:
    """Reference residual of each item of a block: its residual under its own model, bounded from below.

    ref_i = max(r_i,own(i), noise_floor, energy_fraction · energy_i); the floor alone for an item without a
    (finite) residual under its own model; the energy term only when the block has energies.

    Args:
        block: residual block of n items (``owners`` names each hypothesis' item).
        noise_floor: smallest reference, in the units of the residuals.
        energy_fraction: the reference is also at least this fraction of the item's data energy.

    Returns:
        (n,) float64 references.
    """
    floor = np.full(len(block.items), float(noise_floor))
    if block.energy is not None and energy_fraction > 0:
        floor = np.fmax(floor, energy_fraction * block.energy)
    ref = floor.copy()
    if block.owners is not None:
        col = {int(o): j for j, o in enumerate(block.owners)}
        for i, item in enumerate(block.items):
            j = col.get(int(item))
            if j is not None and np.isfinite(block.residuals[i, j]):
                ref[i] = max(floor[i], float(block.residuals[i, j]))
    return ref


def ordered_residual_kernel(blocks: Sequence[ResidualBlock], n_items: int, inlier_fraction: float = 0.2, *,
                            min_inliers: int = 1, prior: float = 0.1, inlier_ratio: float | None = None,
                            noise_floor: float = 0.0, energy_fraction: float = 0.0) -> np.ndarray:
    """ORK affinity of n_items items accumulated over residual blocks.

    a_ij = Σ_blocks c_iᵀ c_j / sqrt(t_i t_j)  /  (number of blocks holding both i and j + prior)

    Args:
        blocks: per-pair residual blocks (items, residuals).
        n_items: N.
        inlier_fraction: fraction of each block's hypotheses that are an item's inliers (t fixed per block).
        min_inliers: at least this many inliers per item and block.
        prior: added to the co-occurrence count; damps affinities seen in few pairs.
        inlier_ratio: if given, an item's inliers are the hypotheses within this factor of its residual under
            its own model (own_residual_reference with noise_floor) instead of a fixed fraction.
        noise_floor: smallest reference residual (same units as the residuals).
        energy_fraction: the reference is also at least this fraction of the item's data energy (see
            own_residual_reference).

    Returns:
        (N, N) symmetric affinity in [0, 1].
    """
    columns, present = [], []
    for block in blocks:
        if block.residuals.shape[1] == 0:
            continue
        if inlier_ratio is None:
            c, t = ork_inliers(block.residuals, inlier_fraction, min_inliers=min_inliers)
            scale = np.full((len(c), 1), 1.0 / np.sqrt(t), dtype=np.float32)
        else:
            reference = own_residual_reference(block, noise_floor, energy_fraction)
            c = ork_inliers_relative(block.residuals, reference, inlier_ratio)
            scale = 1.0 / np.sqrt(np.maximum(c.sum(axis=1, keepdims=True), 1.0))
        full = np.zeros((n_items, c.shape[1]), dtype=np.float32)
        full[block.items] = c * scale
        columns.append(full)
        mask = np.zeros(n_items, dtype=np.float32)
        mask[block.items] = 1.0
        present.append(mask)
    if not columns:
        return np.zeros((n_items, n_items))
    # All blocks in one matrix product: Σ_b C_b C_bᵀ / t_b = C Cᵀ with the columns of block b scaled by t_b^-1/2.
    c_all = np.concatenate(columns, axis=1)
    kernel = (c_all @ c_all.T).astype(np.float64)
    v = np.stack(present, axis=1)
    cooc = (v @ v.T).astype(np.float64)
    return kernel / (cooc + prior)


def sparsify_entropy(affinity: np.ndarray, alpha: float) -> np.ndarray:
    """Adaptive epsilon-neighbour sparsification by the row entropy (Lai et al. 2017).

    p_ij = σ_ij / Σ_j σ_ij with σ_ij = max_j a_ij^α − a_ij^α; entry ij is kept (m_ij = 1) when
    log p_ij < Σ_j p_ij log p_ij (the row's negative entropy); the result is (M + Mᵀ)/2 ⊙ A.

    Args:
        affinity: (N, N) non-negative symmetric affinity.
        alpha: power applied before the rule; larger keeps fewer neighbours.

    Returns:
        (N, N) symmetric sparsified affinity (entries kept by one side are halved).
    """
    a = np.asarray(affinity, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"affinity must be square, got {a.shape}")
    if alpha <= 0:
        raise ValueError(f"alpha must be positive, got {alpha}")
    powered = a ** alpha
    sigma = powered.max(axis=1, keepdims=True) - powered
    total = sigma.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        prob = np.where(total > 0, sigma / total, 0.0)
    eps = np.finfo(np.float64).eps
    log_prob = np.log(prob + eps)
    neg_entropy = np.sum(prob * log_prob, axis=1, keepdims=True)
    mask = (log_prob < neg_entropy).astype(np.float64)
    return 0.5 * (mask + mask.T) * a


def sparsify_knn(affinity: np.ndarray, k: int) -> np.ndarray:
    """Keep each row's k largest entries (plus the diagonal), symmetrized as (M + Mᵀ)/2.

    Args:
        affinity: (N, N) non-negative symmetric affinity.
        k: neighbours per row.

    Returns:
        (N, N) sparsified affinity.
    """
    a = np.asarray(affinity, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"affinity must be square, got {a.shape}")
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    n = a.shape[0]
    k = min(k, n)
    top = np.argpartition(-a, k - 1, axis=1)[:, :k]
    mask = np.zeros_like(a)
    np.put_along_axis(mask, top, 1.0, axis=1)
    np.fill_diagonal(mask, 1.0)
    return 0.5 * (mask + mask.T) * a
