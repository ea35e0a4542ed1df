"""``epipolar_baseline``: one dominant epipolar geometry between consecutive frames, per-pixel residuals.

Pixels far from the dominant geometry (core/baseline.py) form regions that the InstanceTracker keeps by id; a
region is flagged once it persists ``min_persistence`` frames. With upstream instances, an instance is flagged
when ``instance_min_fraction`` of its reliable pixels move. Blind to motion inside the epipolar plane.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from moseg_ros.core.baseline import BaselineConfig, dynamic_instances, epipolar_residual
from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.instances import InstanceTracker, propose_regions
from moseg_ros.methods.base import Decision, FrameInput, Status
from moseg_ros.params import setting

if TYPE_CHECKING:
    from moseg_ros.config import PipelineConfig


@dataclass(frozen=True)
class EpipolarBaselineSettings:
    """The epipolar baseline's settings."""

    residual_threshold_px: float = setting(1.5, "epipolar residual above which a pixel moves (working px)",
                                           low=0.1, high=50.0)
    min_region_area: int = setting(60, "smallest moving region kept (working pixels)", low=1, high=100000)
    min_persistence: int = setting(2, "frames a moving region must persist before it is flagged", low=1, high=100)
    instance_min_fraction: float = setting(0.4, "with instances: share of an instance's reliable pixels that must "
                                           "move to flag it", low=0.01, high=1.0)


class EpipolarBaseline:
    """Dominant-F residual per pixel, regions tracked by id."""

    name = "epipolar_baseline"
    flow_preset = "fast"

    def __init__(self, config: PipelineConfig) -> None:
        self.config, self.settings = config, config.settings_of(self.name)
        self._flow = DenseFlow(config.dis_preset())
        self._regions = InstanceTracker()
        self._baseline = replace(BaselineConfig(), residual_threshold_px=self.settings.residual_threshold_px)
        self.reset()

    def close(self) -> None:
        """Nothing to release: this method fits on the frame path."""

    def reset(self) -> None:
        """Forget the previous frame and every region."""
        self._previous: np.ndarray | None = None
        self._regions.reset()

    def step(self, frame: FrameInput) -> Decision:
        """Residuals against the previous frame; regions or upstream instances flagged."""
        previous, self._previous = self._previous, frame.gray
        if previous is None:
            return Decision(np.zeros(frame.gray.shape, dtype=np.int32), status=Status.WARMUP)
        labels, ids, found = self.decide(previous, frame.gray, frame.instances)
        return Decision(labels, ids, Status.OK if found else Status.NO_GEOMETRY)

    def decide(self, previous: np.ndarray, gray: np.ndarray,
               instances: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, bool]:
        """(labels, dynamic ids, whether the geometry was found) for ``gray`` against ``previous``."""
        evidence = epipolar_residual(self._flow(gray, previous), self._flow(previous, gray), self._baseline)
        moving = evidence.residual > evidence.threshold
        found = evidence.fundamental is not None or evidence.homography is not None
        if instances is not None:
            ids = dynamic_instances(instances, moving, evidence.valid, self.settings.instance_min_fraction)
            return instances, ids, found
        labels = self._regions.update(propose_regions(moving, self.settings.min_region_area))
        ids = np.array(sorted(i for i, age in self._regions.ages.items()
                              if age >= self.settings.min_persistence), dtype=np.int32)
        return labels, ids, found


METHOD = EpipolarBaseline
SETTINGS = EpipolarBaselineSettings
