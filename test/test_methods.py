"""The method plug-ins: one registry, one interface, the default finds movers without instances."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import textured_frames
from moseg_ros.frontend.flow import DIS_PRESETS
from moseg_ros.methods import DEFAULT_METHOD, METHODS, Decision, FrameInput, Status
from moseg_ros.pipeline import Pipeline, PipelineConfig


def test_registry_names_match_and_the_default_needs_no_instances():
    assert DEFAULT_METHOD == "moving_objects" == PipelineConfig().method
    for name, cls in METHODS.items():
        assert cls.name == name and cls.flow_preset in DIS_PRESETS
        assert cls.__doc__ and cls.step.__doc__ and cls.reset.__doc__


@pytest.mark.parametrize("name", sorted(METHODS))
def test_every_method_steps_through_a_stream_and_resets(name):
    method = METHODS[name](PipelineConfig(method=name))
    frames = [f[..., 0].copy() for f in textured_frames(3)]
    decisions = [method.step(FrameInput(f, f.shape)) for f in frames]
    assert all(isinstance(d, Decision) for d in decisions)
    assert decisions[0].status is Status.WARMUP
    assert all(d.labels.shape == frames[0].shape for d in decisions)
    method.reset()
    assert method.step(FrameInput(frames[0], frames[0].shape)).status is Status.WARMUP


class TestFrameInput:
    def test_gray_is_the_frame_itself_at_the_working_size(self):
        full = textured_frames(1)[0][..., 0].copy()
        assert FrameInput(full, full.shape).gray is full

    def test_gray_is_the_area_resized_frame_below_it(self):
        full = np.kron(np.arange(12, dtype=np.uint8).reshape(3, 4) * 10, np.ones((2, 2), np.uint8))
        gray = FrameInput(full, (3, 4)).gray
        assert gray.shape == (3, 4) and np.array_equal(gray, np.arange(12).reshape(3, 4) * 10)

    def test_the_default_method_never_resizes_to_the_working_size(self):
        method = METHODS[DEFAULT_METHOD](PipelineConfig())
        frames = [FrameInput(f[..., 0].copy(), (94, 310)) for f in textured_frames(3)]
        for frame in frames:
            method.step(frame)
        assert all("gray" not in vars(frame) for frame in frames)  # cached_property: never computed


def test_the_default_method_takes_upstream_instances_as_its_objects():
    pipeline = Pipeline(PipelineConfig(mask_margin_px=0))
    for i, frame in enumerate(textured_frames(6)):
        instances = np.zeros(frame.shape[:2], dtype=np.int32)
        y = 188 // 6 + 3 * i
        instances[y:y + 188 // 3, 621 // 4:621 // 4 + 621 // 8] = 7
        instances[150:, 500:] = 3
        result = pipeline.process(frame, i * 100_000_000, instances)
    assert result.dynamic_ids.tolist() == [7]
    assert (result.masks.instance_labels[instances == 7] == 7).all()
