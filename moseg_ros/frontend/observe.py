"""Stage 1, observe: one frame's tracks and dense flow, handed on as an immutable ``Observation``.

``FrameObserver.observe`` runs on the frame path: it shrinks the frame to the dense size, computes the dense flow
back to the frame before (DIS), tracks KLT points into the frame (the flow is their starting guess) and returns
what the later stages need: the window's track positions, the backward flows, K at the tracking size.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, replace

import cv2
import numpy as np

from moseg_ros.core.flow_field import MIN_WORKING_SIDE, shrink_scale
from moseg_ros.core.track_tests.cheirality import guessed_camera_matrix
from moseg_ros.core.track_tests.settings import TrackMotionConfig
from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.motion_config import MotionFrontEndConfig
from moseg_ros.frontend.tracks import PointTracker
from moseg_ros.timing import Stages


def scaled_to(K: np.ndarray, size: tuple[int, int], resized: tuple[int, int]) -> np.ndarray:
    """K of an image of ``size`` (H, W) for the same image resized to ``resized``."""
    return np.diag([resized[1] / size[1], resized[0] / size[0], 1.0]) @ K


# A frame is halved by the Gaussian pyramid while the half keeps this share of the size it is shrunk to: the step
# after it, then a slight enlargement, is smooth (pyrDown's Gaussian already removed what would alias).
PYRAMID_SLACK = 0.9


def resized_to_width(gray: np.ndarray, width: int, max_pixels: int = 0) -> np.ndarray:
    """``gray`` shrunk to ``width`` pixels wide and, when ``max_pixels`` > 0, at most that many pixels, keeping its
    aspect and at least MIN_WORKING_SIDE px a side (``shrink_scale``: the pipeline's working size); returned as is
    when it is not larger.

    Halved by ``cv2.pyrDown`` while the half keeps ``PYRAMID_SLACK`` of that size, then resized the rest of the way
    (INTER_LINEAR up, INTER_AREA down): INTER_AREA at a large non-integer factor costs several times what the
    pyramid's halving and a slight linear enlargement do (docs/experiments.md, ``PYRAMID_SLACK``)."""
    scale = shrink_scale(*gray.shape, width, max_pixels, MIN_WORKING_SIDE)
    if scale == 1.0:
        return gray
    size = (round(gray.shape[1] * scale), round(gray.shape[0] * scale))
    while gray.shape[1] // 2 >= PYRAMID_SLACK * size[0] and gray.shape[0] // 2 >= PYRAMID_SLACK * size[1]:
        gray = cv2.pyrDown(gray)
    if gray.shape[1::-1] == size:
        return gray
    return cv2.resize(gray, size, interpolation=cv2.INTER_LINEAR if gray.shape[1] < size[0] else cv2.INTER_AREA)


@dataclass(frozen=True)
class Observation:
    """What the refit needs from one frame, taken on the frame path and not changed afterwards.

    Attributes:
        index: the frame's number since the last reset.
        camera_matrix: (3, 3) K at the tracking size (camera_info's, or guessed without it).
        flows: dense (backward now -> then, forward then -> now) flows at the dense size, or None; the frame
            path computes only the backward one (forward None), the refit the forward one from ``earlier``.
        gray: the frame at the dense size (for the texture gate).
        tracking_shape: (H, W) of the frame as tracked (``camera_matrix``'s size).
        window: (ids, points) of the window's frames, oldest first and this frame last, so that a refit that
            skipped frames fits their track pairs too (``MotionFrontEnd.refit``); empty: no tracks yet.
        gap: frames between the two frames of a short track pair (``TrackMotionConfig.gap``).
        backward: (frame, backward dense flow to the frame before) of the last frames, oldest first and this
            frame last, to carry an earlier refit's dense mask to this frame.
        earlier: the frame ``dense_gap`` back at the dense size (for the refit's forward flow), or None.
    """

    index: int
    camera_matrix: np.ndarray
    flows: tuple[np.ndarray, np.ndarray] | None
    gray: np.ndarray
    tracking_shape: tuple[int, int]
    window: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    gap: int = TrackMotionConfig().gap
    backward: tuple[tuple[int, np.ndarray], ...] = ()
    earlier: np.ndarray | None = None

    @property
    def first(self) -> int:
        """The frame number (``index``'s count) of the window's first frame: ``window[k]`` is frame ``first + k``."""
        return self.index - len(self.window) + 1

    @property
    def alive(self) -> np.ndarray:
        """Ids of the tracks living now."""
        return self.window[-1][0] if self.window else np.zeros(0, dtype=np.int64)

    @property
    def pair(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """(ids, points, ids, points) of the frames ``gap`` back and now, or None before the window holds both."""
        return (*self.window[-1 - self.gap], *self.window[-1]) if len(self.window) > self.gap else None

    @property
    def long_pair(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The same for the window's first frame and now, or None until the window holds more than ``gap`` + 1
        frames (near the focus of expansion the short pairs' parallax is below their floor, and the first frames
        of a stream would wait for the window to fill)."""
        return (*self.window[0], *self.window[-1]) if len(self.window) > self.gap + 1 else None

    @property
    def long_span(self) -> int:
        """Frames between the long pair's two frames (0 without one)."""
        return len(self.window) - 1 if self.long_pair is not None else 0


    @property
    def flow_here(self) -> np.ndarray | None:
        """(h, w, 2) this frame's dense flow back to the frame before, None when it has none."""
        return self.backward[-1][1] if self.backward and self.backward[-1][0] == self.index else None


class FrameObserver:
    """The frame path's first stage: dense flow and KLT tracks of each frame, kept over the window."""

    def __init__(self, config: MotionFrontEndConfig, flow: DenseFlow) -> None:
        self.config = config
        self.flow = flow
        self._points = PointTracker(replace(config.tracks, max_points=config.max_tracks))
        self.reset()

    def reset(self) -> None:
        """Forget every frame and track."""
        self._points.reset()
        self._index = -1
        self._frames: collections.deque[tuple[np.ndarray, np.ndarray]] = collections.deque(
            maxlen=max(self.config.window_length, self.config.track_motion.gap + 1))
        self._grays: collections.deque[np.ndarray] = collections.deque(maxlen=self.config.dense_gap + 1)
        # The backward dense flow (frame -> the one before) of the last frames, to carry an older refit's
        # dense mask to the current frame.
        self._backward: collections.deque[tuple[int, np.ndarray]] = collections.deque(
            maxlen=self.config.window_length)

    def observe(self, gray: np.ndarray, camera_matrix: np.ndarray | None, stages: Stages) -> Observation:
        """The frame path's part: compute the dense flow back to the frame before, track into ``gray``; returns
        what the later stages need, timed in ``stages`` (tracks, flow)."""
        self._index += 1
        with stages("tracks"):
            self._grays.append(resized_to_width(gray, self.config.dense_width, self.config.dense_pixels))
        flows, earlier = None, None
        if self.config.dense and len(self._grays) > self.config.dense_gap:
            with stages("flow"):
                earlier, now = self._grays[0], self._grays[-1]
                # Only the backward flow: the refit computes the forward one it needs off the frame path.
                flows = (self.flow(now, earlier), None)
            self._backward.append((self._index, flows[0]))
        with stages("tracks"):
            # The dense flow back to the previous frame is the tracks' starting guess (inverted) and backward
            # check too (frontend/tracks.py).
            self._points.update(gray, flows[0] if flows is not None and self.config.dense_gap == 1 else None,
                                self._grays[-1])
            self._frames.append((self._points.ids.copy(), self._points.points.copy()))
        K = guessed_camera_matrix(gray.shape) if camera_matrix is None else camera_matrix
        return Observation(self._index, K, flows, self._grays[-1], gray.shape, tuple(self._frames),
                           self.config.track_motion.gap, tuple(self._backward), earlier)
