"""The 12-parameter quadratic instantaneous flow model, fitted per group (object, frame pair) by least squares.

    u = a + b x + c y + d x² + e xy + f y²,    v = g + h x + i y + j x² + k xy + l y²        (paper eq. 1)

with (x, y) pixel coordinates relative to the image centre. It is the Longuet-Higgins–Prazdny rigid-motion
field with the depth variation inside one object neglected.

Both the fit and the residual of every group under every model only need per-group sufficient statistics
(Σ φφᵀ, Σ φ uvᵀ, Σ |uv|², n with φ = (1, x, y, x², xy, y²)), so the flow vectors are read once and the
residual matrix costs O(groups × models), not O(vectors × models):

    MSE_k(P) = (Σ_k |uv|² − 2 tr(Pᵀ Σ_k φ uvᵀ) + tr(Pᵀ Σ_k φφᵀ P)) / n_k.

Internally x, y are divided by half the image's larger side so the normal equations are well conditioned;
parameters are returned in pixel units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

N_BASIS = 6
N_PARAMS = 12


@dataclass(frozen=True)
class FlowStats:
    """Sufficient statistics of flow vectors per group, in the scaled centred frame.

    Attributes:
        gram: (..., G, 6, 6) Σ φ φᵀ.
        cross: (..., G, 6, 2) Σ φ (u, v)ᵀ.
        energy: (..., G) Σ u² + v².
        count: (..., G) number of vectors.
        centre: (2,) image centre (pixels) the coordinates are relative to.
        scale: pixels per unit of the scaled frame.
    """

    gram: np.ndarray
    cross: np.ndarray
    energy: np.ndarray
    count: np.ndarray
    centre: np.ndarray
    scale: float

    def reshape(self, *shape: int) -> "FlowStats":
        """Same statistics with the group axis reshaped, e.g. (P*K,) -> (P, K) for pairs × objects."""
        return FlowStats(self.gram.reshape(*shape, N_BASIS, N_BASIS), self.cross.reshape(*shape, N_BASIS, 2),
                         self.energy.reshape(shape), self.count.reshape(shape), self.centre, self.scale)


def image_frame(image_size: tuple[int, int]) -> tuple[np.ndarray, float]:
    """Centre (pixels) and scale of the normalized frame of an image.

    Args:
        image_size: (width, height) W, H, both positive.

    Returns:
        centre (2,) ((W − 1)/2, (H − 1)/2) and scale max(W, H)/2 (pixels per unit).
    """
    width, height = image_size
    if width <= 0 or height <= 0:
        raise ValueError(f"image_size must be positive (width, height), got {image_size}")
    return np.array([(width - 1) / 2.0, (height - 1) / 2.0]), max(width, height) / 2.0


def quadratic_basis(xy: np.ndarray) -> np.ndarray:
    """φ(x, y) = (1, x, y, x², xy, y²) for (..., 2) centred coordinates -> (..., 6)."""
    x, y = xy[..., 0], xy[..., 1]
    return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)


def _monomial_scale(scale: float) -> np.ndarray:
    """Factor per basis function between scaled and pixel coordinates: p_scaled = p_pixel * s^degree."""
    return np.array([1.0, scale, scale, scale ** 2, scale ** 2, scale ** 2])


def _per_vector_terms(xy: np.ndarray, uv: np.ndarray, centre: np.ndarray, scale: float) -> np.ndarray:
    """(N, 36 + 12 + 2) products φφᵀ, φ uvᵀ, |uv|², 1 of every vector, to be summed per group."""
    phi = quadratic_basis((xy - centre) / scale)
    return np.concatenate([
        (phi[:, :, None] * phi[:, None, :]).reshape(-1, N_BASIS * N_BASIS),
        (phi[:, :, None] * uv[:, None, :]).reshape(-1, N_BASIS * 2),
        np.sum(uv * uv, axis=1, keepdims=True),
        np.ones((len(uv), 1)),
    ], axis=1)


def _stats_from_sums(sums: np.ndarray, centre: np.ndarray, scale: float) -> FlowStats:
    n_gram = N_BASIS * N_BASIS
    return FlowStats(gram=sums[:, :n_gram].reshape(-1, N_BASIS, N_BASIS),
                     cross=sums[:, n_gram:n_gram + 2 * N_BASIS].reshape(-1, N_BASIS, 2),
                     energy=sums[:, -2], count=sums[:, -1], centre=centre, scale=scale)


def _check_vectors(xy: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xy = np.asarray(xy, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or uv.shape != xy.shape:
        raise ValueError(f"xy and uv must both be (N, 2), got {xy.shape} and {uv.shape}")
    return xy, uv


def flow_statistics(xy: np.ndarray, uv: np.ndarray, groups: np.ndarray, n_groups: int,
                    image_size: tuple[int, int]) -> FlowStats:
    """Accumulate per-group statistics of flow vectors (each vector in at most one group).

    Args:
        xy: (N, 2) pixel positions (x = column, y = row) of the flow vectors.
        uv: (N, 2) flow vectors (pixels).
        groups: (N,) int group of each vector in [0, n_groups); negative = ignored.
        n_groups: number of groups G.
        image_size: (width, height); coordinates are taken relative to the image centre.

    Returns:
        FlowStats with a group axis of length G.
    """
    xy, uv = _check_vectors(xy, uv)
    groups = np.asarray(groups)
    if groups.shape != xy.shape[:1]:
        raise ValueError(f"groups must be ({len(xy)},), got {groups.shape}")
    if np.any(groups >= n_groups):
        raise ValueError(f"group ids must be < n_groups = {n_groups}")
    centre, scale = image_frame(image_size)
    keep = groups >= 0
    xy, uv, groups = xy[keep], uv[keep], groups[keep]
    # One sparse one-hot product sums every statistic of every group in a single pass over the vectors.
    onehot = scipy.sparse.csr_matrix((np.ones(len(groups)), (groups, np.arange(len(groups)))),
                                     shape=(n_groups, len(groups)))
    return _stats_from_sums(np.asarray(onehot @ _per_vector_terms(xy, uv, centre, scale)), centre, scale)


def fit_quadratic_flow(stats: FlowStats, *, min_vectors: int = 12,
                       cond_tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares quadratic flow model of every group.

    A group is degenerate (``valid`` False, parameters 0) with fewer than ``min_vectors`` vectors or when its
    normal matrix is ill-conditioned (smallest/largest eigenvalue < ``cond_tol``: e.g. all vectors on a line).

    (Σ φφᵀ) C = Σ φ (u, v)ᵀ for the (6, 2) coefficients C of each group, in the scaled frame.

    Args:
        stats: statistics with group axis (..., G).
        min_vectors: fewest vectors of a group for a model.
        cond_tol: smallest eigenvalue ratio of a group's normal matrix.

    Returns:
        params (..., G, 12) as (a, b, c, d, e, f, g, h, i, j, k, l) in pixel units relative to the centre;
        valid (..., G) bool.
    """
    gram = stats.gram
    ev = np.linalg.eigvalsh(gram)
    valid = (stats.count >= min_vectors) & (ev[..., 0] > cond_tol * np.maximum(ev[..., -1], 1e-300))
    safe = np.where(valid[..., None, None], gram, np.eye(N_BASIS))
    coef = np.linalg.solve(safe, stats.cross)  # (..., G, 6, 2) in the scaled frame
    coef = np.where(valid[..., None, None], coef, 0.0)
    pixel = coef / _monomial_scale(stats.scale)[:, None]
    return np.concatenate([pixel[..., 0], pixel[..., 1]], axis=-1), valid


