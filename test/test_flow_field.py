"""Flow-field helpers of core/: the pixel grid and the forward-backward error; core/ stands without frontend/."""

from pathlib import Path

import numpy as np

from moseg_ros.core.flow_field import forward_backward_error, lands_inside, pixel_grid, shrink_scale

CORE = Path(__file__).resolve().parents[1] / "moseg_ros" / "core"


class TestShrinkScale:
    def test_a_wide_frame_is_shrunk_to_the_width(self):
        assert shrink_scale(375, 1242, 640, 128_000) == 640 / 1242  # KITTI at 640x193 holds 123,520 pixels

    def test_a_tall_frame_is_shrunk_to_the_pixel_count(self):
        scale = shrink_scale(480, 640, 640, 128_000)
        assert scale == np.sqrt(128_000 / (480 * 640))
        assert round(480 * scale) * round(640 * scale) < 1.001 * 128_000  # to the sides' rounding

    def test_no_side_below_the_least_unless_it_is_shorter(self):
        assert shrink_scale(40, 1242, 640, 0, 32) == 32 / 40  # not 640x21: DIS crashes on heights below 32
        assert shrink_scale(480, 640, 640, 100, 32) == 32 / 480 and shrink_scale(20, 640, 640, 0, 32) == 1.0

    def test_no_pixel_limit_and_never_enlarged(self):
        assert shrink_scale(480, 640, 640) == 1.0 and shrink_scale(480, 640, 640, 0) == 1.0
        assert shrink_scale(100, 200, 640, 128_000) == 1.0


class TestPixelGrid:
    def test_shape_values_and_step(self):
        grid = pixel_grid(4, 6)
        assert grid.shape == (4, 6, 2) and grid.dtype == np.float32
        assert tuple(grid[3, 5]) == (5.0, 3.0)
        assert pixel_grid(4, 6, 2).shape == (2, 3, 2) and tuple(pixel_grid(4, 6, 2)[1, 2]) == (4.0, 2.0)

    def test_cached_grids_are_read_only(self):
        assert pixel_grid(5, 5) is pixel_grid(5, 5) and not pixel_grid(5, 5).flags.writeable


class TestForwardBackwardError:
    def test_a_consistent_translation_has_no_error(self):
        forward = np.full((20, 30, 2), (2.0, -1.0), np.float32)
        error = forward_backward_error(forward, -forward)
        assert error.shape == (20, 30) and np.allclose(error[2:-2, 3:-3], 0.0, atol=1e-5)

    def test_a_mismatch_is_its_size_and_leaving_the_image_is_large(self):
        forward = np.full((20, 30, 2), (2.0, 0.0), np.float32)
        backward = np.full((20, 30, 2), (-1.0, 0.0), np.float32)  # comes back 1 px short
        error = forward_backward_error(forward, backward)
        assert np.allclose(error[5, 5], 1.0, atol=1e-5)
        assert error[5, 29] > 100  # lands outside the image


class TestLandsInside:
    def test_shape_and_a_still_flow_inside_the_margin(self):
        inside = lands_inside(np.zeros((20, 30, 2), np.float32), 3)
        assert inside.shape == (20, 30) and inside.dtype == bool
        assert inside[3:17, 3:27].all() and not inside[:3].any() and not inside[:, 27:].any()

    def test_a_pan_moves_the_excluded_band_to_where_matches_land_near_the_border(self):
        inside = lands_inside(np.full((20, 30, 2), (-10.0, 0.0), np.float32), 4)
        # x - 10 must be in [4, 25]: columns 14..29 (content at the left came from outside the view).
        assert not inside[10, :14].any() and inside[10, 14:].all()


def test_core_imports_nothing_from_the_front_end_or_ros():
    for path in CORE.glob("*.py"):
        text = path.read_text()
        assert "moseg_ros.frontend" not in text and "rclpy" not in text, path.name
