"""Known-answer tests of the quadratic flow model (moseg_ros.core.flow_model)."""

import numpy as np
import pytest

from moseg_ros.core import flow_model

SIZE = (640, 480)


def _field(rng: np.random.Generator, n_models: int) -> np.ndarray:
    # Pixel-unit parameters of realistic size: constant ~ px, linear ~ 1e-2, quadratic ~ 1e-5.
    return rng.normal(size=(n_models, 12)) * np.array([2.0, 1e-2, 1e-2, 1e-5, 1e-5, 1e-5] * 2)


def test_fit_recovers_exact_parameters_per_group():
    rng = np.random.default_rng(0)
    truth = _field(rng, 3)
    xy = rng.uniform([0, 0], SIZE, (3000, 2))
    groups = rng.integers(0, 3, 3000)
    uv = flow_model.predict_flow(truth, xy, SIZE)[groups, np.arange(3000)]
    stats = flow_model.flow_statistics(xy, uv, groups, 3, SIZE)
    params, valid = flow_model.fit_quadratic_flow(stats)
    assert valid.all()
    assert np.allclose(params, truth, rtol=1e-8, atol=1e-12)


def test_parameters_are_relative_to_the_image_centre():
    # A pure constant flow (a = 3, g = -1) and a pure rotation about the centre have the expected parameters.
    xy = np.random.default_rng(1).uniform([0, 0], SIZE, (500, 2))
    centred = xy - np.array([(SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2])
    uv = np.stack([3.0 - 0.01 * centred[:, 1], -1.0 + 0.01 * centred[:, 0]], axis=1)
    params, _ = flow_model.fit_quadratic_flow(flow_model.flow_statistics(xy, uv, np.zeros(500, int), 1, SIZE))
    expected = np.zeros(12)
    expected[[0, 2, 6, 7]] = [3.0, -0.01, -1.0, 0.01]
    assert np.allclose(params[0], expected, atol=1e-10)


def test_residual_matrix_equals_direct_mean_squared_error():
    rng = np.random.default_rng(2)
    truth = _field(rng, 4)
    xy = rng.uniform([0, 0], SIZE, (2000, 2))
    groups = rng.integers(0, 4, 2000)
    uv = flow_model.predict_flow(truth, xy, SIZE)[groups, np.arange(2000)] + rng.normal(0, 0.5, (2000, 2))
    stats = flow_model.flow_statistics(xy, uv, groups, 4, SIZE)
    params, _ = flow_model.fit_quadratic_flow(stats)
    residuals = flow_model.flow_residual_matrix(stats, params)
    err = np.sum((flow_model.predict_flow(params, xy, SIZE) - uv[None]) ** 2, axis=-1)  # (models, vectors)
    direct = np.array([[err[m, groups == k].mean() for m in range(4)] for k in range(4)])
    assert np.allclose(residuals, direct, rtol=1e-7)
    assert np.allclose(np.diag(residuals), 2 * 0.25, rtol=0.2)  # own model: the noise, 2 components × σ²


def test_degenerate_groups_are_flagged_and_batched_shapes_broadcast():
    rng = np.random.default_rng(3)
    xy = np.concatenate([rng.uniform([0, 0], SIZE, (100, 2)), np.stack([np.arange(50.0), np.full(50, 7.0)], 1),
                         rng.uniform([0, 0], SIZE, (5, 2))])
    groups = np.repeat([0, 1, 2], [100, 50, 5])
    stats = flow_model.flow_statistics(xy, rng.normal(size=(155, 2)), groups, 4, SIZE)
    params, valid = flow_model.fit_quadratic_flow(stats)
    assert valid.tolist() == [True, False, False, False]  # full, on a line, 5 vectors, empty
    assert np.all(params[~valid] == 0)
    assert np.isnan(flow_model.flow_residual_matrix(stats, params)[3]).all()
    paired = stats.reshape(2, 2)
    assert flow_model.flow_residual_matrix(paired, params.reshape(2, 2, 12)).shape == (2, 2, 2)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="group ids"):
        flow_model.flow_statistics(np.zeros((3, 2)), np.zeros((3, 2)), np.array([0, 1, 5]), 2, SIZE)
    with pytest.raises(ValueError, match="image_size"):
        flow_model.flow_statistics(np.zeros((3, 2)), np.zeros((3, 2)), np.zeros(3, int), 1, (0, 10))
