"""``moving_objects`` (the default): finds the moving objects itself, with no weights and no instances.

Per frame: observe (KLT tracks at ``track_width``, DIS flow at the working width) -> motion evidence (the track
tests and the dense residual; the refit, on a worker or inline: frontend/refit_schedule.py) -> regions with
lasting ids -> with ``object_fusion`` the paper's fused object-level decision, which takes back the regions in the
background's motion cluster unless the depth tests flagged them (frontend/fusion.py). With upstream instances they
are the objects instead, each judged by the regions the method would publish alone (frontend/instance_decisions.py).
``Decision.telemetry`` says how old the refit (``refit_age``) and the fused decision (``fusion_age``) a frame
applies are, in frames. docs/method.md has each stage's geometry.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING

import cv2
import numpy as np

from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.fusion import FusionDecision, FusionSchedule, FusionSettings
from moseg_ros.frontend.instance_decisions import (InstanceDecisions, InstanceSettings, published_regions,
                                                   with_unknown_regions)
from moseg_ros.frontend.motion import MotionFrontEnd
from moseg_ros.frontend.motion_config import MotionFrontEndConfig, ObserveSettings, RegionSettings
from moseg_ros.frontend.observe import resized_to_width, scaled_to
from moseg_ros.frontend.refit_schedule import RefitSchedule
from moseg_ros.methods.base import Decision, FrameInput, Status

if TYPE_CHECKING:
    from moseg_ros.config import PipelineConfig


@dataclass(frozen=True)
class MovingObjectsSettings(InstanceSettings, FusionSettings, RegionSettings, ObserveSettings):
    """The method's settings: its stages' (observe, regions, the fused decision, upstream instances)."""


def front_end_config(config: PipelineConfig) -> MotionFrontEndConfig:
    """The front-end's settings: the method's stage parameters (``config.settings_of("moving_objects")``), the
    pipeline's working size for the dense flow and the corners seeded, and the front-end's constants."""
    own = config.settings_of("moving_objects")
    stages = {f.name: getattr(own, f.name) for f in fields(ObserveSettings) + fields(RegionSettings)}
    base = MotionFrontEndConfig(**stages)
    tracks = replace(base.tracks, seed_width=config.working_width, seed_pixels=config.working_pixels)
    return replace(base, tracks=tracks, dense_width=config.working_width, dense_pixels=config.working_pixels)


class MovingObjects:
    """Weight-free moving-object regions from sparse and dense epipolar evidence."""

    name = "moving_objects"
    # DIS balanced (medium's resolution) resolves small, fast movers that the fast preset's quarter-size flow
    # leaves in the background (docs/experiments.md, ``flow_preset``).
    flow_preset = "balanced"

    def __init__(self, config: PipelineConfig) -> None:
        self.config, self.settings = config, config.settings_of(self.name)
        self._instance_decisions = InstanceDecisions(self.settings.instance_min_fraction,
                                                     self.settings.instance_hold_fraction)
        self._front_end = MotionFrontEnd(front_end_config(config), DenseFlow(config.dis_preset()))
        self._refits = RefitSchedule(self._front_end, config)
        self._fusion = (FusionSchedule(self.settings.window_length, config.refit == "background", config.refit_nice)
                        if self.settings.object_fusion else None)

    def reset(self) -> None:
        """Forget every track and region (and, with workers, the refit and fused decision they run or wait with)."""
        self._refits.reset()
        self._instance_decisions.reset()
        if self._fusion is not None:
            self._fusion.reset()

    def close(self) -> None:
        """Stop the refit and fusion workers, if any."""
        self._refits.close()
        if self._fusion is not None:
            self._fusion.close()

    def step(self, frame: FrameInput) -> Decision:
        """Track, test and group; the front-end's regions are the moving objects."""
        tracking = resized_to_width(frame.full, self.settings.track_width)
        K = None if frame.camera_matrix is None else scaled_to(frame.camera_matrix, frame.full.shape, tracking.shape)
        observation = self._front_end.observe(tracking, K)
        refit, waited, new_refit = self._refits.refit(observation, frame.wait)
        labels = self._front_end.apply(refit)
        first = observation.index == 0
        telemetry: dict[str, float] = {}
        if frame.instances is not None:
            decision = self._decide_instances(frame.instances, labels, frame.full.shape[1], first)
            if self._fusion is not None:  # its window holds consecutive frames of the method's own regions
                self._fusion.restart_window()
        else:
            moving, fusion, new_fusion = self._moving_regions(labels, observation.index)
            decision = Decision(labels, status=Status.WARMUP) if first or refit is None else Decision(labels, moving)
            if fusion is not None:
                telemetry["fusion_age"] = observation.index - fusion.index
                if new_fusion:
                    telemetry["fusion_seconds"] = fusion.seconds
        decision.stages = dict(self._front_end.stages.seconds)
        if waited > 0:
            decision.stages["refit_wait"] = waited
        if refit is not None:
            telemetry["refit_age"] = observation.index - refit.index
            if new_refit:
                decision.refit_stages = dict(refit.stages)
            if self._refits.worker is None:
                decision.stages.update(refit.stages)
        decision.telemetry = telemetry
        return decision

    def _moving_regions(self, labels: np.ndarray, index: int) -> tuple[np.ndarray, FusionDecision | None, bool]:
        """(D,) int32 ids of the front-end's regions that move: every one, or with ``object_fusion`` all but those
        the fused decision it applies takes back unless the depth tests flagged them; with that decision (None:
        none yet on this window) and whether this frame is the first to apply it."""
        regions = np.unique(labels[labels > 0]).astype(np.int32)
        if self._fusion is None:
            return regions, None, False
        with self._front_end.stages("fusion"):  # timed with the frame's stages (on the worker: only the hand-over)
            standing = np.unique(labels[self._front_end.depth() & (labels > 0)]).astype(np.int32)
            fusion, new = self._fusion.decision(index, self._front_end.window_frame(labels), regions, standing)
        if fusion is None:
            return regions, None, False
        return regions[~np.isin(regions, fusion.taken_back) | np.isin(regions, standing)], fusion, new

    def _decide_instances(self, instances: np.ndarray, labels: np.ndarray, full_width: int,
                          first: bool) -> Decision:
        """Upstream ``instances`` as the objects, judged by the regions the method would publish (``labels``
        grown by the margin, see ``published_regions``) with a hold (``InstanceDecisions``)."""
        if first:  # the method's reset, which comes with every first frame, forgot the held instances
            return Decision(instances, status=Status.WARMUP)
        if labels.shape != instances.shape:  # once, for the regions and the unknown ones alike
            labels = cv2.resize(labels, instances.shape[::-1], interpolation=cv2.INTER_NEAREST)
        margin = round(self.config.mask_margin_px * instances.shape[1] / full_width)
        regions = published_regions(labels, instances.shape, margin)
        moving = self._instance_decisions.update(instances, regions)
        if not self.settings.instance_unknown_regions:
            return Decision(instances, moving)
        combined, own = with_unknown_regions(instances, labels)
        return Decision(combined, np.concatenate([moving, own]))



METHOD = MovingObjects
SETTINGS = MovingObjectsSettings
