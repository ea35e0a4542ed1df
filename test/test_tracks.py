"""KLT point tracks: ids persist, positions follow the true motion, dead points are replaced."""

from __future__ import annotations

import cv2
import numpy as np

from conftest import textured_frames
from moseg_ros.frontend.tracks import PointTracker, TrackerConfig


def test_points_follow_the_pan_and_keep_their_ids():
    tracker = PointTracker(TrackerConfig(max_points=300))
    frames = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in textured_frames(6)]
    tracker.update(frames[0])
    first = dict(zip(tracker.ids.tolist(), tracker.points))
    assert len(first) == 300
    for frame in frames[1:]:
        tracker.update(frame)
    survivors = [i for i in tracker.ids.tolist() if i in first]
    moved = np.array([tracker.points[tracker.ids.tolist().index(i)] - first[i] for i in survivors])
    background = moved[np.abs(moved[:, 1]) < 1.0]  # the sliding block moves down; the texture pans left
    assert len(background) > 150
    assert np.allclose(np.median(background, axis=0), [-10.0, 0.0], atol=0.2)  # 5 frames x 2 px
    assert len(tracker.ids) == len(np.unique(tracker.ids)) == 300  # dead points were replaced by new ids


def test_reset_forgets_every_point():
    tracker = PointTracker()
    tracker.update(cv2.cvtColor(textured_frames(1)[0], cv2.COLOR_RGB2GRAY))
    tracker.reset()
    assert tracker.ids.size == 0 and tracker.points.shape == (0, 2)
