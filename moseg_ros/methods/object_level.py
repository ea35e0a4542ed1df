"""``object_level``: the paper's fused epipolar + flow models per upstream instance over a sliding window.

KLT tracks, DIS flow and the instance maps fill the window (frontend/window.py); every ``refit_interval``
frames, or when an instance appears, ``core.segment.segment_objects`` refits the object-level models and
decides which instances move; in between, each instance keeps its last decision, carried by its id. A frame
without instances is decided by the epipolar baseline and restarts the window (it must hold consecutive
frames).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from moseg_ros.core.segment import SegmentConfig, segment_objects
from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.tracks import PointTracker
from moseg_ros.frontend.window import Window, WindowFrame
from moseg_ros.methods.base import Decision, FrameInput, Status
from moseg_ros.methods.epipolar_baseline import EpipolarBaseline
from moseg_ros.params import setting

if TYPE_CHECKING:
    from moseg_ros.config import PipelineConfig


@dataclass(frozen=True)
class ObjectLevelSettings:
    """The object-level method's settings."""

    window_length: int = setting(8, "frames in the sliding window", low=3, high=60)
    refit_interval: int = setting(4, "frames between refits of the motion models", low=1, high=60)
    ground_contact: bool = setting(True, "objects standing on the ground plane are moving when their foot slides "
                                   "over it")


class ObjectLevel:
    """Object-level fusion on upstream instances, decisions carried by instance id between refits."""

    name = "object_level"
    flow_preset = "medium"  # the ground-contact test compares flows of a pixel or two (core/ground_contact.py)

    def __init__(self, config: PipelineConfig) -> None:
        self.config, self.settings = config, config.settings_of(self.name)
        self._flow = DenseFlow(config.dis_preset())
        self._segment_config = SegmentConfig() if self.settings.ground_contact else SegmentConfig(ground_contact=None)
        self._points = PointTracker()
        self._window = Window(self.settings.window_length)
        self._fallback = EpipolarBaseline(config)
        self.reset()

    def close(self) -> None:
        """Nothing to release: this method fits on the frame path."""

    def reset(self) -> None:
        """Empty the window and forget every decision."""
        self._points.reset()
        self._window.reset()
        self._fallback.reset()
        self._previous: np.ndarray | None = None
        self._object_dynamic = np.zeros(0, dtype=np.int32)
        self._known_objects: set[int] = set()
        self._since_refit = 0

    def step(self, frame: FrameInput) -> Decision:
        """Push the frame into the window and refit when due; without instances, the baseline decides."""
        self._points.update(frame.gray)
        previous, self._previous = self._previous, frame.gray
        if frame.instances is None:
            self._window.reset()
            if previous is None:
                return Decision(np.zeros(frame.gray.shape, dtype=np.int32), status=Status.WARMUP)
            labels, ids, found = self._fallback.decide(previous, frame.gray, None)
            return Decision(labels, ids, Status.NO_INSTANCES if found else Status.NO_GEOMETRY)
        if previous is None:
            self._push(frame.instances, None)
            return Decision(frame.instances, status=Status.WARMUP)
        return Decision(frame.instances, self._decide(frame.instances, self._flow(previous, frame.gray)))

    def _push(self, labels: np.ndarray, flow: np.ndarray | None) -> None:
        self._window.push(WindowFrame(labels, flow, self._points.ids.copy(), self._points.points.copy()))

    def _decide(self, labels: np.ndarray, flow: np.ndarray) -> np.ndarray:
        self._push(labels, flow)
        present = set(np.unique(labels).tolist()) - {0}
        appeared = bool(present - self._known_objects)
        self._known_objects |= present
        self._since_refit += 1
        if len(self._window) >= 3 and (self._since_refit >= self.settings.refit_interval or appeared):
            result = segment_objects(*self._window.arrays(), config=self._segment_config,
                                     rng=np.random.default_rng(0))
            self._object_dynamic = result.object_ids[result.dynamic].astype(np.int32)
            self._since_refit = 0
        return np.intersect1d(self._object_dynamic, np.array(sorted(present), dtype=np.int32))


METHOD = ObjectLevel
SETTINGS = ObjectLevelSettings
