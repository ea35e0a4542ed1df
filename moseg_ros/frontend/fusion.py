"""The paper's fused object-level decision on the ``moving_objects`` method's own regions (``object_fusion``, on).

The front-end's regions (frontend/motion.py) are the objects: each frame's regions, its dense flow back to the
frame before and its tracks fill a window (frontend/window.py, newest first), and ``core.segment.segment_objects``
fits an epipolar model on each region's trajectories and a quadratic flow model on each region's flow, builds
the two ORK affinities, fuses them by co-regularized spectral clustering and finds the background's cluster. A
region moves when it lies outside that cluster, or when the depth tests flagged it (footing, ground, cheirality:
``MotionFrontEnd.depth()``), which play the ground-contact test's part: a car driving along the camera's axis
images exactly as a static copy of it, so its own motion models are a static object's and only where it stands
tells it from a parked car (docs/experiments.md has the derivation). The paper's own ground-contact test
(core/ground_contact.py) is left out: on real streets it rejected most movers.

Every region was flagged by the front-end's evidence, so this decision can only take some back: regions whose
trajectories and flow the background's models explain. ``push`` runs on the frame path; ``taken_back`` where the
method fits (inline, or on a worker of its own with a background refit: methods/moving_objects.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from moseg_ros.core.segment import SegmentConfig, segment_objects
from moseg_ros.frontend.window import Window, WindowFrame
from moseg_ros.params import setting
from moseg_ros.refit import BackgroundRefit, raise_worker_error

# The object-level models' noise floors at the front-end's dense size (640 px): SegmentConfig's (1 px² of Sampson
# distance, 0.25 px² of flow error) are the whole residual of a small far mover there, and with them the clustering
# puts most true movers in the background's cluster; eigengap ties resolved far towards more motions take back
# fewer movers still (docs/experiments.md, ``object_fusion``). An object's flow vectors are thinned to a thousand a
# pair: the background holds most of the grid, and its model and mean error come out the same from a thousand at a
# fraction of the cost.
FUSION_CONFIG = SegmentConfig(epipolar_floor=0.1, flow_floor=0.05, inlier_ratio=2.0, tie_tolerance=0.6,
                              ground_contact=None, max_flow_vectors=1000)
# The largest share of the time the fusion's worker may fit (with a background refit): the region ids carry a
# decision for a few frames, and its rests leave the cores to the frame path and the front-end's refit.
FUSION_DUTY = 0.1
# The fewest frames in the window before the decision runs: two pairs, as object_level.
MIN_FRAMES = 3


@dataclass(frozen=True)
class FusionSettings:
    """The fused decision's settings."""

    object_fusion: bool = setting(True, "without instances: the paper's fused object-level decision on the "
                                  "method's own regions (epipolar and quadratic flow models per region, ORK "
                                  "affinities, co-regularized clustering): a region moves outside the background's "
                                  "cluster or when the depth tests flagged it. Off: every region found moves")


@dataclass(frozen=True)
class FusionJob:
    """What the fused decision of a frame needs: the frame's index, the count of the fusion's windows, a copy of
    the window (``ObjectFusion.push``), the frame's regions and those the depth tests flagged."""

    index: int
    windows: int
    window: Window
    candidates: np.ndarray
    standing: np.ndarray


@dataclass(frozen=True)
class FusionDecision:
    """The fused decision of frame ``index`` on the ``windows``-th window: the region ids it takes back, and how
    long it took."""

    index: int
    windows: int
    taken_back: np.ndarray
    seconds: float


