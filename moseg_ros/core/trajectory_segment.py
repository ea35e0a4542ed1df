"""The trajectory-level method (KT3DMoSeg protocol): trajectories -> motion labels.

Random minimal-sample hypotheses per view, the ordered residual kernel, entropy sparsification and co-regularized
spectral clustering (``segment_trajectories``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from moseg_ros.core import affinity, clustering, hypotheses


TRAJECTORY_VIEWS = ("fundamental", "homography", "affine")


@dataclass(frozen=True)
class TrajectoryConfig:
    """Settings of the trajectory-level method (one fixed setting for every clip; see eval/kt3dmoseg.py).

    Attributes:
        gap: frame gap of the pairwise models.
        n_hypotheses: random minimal-sample hypotheses per frame pair and view.
        inlier_fraction: ORK inliers per item, as a fraction of a pair's hypotheses.
        prior: added to the co-occurrence count when normalizing the kernel.
        alpha: power of the entropy sparsification.
        lam: co-regularization weight λ.
        n_iter: co-regularization rounds.
        k_max: largest number of motions considered when estimating it.
        max_conductance: when estimating the number of motions, the largest K is kept whose every cluster has
            at most this conductance in every view's sparsified affinity (see
            clustering.coregularized_clustering_unknown_k).
        refine_hypotheses: hypotheses per frame pair and view of the second, guided pass (0: one pass; only
            when the number of motions is given, see segment_trajectories).
        guided_fraction: share of the second pass's hypotheses sampled inside the first pass's clusters.
    """

    gap: int = 2
    n_hypotheses: int = 300
    inlier_fraction: float = 0.2
    prior: float = 1.5
    alpha: float = 11.0
    lam: float = 0.01
    n_iter: int = 5
    k_max: int = 6
    max_conductance: float = 0.035
    refine_hypotheses: int = 150
    guided_fraction: float = 2.0 / 3.0


def trajectory_kernels(tracks_xy: np.ndarray, visible: np.ndarray, views: tuple[str, ...],
                       config: TrajectoryConfig, rng: np.random.Generator, *,
                       groups: np.ndarray | None = None) -> list[np.ndarray]:
    """One dense ORK kernel per view (model type) over the trajectories, before sparsification.

    Without ``groups``: ``n_hypotheses`` random minimal samples per pair. With ``groups`` (a first
    clustering): ``refine_hypotheses`` samples per pair, ``guided_fraction`` of them drawn inside the groups.

    Args:
        tracks_xy: (N, F, 2) positions (pixels).
        visible: (N, F) bool.
        views: model types, a non-empty subset of ("fundamental", "homography", "affine").
        config: settings.
        rng: random generator for the samples.
        groups: optional (N,) int group of each trajectory.

    Returns:
        One (N, N) kernel per view, in the order of ``views``.
    """
    unknown = set(views) - set(TRAJECTORY_VIEWS)
    if unknown or not views:
        raise ValueError(f"views must be a non-empty subset of {TRAJECTORY_VIEWS}, got {views}")
    n = np.asarray(tracks_xy).shape[0]
    n_hypotheses = config.n_hypotheses if groups is None else config.refine_hypotheses
    guided = 0.0 if groups is None else config.guided_fraction
    kernels = []
    for view in views:
        blocks = hypotheses.trajectory_hypotheses(tracks_xy, visible, view, gap=config.gap,
                                                  n_hypotheses=n_hypotheses, rng=rng, groups=groups,
                                                  guided_fraction=guided)
        kernels.append(affinity.ordered_residual_kernel(blocks, n, config.inlier_fraction, prior=config.prior))
    return kernels


def _cluster_trajectories(kernels: list[np.ndarray], n_motions: int | None, config: TrajectoryConfig,
                          rng: np.random.Generator) -> np.ndarray:
    affs = [affinity.sparsify_entropy(k, config.alpha) for k in kernels]
    if n_motions is None:
        return clustering.coregularized_clustering_unknown_k(affs, rng, k_max=config.k_max,
                                                             max_conductance=config.max_conductance,
                                                             lam=config.lam, n_iter=config.n_iter)
    return clustering.coregularized_spectral_clustering(affs, n_motions, rng, lam=config.lam, n_iter=config.n_iter)


def segment_trajectories(tracks_xy: np.ndarray, visible: np.ndarray, *,
                         views: tuple[str, ...] = ("fundamental", "homography"), n_motions: int | None = None,
                         config: TrajectoryConfig | None = None,
                         rng: np.random.Generator | None = None) -> np.ndarray:
    """Cluster trajectories by motion.

    Per view: ORK kernel over random minimal-sample hypotheses, entropy sparsification; views fused by
    co-regularized spectral clustering. An unknown number of motions (at least 2) is the largest K whose
    clusters each keep all but ``max_conductance`` of their edge weight inside, in every sparsified view: the
    sparsified graphs keep only near neighbours, so their spectra decay smoothly and show no eigengap
    (docs/experiments.md, ``max_conductance``).

    A second pass (``refine_hypotheses`` > 0) redraws the hypotheses with ``guided_fraction`` of the minimal
    samples inside the first pass's clusters and clusters again with the same K: a random 8-point sample is
    seldom pure when an object holds a few percent of the points, a sample from one cluster mostly is, so the
    small motions get models of their own (cluster-guided sampling, in the spirit of Chin et al.'s guided
    sampling for multi-structure fitting). With K given it lowers the error on most seeds for the cost of a second
    pass; with K estimated it gains nothing, so it only runs when K is given (docs/experiments.md,
    ``refine_hypotheses``).

    Args:
        tracks_xy: (N, F, 2) positions (pixels); visible: (N, F) bool.
        views: model types fused by co-regularization ("fundamental", "homography", "affine").
        n_motions: number of motions K, or None to estimate it.
        config: settings (default TrajectoryConfig()).
        rng: random generator for hypotheses and k-means.

    Returns:
        (N,) int labels in [0, K).
    """
    config = config or TrajectoryConfig()
    rng = rng if rng is not None else np.random.default_rng()
    views = tuple(views)
    labels = _cluster_trajectories(trajectory_kernels(tracks_xy, visible, views, config, rng), n_motions, config,
                                   rng)
    if config.refine_hypotheses == 0 or n_motions is None:
        return labels
    k = int(labels.max()) + 1
    guided = trajectory_kernels(tracks_xy, visible, views, config, rng, groups=labels)
    return _cluster_trajectories(guided, k, config, rng)
