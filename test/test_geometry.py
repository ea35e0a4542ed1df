"""Known-answer tests of the two-view geometry (moseg_ros.core.geometry)."""

import cv2
import numpy as np
import pytest

from moseg_ros.core import geometry

K = np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])


def _project(points: np.ndarray) -> np.ndarray:
    p = points @ K.T
    return p[:, :2] / p[:, 2:]


def _two_views(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    R, _ = cv2.Rodrigues(np.array([0.02, 0.05, -0.01]))
    t = np.array([0.3, 0.05, 1.0])
    return _project(points), _project(points @ R.T + t)


@pytest.fixture
def scene() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    return _two_views(rng.uniform([-5, -3, 8], [5, 3, 20], (60, 3)))


def test_eight_point_exact_correspondences_have_zero_sampson(scene):
    x1, x2 = scene
    F, valid = geometry.fundamental_eight_point(x1, x2)
    assert valid.tolist() == [True]
    assert np.linalg.matrix_rank(F[0], tol=1e-9) == 2
    assert geometry.sampson_distance(F, x1, x2).max() < 1e-12


def test_minimal_eight_point_agrees_with_opencv(scene):
    x1, x2 = scene
    F, valid = geometry.fundamental_eight_point(x1[:8], x2[:8])
    ref, _ = cv2.findFundamentalMat(x1[:8], x2[:8], cv2.FM_8POINT)
    ref /= np.linalg.norm(ref)
    assert valid[0]
    assert min(np.abs(F[0] - ref).max(), np.abs(F[0] + ref).max()) < 1e-4
    assert geometry.sampson_distance(F, x1, x2).max() < 1e-9  # 8 points determine F for all 60


def test_sampson_distance_matches_hand_computation():
    F = np.array([[0.0, -1.0, 2.0], [1.0, 0.0, -3.0], [-2.0, 3.0, 0.5]])
    x1, x2 = np.array([[1.0, 2.0]]), np.array([[2.0, 1.0]])
    # F x1 = (0 - 2 + 2, 1 + 0 - 3, -2 + 6 + 0.5) = (0, -2, 4.5); x2ᵀ F x1 = 0 - 2 + 4.5 = 2.5
    # Fᵀ x2 = (0 + 1 - 2, -2 + 0 + 3, 4 - 3 + 0.5) = (-1, 1, 1.5); d = 2.5² / (0 + 4 + 1 + 1) = 6.25 / 6
    assert geometry.sampson_distance(F[None], x1, x2)[0, 0] == pytest.approx(6.25 / 6.0)


def test_sampson_distance_batches_over_models_and_pairs(scene):
    x1, x2 = scene
    rng = np.random.default_rng(1)
    models = rng.normal(size=(2, 5, 3, 3))
    batched = geometry.sampson_distance(models, np.stack([x1, x2]), np.stack([x2, x1]))
    assert batched.shape == (2, 5, 60)
    single = geometry.sampson_distance(models[1], x2, x1)
    assert np.allclose(batched[1], single)


def test_degenerate_fundamental_sets_are_flagged(scene):
    x1, x2 = scene
    rng = np.random.default_rng(2)
    planar = rng.uniform([-5, -3, 10], [5, 3, 10], (30, 3))
    p1, p2 = _two_views(planar)
    line = np.stack([np.linspace(0, 500, 20), np.linspace(10, 200, 20)], axis=1)
    few_weights = np.zeros(60)
    few_weights[:7] = 1.0
    _, valid = geometry.fundamental_eight_point(np.stack([p1[:30], line[[*range(20), *range(10)]], x1[:30]]),
                                                np.stack([p2[:30], line[[*range(20), *range(10)]] + 3.0, x2[:30]]),
                                                np.stack([np.ones(30), np.ones(30), few_weights[:30]]))
    assert valid.tolist() == [False, False, False]  # plane (F not unique), collinear points, 7 points


def test_homography_and_affine_recover_exact_maps(scene):
    x1, _ = scene
    H0 = np.array([[1.1, 0.05, 12.0], [-0.03, 0.95, -4.0], [1e-4, -2e-4, 1.0]])
    h = np.c_[x1, np.ones(60)] @ H0.T
    x2 = h[:, :2] / h[:, 2:]
    H, valid = geometry.homography_dlt(x1[:4], x2[:4])
    assert valid[0]
    assert geometry.homography_transfer_error(H, x1, x2).max() < 1e-12
    A0 = np.array([[1.1, 0.1, 5.0], [-0.2, 0.9, 3.0], [0.0, 0.0, 1.0]])
    xa = x1 @ A0[:2, :2].T + A0[:2, 2]
    A, valid = geometry.affine_fit(x1, xa)
    assert valid[0]
    assert np.allclose(A[0], A0, atol=1e-9)
    assert geometry.affine_transfer_error(A, x1, xa).max() < 1e-15


def test_collinear_homography_sample_is_degenerate():
    x1 = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 1.0]])
    _, valid = geometry.homography_dlt(x1, x1 + 1.0)
    assert not valid[0]


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="correspondences"):
        geometry.fundamental_eight_point(np.zeros((10, 3)), np.zeros((10, 3)))
    with pytest.raises(ValueError, match="weights"):
        geometry.fundamental_eight_point(np.zeros((10, 2)), np.zeros((10, 2)), np.ones(9))


class TestGric:
    def test_known_value(self):
        # rho = min(e^2 / sigma^2, 2 (r - d)) = [1, 2] for d = 3; + log(4) 3 n + log(8) k
        value = geometry.gric(np.array([1.0, 9.0]), 1.0, manifold_dim=3, parameters=7)
        assert value == pytest.approx(3.0 + np.log(4) * 6 + np.log(8) * 7)

    def test_homography_preferred_for_a_plane_and_not_for_depth(self):
        rng = np.random.default_rng(0)
        n = 300
        planar_f, planar_h = rng.normal(0, 0.3, n) ** 2, rng.normal(0, 0.3, n) ** 2
        assert geometry.homography_preferred(planar_f, planar_h, sigma=0.3)
        parallax_h = (rng.normal(0, 0.3, n) + rng.uniform(0, 4, n)) ** 2  # depth the homography cannot explain
        assert not geometry.homography_preferred(planar_f, parallax_h, sigma=0.3)
