"""core/robust.py: OpenCV's robust fits, with a failure inside OpenCV reported as no model."""

import cv2
import numpy as np
import pytest

from moseg_ros.core import robust
from moseg_ros.core.baseline import epipolar_residual
from moseg_ros.core.track_motion import pair_evidence


def _rigid_pair(n: int = 200, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = np.c_[rng.uniform(-5, 5, (n, 2)), rng.uniform(4, 20, n)]
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    project = lambda P: (P @ K.T)[:, :2] / P[:, 2:3]  # noqa: E731
    return project(X), project(X + [0.3, 0.0, 0.5])


def _raise(*_args, **_kwargs):
    raise cv2.error("(-215:Assertion failed) !model.empty() in function 'setModelParameters'")


class TestFundamentalRansac:
    def test_known_motion(self):
        x1, x2 = _rigid_pair()
        F, inliers = robust.fundamental_ransac(x1, x2, cv2.USAC_MAGSAC, 1.0)
        assert F.shape == (3, 3) and inliers.dtype == bool and inliers.shape == (200,)
        assert inliers.mean() > 0.95
        residual = np.abs(np.sum(np.c_[x2, np.ones(200)] * (np.c_[x1, np.ones(200)] @ F.T), axis=1))
        assert np.median(residual / np.linalg.norm(F)) < 1e-2

    def test_too_few_points(self):
        x1, x2 = _rigid_pair(5)
        assert robust.fundamental_ransac(x1, x2, cv2.USAC_MAGSAC, 1.0) == (None, None)

    def test_opencv_failure_is_no_model(self, monkeypatch):
        monkeypatch.setattr(cv2, "findFundamentalMat", _raise)
        x1, x2 = _rigid_pair()
        assert robust.fundamental_ransac(x1, x2, cv2.USAC_MAGSAC, 1.0) == (None, None)


class TestFundamentalPolished:
    @staticmethod
    def noisy_pair(seed: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A rigid pair with 0.2 px noise and a fifth of the matches thrown far off (and which those are)."""
        x1, x2 = _rigid_pair(1000, seed)
        rng = np.random.default_rng(seed)
        x2 = x2 + rng.normal(0, 0.2, x2.shape)
        outliers = rng.random(1000) < 0.2
        x2[outliers] += rng.uniform(-40, 40, (outliers.sum(), 2))
        return x1.astype(np.float32), x2.astype(np.float32), outliers

    def test_shapes(self):
        x1, x2, _ = self.noisy_pair()
        F, inliers = robust.fundamental_polished(x1, x2, 0.5)
        assert F.shape == (3, 3) and inliers.shape == (1000,) and inliers.dtype == bool

    def test_inliers_are_the_rigid_matches(self):
        x1, x2, outliers = self.noisy_pair()
        _, inliers = robust.fundamental_polished(x1, x2, 0.5)
        assert inliers[outliers].mean() < 0.05  # an outlier thrown along its epipolar line stays an inlier
        assert inliers[~outliers].mean() > 0.9

    def test_mostly_outliers_go_to_magsac_and_the_rigid_matches_are_still_found(self, monkeypatch):
        """Seven tenths thrown off: plain RANSAC's few iterations find less than ``min_share``, MAGSAC++ decides."""
        x1, x2 = _rigid_pair(1500, 4)
        rng = np.random.default_rng(0)
        outliers = rng.random(1500) < 0.7
        x2 = x2 + rng.normal(0, 0.2, x2.shape)
        x2[outliers] += rng.uniform(-40, 40, (outliers.sum(), 2))
        methods = []
        plain = robust.fundamental_ransac
        monkeypatch.setattr(robust, "fundamental_ransac", lambda *a, **k: methods.append(a[2]) or plain(*a, **k))
        _, inliers = robust.fundamental_polished(x1.astype(np.float32), x2.astype(np.float32), 1.0)
        assert cv2.USAC_MAGSAC in methods
        assert inliers[~outliers].mean() > 0.95 and inliers[outliers].mean() < 0.1

    def test_the_refits_hold_at_least_the_ransac_inliers(self):
        x1, x2, _ = self.noisy_pair(3)
        _, plain = robust.fundamental_polished(x1, x2, 0.5, rounds=0)
        _, polished = robust.fundamental_polished(x1, x2, 0.5)
        assert polished.sum() >= plain.sum()

    def test_no_model_from_plain_ransac_goes_to_magsac(self, monkeypatch):
        x1, x2 = _rigid_pair()
        plain = robust.fundamental_ransac
        monkeypatch.setattr(robust, "fundamental_ransac",
                            lambda *a, **k: (None, None) if a[2] == cv2.FM_RANSAC else plain(*a, **k))
        F, inliers = robust.fundamental_polished(x1, x2, 0.5)
        assert F is not None and inliers.mean() > 0.95

    def test_too_few_points_and_opencv_failure(self, monkeypatch):
        x1, x2 = _rigid_pair(5)
        assert robust.fundamental_polished(x1, x2, 0.5) == (None, None)
        monkeypatch.setattr(cv2, "findFundamentalMat", _raise)
        x1, x2 = _rigid_pair()
        assert robust.fundamental_polished(x1, x2, 0.5) == (None, None)


class TestHomographyRansac:
    def test_known_homography(self):
        rng = np.random.default_rng(1)
        H = np.array([[1.01, 0.02, 3.0], [-0.01, 0.99, -2.0], [1e-5, 0.0, 1.0]])
        x1 = rng.uniform(0, 600, (100, 2))
        x2 = cv2.perspectiveTransform(x1[None], H)[0]
        found, inliers = robust.homography_ransac(x1, x2, cv2.USAC_MAGSAC, 1.0)
        assert inliers.all()
        np.testing.assert_allclose(found / found[2, 2], H, atol=1e-4)

    def test_opencv_failure_is_no_model(self, monkeypatch):
        monkeypatch.setattr(cv2, "findHomography", _raise)
        x1, x2 = _rigid_pair()
        assert robust.homography_ransac(x1, x2, cv2.USAC_MAGSAC, 1.0) == (None, None)


class TestCallersSurviveOpenCVFailures:
    """A raising estimator gives the callers 'no model', not an exception (a frame with a failed status)."""

    def test_pair_evidence(self, monkeypatch):
        x1, x2 = _rigid_pair()
        assert pair_evidence(x1, x2) is not None
        monkeypatch.setattr(cv2, "findFundamentalMat", _raise)
        assert pair_evidence(x1, x2) is None

    def test_pair_evidence_without_homography_keeps_f(self, monkeypatch):
        x1, x2 = _rigid_pair()
        monkeypatch.setattr(cv2, "findHomography", _raise)
        distance = pair_evidence(x1, x2).distance
        assert np.median(distance) < 0.1

    @pytest.mark.parametrize("estimator", ["findFundamentalMat", "findHomography"])
    def test_epipolar_residual(self, monkeypatch, estimator):
        yy, xx = np.mgrid[0:120, 0:160].astype(np.float32)
        backward = np.stack([(xx - 80) * 0.05, (yy - 60) * 0.05 + 0.002 * xx], axis=-1)
        monkeypatch.setattr(cv2, estimator, _raise)
        evidence = epipolar_residual(backward, -backward)
        assert evidence.residual.shape == (120, 160)
