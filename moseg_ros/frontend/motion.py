"""The motion front-end: frames in, moving regions with persistent ids out, in three stages.

observe (frontend/observe.py, the frame path) -> motion evidence (frontend/evidence.py: the track and dense
tests, on the refit's worker or inline) -> regions (frontend/regions.py, the frame path). Each stage hands the
next an immutable value (``Observation``, ``Refit``); ``MotionFrontEnd`` runs them in order for one caller, and
the default method (methods/moving_objects.py) puts the evidence stage on a worker. docs/method.md has the
geometry of each stage and test.
"""

from __future__ import annotations

import numpy as np

from moseg_ros.frontend.evidence import MotionEvidence, Refit
from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.motion_config import MotionFrontEndConfig
from moseg_ros.frontend.observe import FrameObserver, Observation
from moseg_ros.frontend.regions import RegionStage
from moseg_ros.frontend.window import WindowFrame
from moseg_ros.timing import Stages


class MotionFrontEnd:
    """Turns a stream of grey frames into moving regions with persistent ids.

    Per frame, :meth:`update` is :meth:`observe` (tracks and flow: the frame path), :meth:`refit` (the fits
    and tests) and :meth:`apply` (regions from the newest refit). A caller may run ``refit`` elsewhere
    (moseg_ros/refit.py) and apply the newest refit that is done: the evidence stage (``evidence``) and the
    frame path's stages (``observer``, ``regions``) share no state; what crosses between them are the frozen
    ``Observation`` and ``Refit``.
    """

    def __init__(self, config: MotionFrontEndConfig = MotionFrontEndConfig(), flow: DenseFlow | None = None) -> None:
        self.config = config
        flow = flow or DenseFlow("fast")
        self.observer = FrameObserver(config, flow)
        self.evidence = MotionEvidence(config, DenseFlow(flow.preset))
        self.regions = RegionStage(config)
        self.stages = Stages()
        self._observation: Observation | None = None

    def reset(self) -> None:
        """Forget every frame, track and region, and the evidence stage's window."""
        self.observer.reset()
        self.regions.reset()
        self.evidence.reset()
        self._observation = None

    @property
    def moving(self) -> np.ndarray:
        """(h, w) bool: the last frame's evidence (hulls, dense mask, memory, coasting) before grouping."""
        return self.regions.moving

    @property
    def moving_track_points(self) -> np.ndarray:
        """(M, 2) the last frame's drawn moving tracks (tracking pixels)."""
        return self.regions.moving_track_points

    def update(self, gray: np.ndarray, camera_matrix: np.ndarray | None = None) -> np.ndarray:
        """Take the next frame ((H, W) uint8, tracked at this size) and, when calibrated, its (3, 3) camera
        matrix at this size; returns (h, w) int32 moving regions with persistent ids at the dense size
        (``dense_width`` wide).

        ``stages.seconds`` then holds the time of each stage: tracks, flow (the dense flow back to the frame
        before), fit (pair fits and the track test), dense_flow (the dense flow forward, for the residual's
        check), dense_fit (the dense residual test) and regions (hulls, carrying, regions)."""
        observation = self.observe(gray, camera_matrix)
        refit = self.evidence.refit(observation)
        labels = self.apply(refit)
        self.stages.seconds.update(refit.stages)
        return labels

    def observe(self, gray: np.ndarray, camera_matrix: np.ndarray | None = None) -> Observation:
        """The frame path's first stage (``FrameObserver.observe``); clears ``stages`` (a new frame)."""
        self.stages.clear()
        self._observation = self.observer.observe(gray, camera_matrix, self.stages)
        return self._observation

    def refit(self, observation: Observation) -> Refit:
        """The evidence stage on one observation (``MotionEvidence.refit``)."""
        return self.evidence.refit(observation)

    def apply(self, refit: Refit | None) -> np.ndarray:
        """Moving regions of the last observed frame from ``refit`` (this frame's or an older one; None: nothing)."""
        return self.regions.apply(self._observation, refit, self.stages)

    def window_frame(self, labels: np.ndarray) -> WindowFrame:
        """The last applied frame as an object-level window takes it (``RegionStage.window_frame``)."""
        return self.regions.window_frame(labels)

    def depth(self) -> np.ndarray:
        """(h, w) bool: the last applied frame's evidence from the depth tests (``RegionStage.depth``)."""
        return self.regions.depth()
