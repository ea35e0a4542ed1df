"""Decisions -> masks: ids kept, margins grown, polarity and size."""

import cv2
import numpy as np

from moseg_ros.render import render_masks


def _full_image_growth(labels: np.ndarray, margin_px: int) -> np.ndarray:
    """The margin's definition: every id dilated over the whole image, labelled pixels kept."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
    grown = cv2.dilate(labels.astype(np.float32), kernel).astype(np.int32)
    return np.where(labels > 0, labels, grown)


class TestRenderMasks:
    def test_smoke_nothing_dynamic(self):
        masks = render_masks(np.zeros((20, 30), np.int32), np.zeros(0, np.int32), (20, 30), margin_px=3)
        assert not masks.dynamic.any() and (masks.static == 255).all() and not masks.instance_labels.any()

    def test_shapes_and_polarity_at_the_input_size(self):
        instances = np.zeros((10, 20), np.int32)
        instances[2:5, 3:8] = 4
        masks = render_masks(instances, np.array([4], np.int32), (40, 80))
        assert masks.dynamic.shape == masks.static.shape == masks.instance_labels.shape == (40, 80)
        assert masks.dynamic.dtype == np.uint8 and masks.instance_labels.dtype == np.int32
        assert ((masks.dynamic == 255) == (masks.instance_labels == 4)).all()
        assert (masks.static == 255 - masks.dynamic).all()
        assert masks.dynamic.sum() == 255 * 12 * 20

    def test_only_dynamic_ids_are_painted(self):
        instances = np.zeros((10, 10), np.int32)
        instances[1:3, 1:3], instances[6:9, 6:9] = 2, 5
        masks = render_masks(instances, np.array([5, 99], np.int32), (10, 10))
        assert set(np.unique(masks.instance_labels)) == {0, 5}

    def test_ids_keep_their_values_whatever_their_rank(self):
        """A few ids (ranked in a byte) beyond 255 and out of order come out as themselves; ids <= 0 are none."""
        rng = np.random.default_rng(3)
        for dynamic in (np.array([300, 7, 70], np.int32), np.array([2**31 - 1, 300, 7], np.int32)):  # table, search
            instances = rng.choice(np.r_[dynamic, 0, -1, -300, 70_000].astype(np.int32), size=(12, 17))
            masks = render_masks(instances, np.r_[dynamic, -1, 0].astype(np.int32), (12, 17))
            assert (masks.instance_labels == np.where(np.isin(instances, dynamic), instances, 0)).all()
            assert ((masks.dynamic > 0) == np.isin(instances, dynamic)).all()

    def test_a_pixel_grows_into_a_disc_of_the_margin(self):
        instances = np.zeros((41, 41), np.int32)
        instances[20, 20] = 3
        masks = render_masks(instances, np.array([3], np.int32), (41, 41), margin_px=6)
        ys, xs = np.nonzero(masks.instance_labels)
        assert (masks.instance_labels[ys, xs] == 3).all()
        assert np.hypot(ys - 20, xs - 20).max() <= 6.5 and masks.instance_labels[20, 14] == 3

    def test_growth_never_overwrites_another_id(self):
        instances = np.zeros((20, 20), np.int32)
        instances[5:15, 5:9], instances[5:15, 9:13] = 1, 2
        masks = render_masks(instances, np.array([1, 2], np.int32), (20, 20), margin_px=4)
        assert (masks.instance_labels[5:15, 5:9] == 1).all() and (masks.instance_labels[5:15, 9:13] == 2).all()

    def test_growth_equals_the_whole_image_dilation(self):
        rng = np.random.default_rng(0)
        for _ in range(40):
            instances = np.zeros((60, 90), np.int32)
            for _ in range(rng.integers(1, 4)):
                y, x = rng.integers(0, 60), rng.integers(0, 90)  # boxes touch every border sometimes
                instances[y:y + rng.integers(1, 30), x:x + rng.integers(1, 40)] = rng.integers(1, 2 ** 20)
            ids = np.unique(instances[instances > 0]).astype(np.int32)
            margin = int(rng.integers(1, 8))
            masks = render_masks(instances, ids, (60, 90), margin_px=margin)
            np.testing.assert_array_equal(masks.instance_labels, _full_image_growth(instances, margin))

    def test_growth_with_more_ids_than_a_byte_holds(self):
        instances = np.zeros((60, 90), np.int32)
        ys, xs = np.divmod(np.arange(300) * 17 % (60 * 90), 90)
        instances[ys, xs] = np.arange(1000, 1300)
        masks = render_masks(instances, np.arange(1000, 1300, dtype=np.int32), (60, 90), margin_px=3)
        np.testing.assert_array_equal(masks.instance_labels, _full_image_growth(instances, 3))
        assert ((masks.dynamic == 255) == (masks.instance_labels > 0)).all()

    def test_single_row_and_single_pixel_images(self):
        for shape in ((1, 1), (1, 7), (7, 1)):
            instances = np.ones(shape, np.int32)
            masks = render_masks(instances, np.array([1], np.int32), shape, margin_px=2)
            assert (masks.dynamic == 255).all() and (masks.instance_labels == 1).all() and not masks.static.any()

    def test_more_ids_than_sixteen_bits_hold(self):
        instances = np.arange(1, 300 * 300 + 1, dtype=np.int32).reshape(300, 300)
        instances[::7] = 0
        ids = np.unique(instances[instances > 0])
        assert ids.size > 2 ** 16
        masks = render_masks(instances, ids, (300, 300), margin_px=1)
        np.testing.assert_array_equal(masks.instance_labels, _full_image_growth(instances, 1))
