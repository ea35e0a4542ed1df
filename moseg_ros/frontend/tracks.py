"""Sparse point trajectories: pyramidal Lucas-Kanade with a forward-backward check, reseeded where thin.

The caller's dense backward flow (the motion front-end's DIS flow, computed anyway) saves KLT work both ways:
inverted, it tells KLT where each point lands, so KLT refines that guess on the finest pyramid levels only
instead of searching from the coarsest; a point whose round trip through it lands close to its start is kept
without KLT's backward pass, and only the others are tracked back by KLT (from the flow's guess too). One dense
flow instead of one each way: DIS is the frame path's costliest step.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core.flow_field import shrink_scale


@dataclass(frozen=True)
class TrackerConfig:
    """KLT settings (pixels at the working resolution)."""

    max_points: int = 800
    min_distance: int = 7
    quality: float = 0.005
    fb_max_px: float = 1.0
    window: int = 21
    levels: int = 3
    # KLT stops iterating at a level once its step is below this. 0.1 px instead of OpenCV's usual 0.03
    # saves much of the tracking time and moves the tracks by a small fraction of a pixel, far below the 1 px
    # forward-backward and RANSAC thresholds (docs/experiments.md, ``tracks``).
    stop_px: float = 0.1
    # With a dense backward flow, a point whose round trip through it lands within this of its start needs
    # no KLT backward pass. Half of fb_max_px: the dense flow is coarser than KLT, so only a clear agreement
    # stands in for KLT's own check (at fb_max_px, tracks on moving objects' edges slipped through).
    flow_check_px: float = 0.5
    # Pyramid levels above the finest that KLT searches when a dense flow gives it a starting guess: the guess
    # is within a pixel or two except on small fast movers, which one coarser level still reaches.
    guided_levels: int = 1
    # New corners are found on the frame shrunk to this width (0: at full size) and to at most ``seed_pixels``
    # pixels (0: any): much cheaper at half size (docs/experiments.md, ``tracks``), and ``min_distance`` still
    # holds in full-size pixels.
    seed_width: int = 0
    seed_pixels: int = 0


class PointTracker:
    """Tracks corners from frame to frame; every point has an id that never changes while it lives.

    A point dies when KLT fails, when tracking it back lands more than ``fb_max_px`` from where it started
    (Kalal et al. 2010's forward-backward error), or when it leaves the image. New corners are seeded away
    from the living points whenever fewer than ``max_points`` remain.

    Attributes:
        flow_checked: share of the last update's tracked points that the dense backward flow confirmed (0
            without one).
    """

    def __init__(self, config: TrackerConfig = TrackerConfig()) -> None:
        self.config = config
        self._lk = dict(winSize=(config.window, config.window), maxLevel=config.levels,
                        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, config.stop_px))
        self._guided = dict(self._lk, maxLevel=min(config.levels, config.guided_levels),
                            flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        self.reset()

    def reset(self) -> None:
        """Forget every point."""
        self.ids = np.zeros(0, dtype=np.int64)
        self.points = np.zeros((0, 2), dtype=np.float32)
        self._previous: np.ndarray | None = None
        self._next_id = 0
        self.flow_checked = 0.0

    def update(self, gray: np.ndarray, backward_flow: np.ndarray | None = None,
               shrunk: np.ndarray | None = None) -> None:
        """Track the living points into ``gray``, then seed new ones.

        Args:
            gray: (H, W) uint8 frame.
            backward_flow: optional (h, w, 2) flow from ``gray`` to the previous frame, at any size of the same
                aspect (its vectors in its own pixels): inverted, KLT's starting guess (``landing``); the points it
                brings back near their start skip KLT's backward pass.
            shrunk: optional ``gray`` already shrunk (INTER_AREA) by the caller; corners are found on it when it
                has the size ``seed_width`` and ``seed_pixels`` give, instead of shrinking ``gray`` again (the
                motion front-end's dense frame).
        """
        self.flow_checked = 0.0
        if self._previous is not None and len(self.points):
            self._track(self._previous, gray, backward_flow)
        self._seed(gray, shrunk)
        self._previous = gray

    def _track(self, previous: np.ndarray, gray: np.ndarray, backward_flow: np.ndarray | None) -> None:
        guess = None if backward_flow is None else landing(backward_flow, self.points, gray.shape)
        moved, ok = _klt(previous, gray, self.points, guess, self._lk, self._guided)
        back, ok_back = self._tracked_back(previous, gray, moved, backward_flow)
        h, w = gray.shape
        keep = ok & ok_back
        keep &= np.hypot(*(back - self.points).T) < self.config.fb_max_px
        keep &= (moved[:, 0] >= 0) & (moved[:, 0] <= w - 1) & (moved[:, 1] >= 0) & (moved[:, 1] <= h - 1)
        self.ids, self.points = self.ids[keep], moved[keep]

    def _tracked_back(self, previous: np.ndarray, gray: np.ndarray, moved: np.ndarray,
                      backward_flow: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) where each moved point lands back in ``previous`` and (N,) bool whether that is known: from
        the dense backward flow where it agrees with the start within ``flow_check_px``, from KLT elsewhere."""
        guess = None if backward_flow is None else moved + _sampled(backward_flow, moved, gray.shape)
        back = np.empty_like(moved) if guess is None else guess.copy()
        ok_back = np.zeros(len(moved), dtype=bool)
        redo = np.arange(len(moved))
        if guess is not None and self.config.flow_check_px > 0:
            agrees = np.hypot(*(guess - self.points).T) < self.config.flow_check_px
            ok_back[agrees] = True
            redo = np.flatnonzero(~agrees)
            self.flow_checked = float(agrees.mean())
        if len(redo):
            back[redo], ok_back[redo] = _klt(gray, previous, moved[redo], None if guess is None else guess[redo],
                                             self._lk, self._guided)
        return back, ok_back

    def _seed(self, gray: np.ndarray, shrunk: np.ndarray | None = None) -> None:
        wanted = self.config.max_points - len(self.points)
        if wanted <= 0:
            return
        width = self.config.seed_width
        scale = shrink_scale(*gray.shape, width, self.config.seed_pixels) if width > 0 else 1.0
        shrink = 1.0 / scale
        if shrink > 1:
            size = (max(1, round(gray.shape[1] * scale)), max(1, round(gray.shape[0] * scale)))
            gray = (shrunk if shrunk is not None and shrunk.shape == size[::-1]
                    else cv2.resize(gray, size, interpolation=cv2.INTER_AREA))
        spacing = max(1, round(self.config.min_distance / shrink))
        occupied = np.zeros(gray.shape, dtype=np.uint8)
        xy = np.clip(np.rint(self.points / shrink).astype(int), 0, np.array(gray.shape[::-1]) - 1)
        occupied[xy[:, 1], xy[:, 0]] = 1
        size = 2 * spacing + 1
        occupied = cv2.dilate(occupied, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
        mask = np.where(occupied > 0, 0, 255).astype(np.uint8)
        corners = cv2.goodFeaturesToTrack(gray, wanted, self.config.quality, spacing, mask=mask)
        if corners is None:
            return
        corners = ((corners.reshape(-1, 2) + 0.5) * shrink - 0.5).astype(np.float32)
        self.ids = np.concatenate([self.ids, np.arange(self._next_id, self._next_id + len(corners))])
        self.points = np.concatenate([self.points, corners])
        self._next_id += len(corners)


def _klt(source: np.ndarray, target: np.ndarray, points: np.ndarray, guess: np.ndarray | None, search: dict,
         guided: dict) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) positions in ``target`` of the (N, 2) ``points`` of ``source`` and (N,) bool whether KLT found
    them: a full pyramid ``search`` without a ``guess`` (N, 2) of where they land (a dense flow's), else a
    ``guided`` refinement of it."""
    start = points.reshape(-1, 1, 2)
    if guess is None:
        moved, ok, _ = cv2.calcOpticalFlowPyrLK(source, target, start, None, **search)
    else:
        moved, ok, _ = cv2.calcOpticalFlowPyrLK(source, target, start,
                                                guess.astype(np.float32).reshape(-1, 1, 2), **guided)
    return moved.reshape(-1, 2), ok.ravel() == 1


def landing(backward_flow: np.ndarray, points: np.ndarray, shape: tuple[int, int], rounds: int = 2) -> np.ndarray:
    """Where points of the previous frame land in the current one, by inverting the backward flow.

    The q with q + b(q) = p, by fixed-point rounds q <- p − b(q) from q = p. Each round's error is the flow's
    change over the last one's error, so two rounds land within a fraction of a pixel wherever the flow is
    smooth, close to what sampling a forward flow at p gives, which would cost a second dense flow.

    Args:
        backward_flow: (h, w, 2) flow b, current -> previous, at any size of the same aspect, in its own pixels.
        points: (N, 2) points p (x, y) of the previous frame.
        shape: (H, W) of the current frame.
        rounds: fixed-point rounds.

    Returns:
        (N, 2) positions q in the current frame.
    """
    guess = points
    for _ in range(rounds):
        guess = points - _sampled(backward_flow, guess, shape)
    return guess


def _sampled(flow: np.ndarray, points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N, 2) ``flow`` ((h, w, 2), in its own pixels) bilinearly sampled at ``points`` of an image of ``shape``
    (H, W), in that image's pixels."""
    sy, sx = flow.shape[0] / shape[0], flow.shape[1] / shape[1]
    # cv2.remap takes its sample positions as (1, N) maps: one bilinear gather for all points.
    xs = (points[:, 0] * sx).astype(np.float32)[None]
    ys = (points[:, 1] * sy).astype(np.float32)[None]
    u = cv2.remap(flow[..., 0], xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
    v = cv2.remap(flow[..., 1], xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
    return np.stack([u / sx, v / sy], axis=1)