class ObjectFusion:
    """The fused decision over a sliding window of the front-end's regions (the module's docstring), in two steps:
    ``push`` on the frame path, ``taken_back`` wherever the fit runs (inline, or on a worker: ``decide`` does
    both)."""

    def __init__(self, window_length: int, config: SegmentConfig = FUSION_CONFIG) -> None:
        self.config = config
        self._window = Window(window_length, backward=True)

    def reset(self) -> None:
        """Empty the window (a new stream)."""
        self._window.reset()

    def push(self, frame: WindowFrame) -> Window | None:
        """Push ``frame`` (``MotionFrontEnd.window_frame``: its regions, flow back to the frame before, tracks);
        returns a copy of the window to decide on once it holds ``MIN_FRAMES`` frames in a row, else None. A
        frame without a flow back starts the window again."""
        if frame.flow is None:  # the window must hold consecutive frames
            self._window.reset()
        self._window.push(frame)
        return self._window.copy() if len(self._window) >= MIN_FRAMES else None

    def taken_back(self, window: Window, candidates: np.ndarray, standing: np.ndarray) -> np.ndarray:
        """(T,) int32 sorted ids of the ``candidates`` (regions of ``window``'s newest frame) that the decision
        takes back: inside the background's motion cluster and not among ``standing`` (the regions the depth
        tests flagged)."""
        candidates = np.asarray(candidates, dtype=np.int32)
        if candidates.size == 0:
            return candidates
        labels, flows, tracks, visible = window.arrays()
        result = segment_objects(labels, flows, tracks, visible, config=self.config, rng=np.random.default_rng(0))
        dynamic = result.object_ids[result.dynamic]
        return candidates[~np.isin(candidates, dynamic) & ~np.isin(candidates, standing)]

    def fuse(self, job: FusionJob) -> FusionDecision:
        """``taken_back`` on ``job``, timed (inline, or the fusion worker's fit)."""
        start = time.perf_counter()
        taken_back = self.taken_back(job.window, job.candidates, job.standing)
        return FusionDecision(job.index, job.windows, taken_back, time.perf_counter() - start)

    def decide(self, frame: WindowFrame, candidates: np.ndarray, standing: np.ndarray) -> np.ndarray:
        """``push`` and ``taken_back`` in one: the (D,) int32 sorted ids of the ``candidates`` that move. Until the
        window holds ``MIN_FRAMES`` frames in a row every candidate moves (the front-end's own decision)."""
        candidates = np.asarray(candidates, dtype=np.int32)
        window = self.push(frame)
        if window is None:
            return candidates
        return candidates[~np.isin(candidates, self.taken_back(window, candidates, standing))]


class FusionSchedule:
    """The fused decision of every frame, inline or on a worker of its own (resting so that it fits
    ``FUSION_DUTY`` of the time at most); a frame applies the newest decision done on the current window, by region
    id, and a new window (a new stream, a frame without a flow back) voids the decisions on the last."""

    def __init__(self, window_length: int, background: bool, nice: int = 0) -> None:
        self.fusion = ObjectFusion(window_length)
        self.worker = (BackgroundRefit(self.fusion.fuse, name="moseg-fusion", nice=nice, duty=FUSION_DUTY)
                       if background else None)
        self.reset()

    def reset(self) -> None:
        """Forget the window and every decision (a new stream)."""
        self.fusion.reset()
        if self.worker is not None:
            self.worker.clear()
        self._windows = 0  # counts the windows: a decision on an earlier one's ids is void
        self._applied: FusionDecision | None = None

    def restart_window(self) -> None:
        """Empty the window, which must hold consecutive frames of the regions (a frame decided otherwise)."""
        self.fusion.reset()

    def close(self) -> None:
        """Stop the worker, if any."""
        if self.worker is not None:
            self.worker.stop()

    def decision(self, index: int, frame: WindowFrame, candidates: np.ndarray,
                 standing: np.ndarray) -> tuple[FusionDecision | None, bool]:
        """Push frame ``index`` (``frame``, its ``candidates`` regions and the ``standing`` ones the depth tests
        flagged) and return the decision it applies (its own inline, the newest done on the worker; None before the
        first on this window) and whether this frame is the first to apply it."""
        window = self.fusion.push(frame)
        if window is None:
            self._windows += 1
            return None, False
        job = FusionJob(index, self._windows, window, candidates, standing)
        if self.worker is None:
            fusion = self.fusion.fuse(job)
        else:
            raise_worker_error(self.worker)
            self.worker.submit(job)
            fusion = self.worker.latest()
            if fusion is not None and fusion.windows != self._windows:
                fusion = None
        if fusion is None:
            return None, False
        new, self._applied = fusion is not self._applied, fusion
        return fusion, new