def flow_residual_matrix(stats: FlowStats, params: np.ndarray) -> np.ndarray:
    """Mean squared error of every group's flow vectors under every model, from the statistics alone.

    MSE_gm = (Σ_g |uv|² − 2 tr(P_mᵀ Σ_g φ uvᵀ) + tr(P_mᵀ Σ_g φφᵀ P_m)) / n_g, P_m the (6, 2) coefficients of m.

    Args:
        stats: statistics with group axis (..., G).
        params: (..., M, 12) models in pixel units (as returned by fit_quadratic_flow); leading dimensions
            broadcast with the statistics' (e.g. one set of models per frame pair).

    Returns:
        (..., G, M) MSE in pixels²; NaN for groups without vectors.
    """
    params = np.asarray(params, dtype=np.float64)
    if params.shape[-1] != N_PARAMS:
        raise ValueError(f"params must end in {N_PARAMS}, got {params.shape}")
    P = np.stack([params[..., :N_BASIS], params[..., N_BASIS:]], axis=-1) * _monomial_scale(stats.scale)[:, None]
    cross_term = np.einsum("...gic,...mic->...gm", stats.cross, P)
    quad_term = np.einsum("...mic,...gij,...mjc->...gm", P, stats.gram, P)
    sse = stats.energy[..., None] - 2.0 * cross_term + quad_term
    with np.errstate(invalid="ignore", divide="ignore"):
        mse = np.maximum(sse, 0.0) / stats.count[..., None]
    return np.where(stats.count[..., None] > 0, mse, np.nan)


def predict_flow(params: np.ndarray, xy: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Flow of quadratic models at pixel positions: (u, v) = (φ(x − c) · p[:6], φ(x − c) · p[6:]).

    Args:
        params: (..., 12) models in pixel units relative to the image centre c.
        xy: (N, 2) pixel positions (x, y).
        image_size: (width, height).

    Returns:
        (..., N, 2) flow vectors in pixels.
    """
    centre, _ = image_frame(image_size)
    phi = quadratic_basis(np.asarray(xy, dtype=np.float64) - centre)
    params = np.asarray(params, dtype=np.float64)
    return np.stack([np.einsum("nb,...b->...n", phi, params[..., :N_BASIS]),
                     np.einsum("nb,...b->...n", phi, params[..., N_BASIS:])], axis=-1)
