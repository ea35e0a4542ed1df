"""Dense DIS flow: its presets, shapes and a known pan."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import textured_frames
from moseg_ros.frontend.flow import DIS_PRESETS, DenseFlow

FRAMES = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in textured_frames(2)]


class TestDenseFlow:
    @pytest.mark.parametrize("preset", sorted(DIS_PRESETS))
    def test_shape_and_type(self, preset):
        flow = DenseFlow(preset)(FRAMES[0], FRAMES[1])
        assert flow.shape == (*FRAMES[0].shape, 2) and flow.dtype == np.float32

    @pytest.mark.parametrize("preset", sorted(DIS_PRESETS))
    def test_the_pan_is_two_pixels_left(self, preset):
        flow = DenseFlow(preset)(FRAMES[0], FRAMES[1])
        background = flow[:, FRAMES[0].shape[1] // 2:]  # right of the sliding block
        assert np.allclose(np.median(background.reshape(-1, 2), axis=0), [-2.0, 0.0], atol=0.1)

    def test_balanced_is_medium_with_fewer_refinement_rounds(self):
        balanced, medium = DenseFlow("balanced")._dis, DenseFlow("medium")._dis
        assert balanced.getVariationalRefinementIterations() == 2
        assert medium.getVariationalRefinementIterations() == 5
        assert balanced.getFinestScale() == medium.getFinestScale() == 1
        assert balanced.getPatchSize() == medium.getPatchSize()

    def test_unknown_preset_and_mismatched_frames_are_named(self):
        with pytest.raises(ValueError, match="unknown flow preset 'warp'"):
            DenseFlow("warp")
        with pytest.raises(ValueError, match="two grey frames of one size"):
            DenseFlow("fast")(FRAMES[0], FRAMES[1][:-1])
