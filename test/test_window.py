"""The sliding window keeps the last W frames and exports the motion core's arrays."""

from __future__ import annotations

import numpy as np
import pytest

from moseg_ros.frontend.window import Window, WindowFrame


def _frame(t: int, ids: list[int]) -> WindowFrame:
    labels = np.full((4, 5), t, dtype=np.int32)
    flow = None if t == 0 else np.full((4, 5, 2), t, dtype=np.float32)
    points = np.array([[i, t] for i in ids], dtype=np.float32).reshape(-1, 2)
    return WindowFrame(labels, flow, np.array(ids, dtype=np.int64), points)


def test_arrays_follow_the_last_frames_and_mark_visibility():
    window = Window(length=3)
    for t, ids in enumerate([[1, 2], [2, 3], [2, 3, 4], [3, 5]]):
        window.push(_frame(t, ids))
    labels, flows, xy, visible = window.arrays()
    assert len(window) == 3
    assert labels[:, 0, 0].tolist() == [1, 2, 3]          # frame 0 fell out
    assert flows.shape == (2, 4, 5, 2) and flows[:, 0, 0, 0].tolist() == [2, 3]
    assert visible.tolist() == [[True, True, False],      # id 2
                                [True, True, True],       # id 3
                                [False, True, False],     # id 4
                                [False, False, True]]     # id 5
    assert xy[1, :, 1].tolist() == [1, 2, 3]              # id 3's y is the frame index
    assert np.isnan(xy[0, 2]).all()


def test_window_needs_two_frames():
    with pytest.raises(ValueError, match="at least 2"):
        Window(length=1)


def test_a_backward_window_comes_newest_first_with_each_frames_own_flow():
    window = Window(length=3, backward=True)
    for t, ids in enumerate([[1, 2], [2, 3], [2, 3, 4], [3, 5]]):
        window.push(_frame(t, ids))
    labels, flows, xy, visible = window.arrays()
    assert labels[:, 0, 0].tolist() == [3, 2, 1]
    # Frame 3's flow back to frame 2 is the first pair's, read at frame 3's pixels; frame 1's (to frame 0, which
    # fell out) is left out.
    assert flows.shape == (2, 4, 5, 2) and flows[:, 0, 0, 0].tolist() == [3, 2]
    assert visible.tolist() == [[False, True, True],      # id 2
                                [True, True, True],       # id 3
                                [False, True, False],     # id 4
                                [True, False, False]]     # id 5
    assert xy[1, :, 1].tolist() == [3, 2, 1]
