"""Two-view geometry, batched: fundamental matrices, homographies, affinities and their residuals.

Every fit takes a batch of correspondence sets ``x1, x2`` of shape (B, N, 2) (pixel coordinates, x = column,
y = row) with optional per-point ``weights`` (B, N) (0 = not part of the set), so many models (random minimal
samples, or one model per object) are fitted in one vectorized call. Every residual takes models (..., M, 3, 3)
and correspondences (..., N, 2) and returns an (..., M, N) matrix: each model against each correspondence.

References: Hartley and Zisserman, *Multiple View Geometry*, 2nd ed. (HZ): normalized eight-point algorithm
(Alg. 11.1), Sampson distance (eq. 11.9), DLT for homographies (Alg. 4.2), affine least squares (§4.2.5).
"""

from __future__ import annotations

import numpy as np

MINIMAL_SAMPLE = {"fundamental": 8, "homography": 4, "affine": 3}
"""Points in a minimal sample of each model (the eight-point algorithm, not the seven-point one)."""

_DEFAULT_COND_TOL = 1e-6
_DEFAULT_COLLINEAR_TOL = 1e-3


def _as_batch(x1: np.ndarray, x2: np.ndarray, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    if x1.ndim == 2:
        x1, x2 = x1[None], x2[None]
        weights = None if weights is None else np.asarray(weights)[None]
    if x1.ndim != 3 or x1.shape[-1] != 2 or x1.shape != x2.shape:
        raise ValueError(f"correspondences must be (B, N, 2) or (N, 2) and equal in shape, got {x1.shape} and "
                         f"{x2.shape}")
    if weights is None:
        weights = np.ones(x1.shape[:2])
    weights = np.asarray(weights, dtype=np.float64)
    if weights.shape != x1.shape[:2]:
        raise ValueError(f"weights must be {x1.shape[:2]}, got {weights.shape}")
    if np.any(weights < 0):
        raise ValueError("weights must be non-negative")
    return x1, x2, weights


def hartley_normalization(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Similarity T per set that moves the weighted centroid to 0 and the mean distance to √2 (HZ §4.4.4).

    Args:
        x: (B, N, 2) points.
        weights: (B, N) non-negative weights.

    Returns:
        (B, 3, 3) transforms acting on homogeneous column vectors.
    """
    wsum = np.maximum(weights.sum(axis=1), 1e-12)
    centroid = np.einsum("bn,bnc->bc", weights, x) / wsum[:, None]
    dist = np.linalg.norm(x - centroid[:, None, :], axis=-1)
    mean_dist = np.einsum("bn,bn->b", weights, dist) / wsum
    scale = np.sqrt(2.0) / np.maximum(mean_dist, 1e-12)
    T = np.zeros((x.shape[0], 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = scale
    T[:, :2, 2] = -scale[:, None] * centroid
    T[:, 2, 2] = 1.0
    return T


def _apply(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Apply (B, 3, 3) affine-normalizing transforms to (B, N, 2) points."""
    return x @ np.swapaxes(T[:, :2, :2], 1, 2) + T[:, None, :2, 2]


def _collinear(x: np.ndarray, weights: np.ndarray, tol: float) -> np.ndarray:
    """True where the weighted points of a set lie (nearly) on a line: small/large covariance eigenvalue < tol."""
    wsum = np.maximum(weights.sum(axis=1), 1e-12)
    centroid = np.einsum("bn,bnc->bc", weights, x) / wsum[:, None]
    d = x - centroid[:, None, :]
    cov = (np.swapaxes(d * weights[..., None], 1, 2) @ d) / wsum[:, None, None]
    return flat_covariance(cov, tol)


def flat_covariance(cov: np.ndarray, tol: float = _DEFAULT_COLLINEAR_TOL) -> np.ndarray:
    """(B,) bool: True where a (B, 2, 2) covariance (or scatter) of points is that of points (nearly) on a line,
    its small eigenvalue below ``tol`` times its large one."""
    # Closed-form eigenvalues of the symmetric 2x2 covariance.
    half_trace = 0.5 * (cov[:, 0, 0] + cov[:, 1, 1])
    radius = np.sqrt(0.25 * (cov[:, 0, 0] - cov[:, 1, 1]) ** 2 + cov[:, 0, 1] ** 2)
    return half_trace - radius <= tol * np.maximum(half_trace + radius, 1e-300)


def _null_vector_exact(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Null vector of each (B, 8, 9) system by Gaussian elimination with complete pivoting.

    Minimal samples give exactly determined systems; elimination vectorized over the batch is several times
    faster than numpy's batched SVD of tiny matrices (LAPACK is called once per matrix). Complete pivoting
    keeps it stable whichever unknown is zero and makes the last/first pivot ratio a rank indicator.

    Returns:
        (B, 9) unit null vectors and (B,) |last pivot| / |first pivot|.
    """
    a = np.array(A, dtype=np.float64, copy=True)
    b, rows, cols = a.shape
    bi = np.arange(b)
    perm = np.broadcast_to(np.arange(cols), (b, cols)).copy()
    first = np.ones(b)
    for k in range(rows):
        pi, pj = np.divmod(np.abs(a[:, k:, k:]).reshape(b, -1).argmax(axis=1), cols - k)
        pi += k
        pj += k
        a[bi, k], a[bi, pi] = a[bi, pi], a[bi, k].copy()
        a[bi, :, k], a[bi, :, pj] = a[bi, :, pj], a[bi, :, k].copy()
        perm[bi, k], perm[bi, pj] = perm[bi, pj], perm[bi, k].copy()
        piv = a[:, k, k]
        if k == 0:
            first = np.abs(piv)
        safe = np.where(piv == 0.0, 1.0, piv)
        a[:, k + 1:, k:] -= (a[:, k + 1:, k] / safe[:, None])[:, :, None] * a[:, k, None, k:]
    last = np.abs(a[:, rows - 1, rows - 1])
    y = np.zeros((b, cols))
    y[:, rows] = 1.0  # the unknown left without a pivot is free
    for k in range(rows - 1, -1, -1):
        d = a[:, k, k]
        y[:, k] = -np.einsum("bj,bj->b", a[:, k, k + 1:], y[:, k + 1:]) / np.where(d == 0.0, 1.0, d)
    out = np.empty_like(y)
    np.put_along_axis(out, perm, y, axis=1)
    return out / np.linalg.norm(out, axis=1, keepdims=True), last / np.maximum(first, 1e-300)


def _null_vector(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares null vector of each (B, R, 9) system (R >= 8) and a rank indicator in [0, 1].

    Exactly determined systems (R = 8) use elimination; overdetermined ones the right singular vector of the
    smallest singular value (rank indicator: 8-th / 1-st singular value).
    """
    if A.shape[1] == A.shape[2] - 1:
        return _null_vector_exact(A)
    if A.shape[1] < A.shape[2] - 1:
        A = np.concatenate([A, np.zeros((A.shape[0], A.shape[2] - 1 - A.shape[1], A.shape[2]))], axis=1)
        return _null_vector_exact(A)
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    return vt[:, -1, :], s[:, 7] / np.maximum(s[:, 0], 1e-300)


def _enforce_rank2(F: np.ndarray) -> np.ndarray:
    """Closest rank-2 matrices in Frobenius norm: F (I − v vᵀ), v the right singular vector of the smallest
    singular value (the eigenvector of FᵀF of its smallest eigenvalue; cheaper than a batched 3x3 SVD)."""
    _, vec = np.linalg.eigh(np.swapaxes(F, 1, 2) @ F)
    v = vec[:, :, 0]
    return F - (F @ v[:, :, None]) * v[:, None, :]


def fundamental_eight_point(x1: np.ndarray, x2: np.ndarray, weights: np.ndarray | None = None, *,
                            cond_tol: float = _DEFAULT_COND_TOL,
                            collinear_tol: float = _DEFAULT_COLLINEAR_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Normalized eight-point fundamental matrices with x2ᵀ F x1 = 0 (HZ Alg. 11.1), with degeneracy flags.

    A set is degenerate (``valid`` False) when it has fewer than 8 points of positive weight, its points are
    near-collinear in either image (covariance eigenvalue ratio < ``collinear_tol``), or the normalized linear
    system's rank indicator (8-th / 1-st singular value; last / first pivot for exactly 8 points) is below
    ``cond_tol``, i.e. the solution is not unique (e.g. all points on one plane seen under a homography).

    Args:
        x1, x2: (B, N, 2) or (N, 2) correspondences, first and second image.
        weights: (B, N) or (N,) non-negative point weights (None = all 1).

    Returns:
        F (B, 3, 3) rank-2, unit Frobenius norm; valid (B,) bool. A batch of one is kept as B = 1.
    """
    x1, x2, w = _as_batch(x1, x2, weights)
    T1, T2 = hartley_normalization(x1, w), hartley_normalization(x2, w)
    p, q = _apply(T1, x1), _apply(T2, x2)
    # Row of the linear system q^T F p = 0 with F stored row-major (HZ eq. 11.3).
    A = np.concatenate([q[..., :1] * p, q[..., :1], q[..., 1:] * p, q[..., 1:], p, np.ones_like(p[..., :1])],
                       axis=-1) * np.sqrt(w)[..., None]
    f, rank = _null_vector(A)
    Fn = _enforce_rank2(f.reshape(-1, 3, 3))
    F = np.swapaxes(T2, 1, 2) @ Fn @ T1
    F /= np.maximum(np.linalg.norm(F, axis=(1, 2)), 1e-300)[:, None, None]
    valid = ((w > 0).sum(axis=1) >= 8) & (rank > cond_tol)
    valid &= ~_collinear(p, w, collinear_tol) & ~_collinear(q, w, collinear_tol)
    return F, valid


def homography_dlt(x1: np.ndarray, x2: np.ndarray, weights: np.ndarray | None = None, *,
                   cond_tol: float = _DEFAULT_COND_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Normalized DLT homographies with x2 ~ H x1 (HZ Alg. 4.2), with degeneracy flags.

    Degenerate (``valid`` False): fewer than 4 points, a rank-deficient linear system (rank indicator as in
    fundamental_eight_point below ``cond_tol``: e.g. three of four points collinear), or a near-singular H.

    Args:
        x1, x2: (B, N, 2) or (N, 2) correspondences.
        weights: (B, N) or (N,) non-negative point weights (None = all 1).

    Returns:
        H (B, 3, 3) with unit Frobenius norm; valid (B,) bool.
    """
    x1, x2, w = _as_batch(x1, x2, weights)
    T1, T2 = hartley_normalization(x1, w), hartley_normalization(x2, w)
    p, q = _apply(T1, x1), _apply(T2, x2)
    ph = np.concatenate([p, np.ones_like(p[..., :1])], axis=-1)
    zero = np.zeros_like(ph)
    # Two rows per correspondence of q × (H p) = 0 (HZ eq. 4.3).
    r1 = np.concatenate([zero, -ph, q[..., 1:] * ph], axis=-1)
    r2 = np.concatenate([ph, zero, -q[..., :1] * ph], axis=-1)
    sw = np.sqrt(w)[..., None]
    A = np.concatenate([r1 * sw, r2 * sw], axis=1)
    h, rank = _null_vector(A)
    Hn = h.reshape(-1, 3, 3)
    H = np.linalg.inv(T2) @ Hn @ T1
    H /= np.maximum(np.linalg.norm(H, axis=(1, 2)), 1e-300)[:, None, None]
    # |det| of a unit-norm 3x3 matrix is at most 3^-3/2; far below that H is (near) singular.
    valid = ((w > 0).sum(axis=1) >= 4) & (rank > cond_tol) & (np.abs(np.linalg.det(Hn)) > cond_tol)
    return H, valid


def affine_fit(x1: np.ndarray, x2: np.ndarray, weights: np.ndarray | None = None, *,
               collinear_tol: float = _DEFAULT_COLLINEAR_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares affine maps x2 = M x1 + t (HZ §4.2.5), as 3x3 matrices with last row (0, 0, 1).

    Degenerate (``valid`` False): fewer than 3 points or near-collinear points in the first image.

    Args:
        x1, x2: (B, N, 2) or (N, 2) correspondences.
        weights: (B, N) or (N,) non-negative point weights (None = all 1).

    Returns:
        A (B, 3, 3); valid (B,) bool.
    """
    x1, x2, w = _as_batch(x1, x2, weights)
    T1, T2 = hartley_normalization(x1, w), hartley_normalization(x2, w)
    p, q = _apply(T1, x1), _apply(T2, x2)
    ph = np.concatenate([p, np.ones_like(p[..., :1])], axis=-1)
    wph = np.swapaxes(ph * w[..., None], 1, 2)
    gram = wph @ ph
    rhs = wph @ q
    collinear = _collinear(p, w, collinear_tol)
    gram[collinear] = np.eye(3)
    sol = np.linalg.solve(gram, rhs)
    An = np.zeros((x1.shape[0], 3, 3))
    An[:, :2, :] = np.swapaxes(sol, 1, 2)
    An[:, 2, 2] = 1.0
    A = np.linalg.inv(T2) @ An @ T1
    valid = ((w > 0).sum(axis=1) >= 3) & ~collinear
    return A, valid


def to_homogeneous(x: np.ndarray) -> np.ndarray:
    """(..., 2) -> (..., 3) with a trailing 1."""
    return np.concatenate([x, np.ones_like(x[..., :1])], axis=-1)


def _apply_models(M: np.ndarray, h: np.ndarray, transpose: bool = False) -> np.ndarray:
    """(M_m h_n) for models (..., M, 3, 3) and homogeneous points (..., N, 3) -> (..., N, M, 3).

    The models are stacked side by side so the product is one matrix multiplication (per leading index)
    instead of M small ones.
    """
    lead = M.shape[:-3]
    m = M.shape[-3]
    # stacked[..., j, m*3 + i] = M[..., m, i, j] (or M[..., m, j, i] for the transpose)
    order = (*range(len(lead)), len(lead) + 1, len(lead), len(lead) + 2) if transpose else \
        (*range(len(lead)), len(lead) + 2, len(lead), len(lead) + 1)
    stacked = np.transpose(M, order).reshape(*lead, 3, 3 * m)
    out = h @ stacked
    return out.reshape(*out.shape[:-1], m, 3)


def sampson_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """First-order geometric error of correspondences under fundamental matrices (HZ eq. 11.9).

    d(x, x') = (x'ᵀ F x)² / ((F x)₁² + (F x)₂² + (Fᵀ x')₁² + (Fᵀ x')₂²)

    Args:
        F: (..., M, 3, 3) models.
        x1, x2: (..., N, 2) correspondences; leading dimensions broadcast with F's.

    Returns:
        (..., M, N) squared distances (pixels² when x is in pixels).
    """
    F = np.asarray(F, dtype=np.float64)
    h1 = to_homogeneous(np.asarray(x1, dtype=np.float64))
    h2 = to_homogeneous(np.asarray(x2, dtype=np.float64))
    Fx1 = _apply_models(F, h1)  # (..., N, M, 3)
    Ftx2 = _apply_models(F, h2, transpose=True)
    num = (h2[..., :, None, 0] * Fx1[..., 0] + h2[..., :, None, 1] * Fx1[..., 1] + Fx1[..., 2]) ** 2
    den = Fx1[..., 0] ** 2 + Fx1[..., 1] ** 2 + Ftx2[..., 0] ** 2 + Ftx2[..., 1] ** 2
    return np.swapaxes(num / np.maximum(den, 1e-300), -1, -2)


def _transfer_error(H: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """||x2 - H x1||² for maps (..., M, 3, 3) and points (..., N, 2) -> (..., N, M)."""
    y = _apply_models(H, to_homogeneous(x1))
    w = y[..., 2]
    w = np.where(np.abs(w) < 1e-12, np.copysign(1e-12, w), w)
    return (y[..., 0] / w - x2[..., :, None, 0]) ** 2 + (y[..., 1] / w - x2[..., :, None, 1]) ** 2


def homography_transfer_error(H: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Symmetric transfer error ||x2 - H x1||² + ||x1 - H⁻¹ x2||² (HZ eq. 4.7).

    Args:
        H: (..., M, 3, 3) invertible homographies.
        x1, x2: (..., N, 2) correspondences.

    Returns:
        (..., M, N) squared errors.
    """
    H = np.asarray(H, dtype=np.float64)
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    err = _transfer_error(H, x1, x2) + _transfer_error(np.linalg.inv(H), x2, x1)
    return np.swapaxes(err, -1, -2)


def affine_transfer_error(A: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Forward transfer error ||x2 - (M x1 + t)||² of affine maps.

    Args:
        A: (..., M, 3, 3) affine maps (last row 0, 0, 1).
        x1, x2: (..., N, 2) correspondences.

    Returns:
        (..., M, N) squared errors.
    """
    A = np.asarray(A, dtype=np.float64)
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    return np.swapaxes(_transfer_error(A, x1, x2), -1, -2)


FIT = {"fundamental": fundamental_eight_point, "homography": homography_dlt, "affine": affine_fit}
RESIDUAL = {"fundamental": sampson_distance, "homography": homography_transfer_error,
            "affine": affine_transfer_error}
"""Fit and residual function of each model name, for code that is generic over the model."""


def gric(squared_errors: np.ndarray, sigma: float, manifold_dim: int, parameters: int,
         data_dim: int = 4) -> float:
    """Torr's Geometric Robust Information Criterion of one model (lower is better).

    GRIC = sum rho(e^2 / sigma^2) + log(r) d n + log(r n) k, rho(x) = min(x, 2 (r - d)); r = 4 for two-view
    correspondences, d = 3, k = 7 for F and d = 2, k = 8 for a homography (Torr, 'An assessment of
    information criteria for motion model selection', CVPR 1997).
    """
    n = len(squared_errors)
    rho = np.minimum(np.asarray(squared_errors, dtype=np.float64) / sigma ** 2, 2.0 * (data_dim - manifold_dim))
    return float(rho.sum() + np.log(data_dim) * manifold_dim * n + np.log(data_dim * n) * parameters)


def homography_preferred(f_squared: np.ndarray, h_squared: np.ndarray, sigma: float) -> bool:
    """Whether GRIC prefers the homography (d = 2, k = 8) over F (d = 3, k = 7) for the same correspondences."""
    return gric(h_squared, sigma, 2, 8) < gric(f_squared, sigma, 3, 7)
