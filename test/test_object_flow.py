"""The flow view around moving groups: affine flow models, their error fields, growing and trimming regions."""

from __future__ import annotations

import numpy as np

from moseg_ros.core.object_flow import ObjectFlowConfig, affine_flow_error, fit_affine_flows, refine_by_flow

A_OBJECT = np.array([[0.01, 0.0], [0.0, 0.01], [-3.0, 1.0]])  # a mover: its own translation, a little zoom
A_BACKGROUND = np.array([[0.0, 0.0], [0.0, 0.0], [2.0, 0.0]])  # the camera pans


def affine_field(params: np.ndarray, height: int, width: int) -> np.ndarray:
    y, x = np.mgrid[:height, :width].astype(np.float64)
    design = np.stack([x, y, np.ones_like(x)], axis=-1)
    return (design @ params).astype(np.float32)


class TestFitAffineFlows:
    def test_smoke_and_shape(self):
        xy = np.array([[0, 0], [10, 0], [0, 10], [10, 10]], dtype=np.float64)
        models = fit_affine_flows([xy, xy[:3]], [np.zeros((4, 2)), np.zeros((3, 2))])
        assert len(models) == 2 and all(model.shape == (3, 2) for model in models)

    def test_recovers_a_known_model(self):
        xy = np.random.default_rng(0).uniform(0, 200, size=(30, 2))
        uv = np.column_stack([xy, np.ones(30)]) @ A_OBJECT
        np.testing.assert_allclose(fit_affine_flows([xy], [uv])[0], A_OBJECT, atol=1e-9)

    def test_refit_ignores_gross_outliers(self):
        rng = np.random.default_rng(1)
        xy = rng.uniform(0, 200, size=(40, 2))
        uv = np.column_stack([xy, np.ones(40)]) @ A_OBJECT
        uv[:4] += 20.0  # four tracks slipped onto something else
        np.testing.assert_allclose(fit_affine_flows([xy], [uv])[0], A_OBJECT, atol=1e-9)

    def test_each_set_of_a_batch_gets_its_own_model(self):
        rng = np.random.default_rng(2)
        xy = [rng.uniform(0, 200, size=(n, 2)) for n in (40, 7, 25)]
        uv = [np.column_stack([points, np.ones(len(points))]) @ params
              for points, params in zip(xy, (A_OBJECT, A_BACKGROUND, A_OBJECT))]
        uv[0][:5] += 20.0  # outliers in one set must not move the others' models
        models = fit_affine_flows(xy, uv)
        for model, params in zip(models, (A_OBJECT, A_BACKGROUND, A_OBJECT)):
            np.testing.assert_allclose(model, params, atol=1e-9)

    def test_a_batch_fits_each_set_as_alone(self):
        """Sets of very different sizes (a group's few tracks beside its background's hundreds), noisy and with
        outliers, so that each set's own median decides its refit."""
        rng = np.random.default_rng(3)
        xy = [rng.uniform(0, 600, size=(n, 2)) for n in (500, 4, 9, 120)]
        uv = [np.column_stack([points, np.ones(len(points))]) @ A_OBJECT + rng.normal(0, 0.3, (len(points), 2))
              for points in xy]
        uv[0][:60] += 15.0
        uv[2][:2] -= 8.0
        together = fit_affine_flows(xy, uv)
        for points, flows, model in zip(xy, uv, together):
            np.testing.assert_allclose(model, fit_affine_flows([points], [flows])[0], atol=1e-9)
        design = np.column_stack([xy[0], np.ones(len(xy[0]))])
        assert np.abs(design @ together[0] - design @ A_OBJECT).max() < 0.1  # the outliers left out

    def test_collinear_or_too_few_points_give_no_model(self):
        line = np.column_stack([np.arange(10.0), 2.0 * np.arange(10.0)])
        square = np.array([[0, 0], [10, 0], [0, 10], [10, 10]], dtype=np.float64)
        models = fit_affine_flows([line, square[:2], square], [np.zeros((10, 2)), np.zeros((2, 2)), np.zeros((4, 2))])
        assert models[0] is None and models[1] is None
        np.testing.assert_allclose(models[2], 0.0, atol=1e-12)


class TestAffineFlowError:
    def test_zero_on_the_model_in_a_crop(self):
        field = affine_field(A_OBJECT, 60, 80)
        error = affine_flow_error(A_OBJECT, field[10:30, 20:50], 20, 10)
        assert error.shape == (20, 30) and error.dtype == np.float32
        np.testing.assert_allclose(error, 0.0, atol=1e-4)

    def test_known_offset(self):
        field = affine_field(A_BACKGROUND, 20, 20) + np.array([3.0, 4.0], dtype=np.float32)
        np.testing.assert_allclose(affine_flow_error(A_BACKGROUND, field, 0, 0), 5.0, atol=1e-4)


