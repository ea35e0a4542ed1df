"""The pipeline's wait policy: a fixed wait, or a share of the time left until the camera's next frame."""

from __future__ import annotations

import time

import numpy as np
import pytest

from moseg_ros.pipeline import Pipeline, PipelineConfig
from moseg_ros.wait import AUTO_WAIT_SHARE, WaitPolicy, wait_policy


class TestWaitPolicy:
    def test_a_fixed_wait_is_its_milliseconds_whatever_the_camera(self):
        assert wait_policy(40.0, time.monotonic() + 5.0).budget() == (0.04, True)
        assert wait_policy(0.0, None).budget() == (0.0, True)

    def test_adaptive_is_a_share_of_the_time_left_until_the_next_frame(self):
        seconds, fixed = wait_policy(-1.0, time.monotonic() + 0.2).budget()
        assert not fixed and AUTO_WAIT_SHARE * 0.19 < seconds <= AUTO_WAIT_SHARE * 0.2
        assert WaitPolicy(None, time.monotonic() - 0.1).budget()[0] < 0  # the next frame is late: no time

    def test_no_time_without_the_next_frames_time(self):
        assert wait_policy(-1.0, None).budget() == (0.0, True) == WaitPolicy().budget()


@pytest.mark.parametrize("wait_ms, fixed", [(-1.0, None), (25.0, 0.025)])
def test_the_pipeline_hands_each_frame_its_policy(monkeypatch, wait_ms, fixed):
    from moseg_ros.methods.moving_objects import MovingObjects

    seen = []
    step = MovingObjects.step
    monkeypatch.setattr(MovingObjects, "step", lambda self, frame: seen.append(frame.wait) or step(self, frame))
    due = time.monotonic() + 1.0
    with Pipeline(PipelineConfig(refit_wait_ms=wait_ms)) as pipeline:
        pipeline.process(np.zeros((120, 160), np.uint8), 1, next_frame_at=due)
    assert seen == [WaitPolicy(fixed, due)]