class TestRefineByFlow:
    H, W = 120, 200
    BODY = (slice(30, 90), slice(60, 140))  # the mover's pixels

    def scene(self, object_params: np.ndarray = A_OBJECT):
        """Dense flow of a panning camera with a mover in BODY, tracks on a grid: the mover's only on its left
        half, x 65-95 (a smooth body elsewhere), static ones everywhere else. The group's box then reaches
        15 px (half its width) around its tracks: x 50-110."""
        flow = affine_field(A_BACKGROUND, self.H, self.W)
        flow[self.BODY] = affine_field(object_params, self.H, self.W)[self.BODY]
        y, x = np.mgrid[5:self.H:10, 5:self.W:10]
        xy = np.column_stack([x.ravel(), y.ravel()]).astype(np.float64)
        on_body = (xy[:, 1] >= 30) & (xy[:, 1] < 90) & (xy[:, 0] >= 60) & (xy[:, 0] < 140)
        tracked = on_body & (xy[:, 0] < 100)
        keep = tracked | ~on_body
        xy, tracked = xy[keep], tracked[keep]
        uv = flow[xy[:, 1].astype(int), xy[:, 0].astype(int)].astype(np.float64)
        group = np.where(tracked, 0, -1)
        truth = np.zeros((self.H, self.W), dtype=bool)
        truth[self.BODY] = True
        return flow, xy, uv, group, truth

    def test_grows_over_the_smooth_body_within_reach(self):
        flow, xy, uv, group, truth = self.scene()
        hull = np.zeros_like(truth)
        hull[35:86, 65:96] = True  # the hull of the tracks on the left half
        refined = refine_by_flow(hull, flow, xy, uv, group, link_px=12.0)
        assert refined.shape == truth.shape and refined.dtype == bool
        assert refined[30:90, 60:110].all()
        assert not (refined & ~truth).any() and not refined[:, 111:].any()

    def test_pixels_the_object_model_does_not_explain_do_not_join(self):
        flow, xy, uv, group, truth = self.scene()
        flow[:, 100:] += np.float32(1.2)  # the body's right part fits its model only within 1.2 px
        hull = np.zeros_like(truth)
        hull[35:86, 65:96] = True
        refined = refine_by_flow(hull, flow, xy, uv, group, link_px=12.0)
        assert refined[30:90, 60:100].all() and not refined[:, 100:].any()

    def test_trims_background_the_hull_swallowed(self):
        flow, xy, uv, group, truth = self.scene()
        hull = np.zeros_like(truth)
        hull[35:86, 52:96] = True  # reaches 8 px left of the body, over the panning background
        refined = refine_by_flow(hull, flow, xy, uv, group, link_px=12.0)
        assert not refined[:, :60].any()
        assert refined[30:90, 60:110].all()

    def test_only_a_background_that_fits_its_model_is_trimmed(self):
        flow, xy, uv, group, truth = self.scene()
        flow[:, 50:60] += 0.7  # the background beside the body fits its model only within 0.7 px
        hull = np.zeros_like(truth)
        hull[35:86, 52:96] = True
        refined = refine_by_flow(hull, flow, xy, uv, group, link_px=12.0)
        assert refined[35:86, 52:60].all()

    def test_nothing_changes_where_the_two_models_agree(self):
        flow, xy, uv, group, truth = self.scene(object_params=A_BACKGROUND)
        hull = np.zeros_like(truth)
        hull[35:86, 52:96] = True
        np.testing.assert_array_equal(refine_by_flow(hull, flow, xy, uv, group, link_px=12.0), hull)

    def test_a_group_that_was_not_drawn_is_left_out(self):
        flow, xy, uv, group, truth = self.scene()
        empty = np.zeros_like(truth)
        assert not refine_by_flow(empty, flow, xy, uv, group, link_px=12.0).any()

    def test_too_few_background_tracks_leave_the_hull_as_drawn(self):
        flow, xy, uv, group, truth = self.scene()
        hull = np.zeros_like(truth)
        hull[35:86, 52:96] = True
        config = ObjectFlowConfig(min_background=10_000)
        np.testing.assert_array_equal(refine_by_flow(hull, flow, xy, uv, group, 12.0, config), hull)
