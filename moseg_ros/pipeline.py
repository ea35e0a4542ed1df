"""Frames in -> masks out: the one path that the node and the command-line tools both call.

``Pipeline.process`` takes one decoded frame (and optionally an upstream instance map with the same stamp)
and always returns masks for that frame. The first frame of a stream, or the first after a reset, has no
motion evidence yet and gets an empty dynamic mask with status ``warmup``. A frame smaller than
``MIN_WORKING_SIDE`` on either side gets an empty mask with status ``too_small`` before any OpenCV call (DIS
flow crashes the process on working heights below 32 px, OpenCV 5.0), and a frame whose method raises gets an
empty mask with status ``failed: <reason>``; both restart the window.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from moseg_ros.core.baseline import BaselineConfig, dynamic_instances, epipolar_residual
from moseg_ros.core.segment import SegmentConfig, segment_objects
from moseg_ros.frontend.flow import DIS_PRESETS, DenseFlow
from moseg_ros.frontend.instances import InstanceTracker, propose_regions
from moseg_ros.frontend.tracks import PointTracker
from moseg_ros.frontend.window import Window, WindowFrame
from moseg_ros.io.image import to_gray
from moseg_ros.render import Masks, render_masks

# epipolar_baseline: one dominant epipolar geometry, per-pixel residuals (core/baseline.py).
# object_level: the paper's fused epipolar + flow models per instance over a sliding window (core/segment.py);
#   it needs an instance map with every frame and falls back to the baseline for frames without one.
METHODS = ("epipolar_baseline", "object_level")
# auto: fast for epipolar_baseline; medium for object_level, whose ground-contact test compares flows of a
# pixel or two (measured on the synthetic presets: 152 of 208 moving object-frames flagged with medium, 91 with
# fast; see core/ground.py).
FLOW_PRESETS = ("auto", *DIS_PRESETS)
# Smallest working side, in pixels. cv2.DISOpticalFlow.calc segfaults on heights of about 8-31 px at widths of
# 48 px and more (OpenCV 5.0.0); KLT and resize raise on 1-15 px frames. Probed: 32 is safe at widths 31-4096.
MIN_WORKING_SIDE = 32


@dataclass(frozen=True)
class PipelineConfig:
    """Every setting of the pipeline; the node's parameters map one to one onto these fields."""

    method: str = "epipolar_baseline"
    working_width: int = 640
    flow_preset: str = "auto"
    mask_margin_px: int = 6
    min_region_area: int = 60
    min_persistence: int = 2
    instance_min_fraction: float = 0.3
    window_length: int = 8
    refit_interval: int = 4
    ground_contact: bool = True
    baseline: BaselineConfig = field(default_factory=BaselineConfig)

    def dis_preset(self) -> str:
        """The DIS preset that flow_preset stands for (auto: by method)."""
        if self.flow_preset != "auto":
            return self.flow_preset
        return "medium" if self.method == "object_level" else "fast"

    def validate(self) -> None:
        """Raise ValueError naming the first setting out of range."""
        if self.method not in METHODS:
            raise ValueError(f"method {self.method!r} is not one of {METHODS}")
        if self.flow_preset not in FLOW_PRESETS:
            raise ValueError(f"flow_preset {self.flow_preset!r} is not one of {FLOW_PRESETS}")
        if not 64 <= self.working_width <= 4096:
            raise ValueError(f"working_width {self.working_width} must be within 64..4096 pixels")
        if self.mask_margin_px < 0:
            raise ValueError(f"mask_margin_px {self.mask_margin_px} must be >= 0")
        if self.min_region_area < 1:
            raise ValueError(f"min_region_area {self.min_region_area} must be >= 1")
        if self.min_persistence < 1:
            raise ValueError(f"min_persistence {self.min_persistence} must be >= 1")
        if not 0.0 < self.instance_min_fraction <= 1.0:
            raise ValueError(f"instance_min_fraction {self.instance_min_fraction} must be in (0, 1]")
        if self.window_length < 3:
            raise ValueError(f"window_length {self.window_length} must be >= 3")
        if self.refit_interval < 1:
            raise ValueError(f"refit_interval {self.refit_interval} must be >= 1")


@dataclass
class FrameResult:
    """What the pipeline says about one input frame.

    Attributes:
        stamp_ns: the input's stamp, unchanged.
        masks: masks at the input size.
        status: ``ok``, ``warmup`` (no previous frame yet), ``no_geometry`` (camera too still or RANSAC
            failed: nothing flagged), ``reset: <reason>`` (window cleared before this frame), ``too_small``
            (a side below MIN_WORKING_SIDE: empty mask) or ``failed: <reason>`` (the method raised: empty
            mask, window cleared).
        dynamic_ids: (D,) ids of the instances flagged as moving.
        seconds: processing time of this frame.
    """

    stamp_ns: int
    masks: Masks
    status: str
    dynamic_ids: np.ndarray
    seconds: float


class Pipeline:
    """Streaming motion segmentation over a sliding window of frames."""

    def __init__(self, config: PipelineConfig = PipelineConfig()) -> None:
        config.validate()
        self.config = config
        self._flow = DenseFlow(config.dis_preset())
        self._segment_config = SegmentConfig() if config.ground_contact else SegmentConfig(ground_contact=None)
        self._tracker = InstanceTracker()
        self._points = PointTracker()
        self._window = Window(config.window_length)
        self._object_dynamic = np.zeros(0, dtype=np.int32)
        self._known_objects: set[int] = set()
        self._since_refit = 0
        self._previous: np.ndarray | None = None
        self._last_stamp: int | None = None
        self._input_size: tuple[int, int] | None = None
        self.resets = 0

    def reset(self) -> None:
        """Clear the window (the next frame starts a new stream)."""
        self._previous = None
        self._last_stamp = None
        self._input_size = None
        self._tracker.reset()
        self._points.reset()
        self._window.reset()
        self._object_dynamic = np.zeros(0, dtype=np.int32)
        self._known_objects = set()
        self._since_refit = 0

    def _working_size(self, height: int, width: int) -> tuple[int, int]:
        # Downscale to working_width, but never below MIN_WORKING_SIDE on a side that is at least that long.
        scale = max(self.config.working_width / width, MIN_WORKING_SIDE / height, MIN_WORKING_SIDE / width)
        scale = min(1.0, scale)
        return round(height * scale), round(width * scale)

    def _reset_reason(self, size: tuple[int, int], stamp_ns: int) -> str | None:
        if self._input_size is not None and size != self._input_size:
            return f"image size changed from {self._input_size} to {size}"
        if self._last_stamp is not None and stamp_ns <= self._last_stamp:
            return "time went backwards" if stamp_ns < self._last_stamp else "repeated stamp"
        return None

    def process(self, image: np.ndarray, stamp_ns: int, instances: np.ndarray | None = None) -> FrameResult:
        """Segment one frame.

        Args:
            image: (H, W) grey or (H, W, 3) rgb uint8 frame.
            stamp_ns: the frame's stamp; a stamp not after the previous one resets the window.
            instances: optional (H, W) int upstream instance ids for this frame (0 = none).

        Returns:
            The frame's masks and status.
        """
        start = time.perf_counter()
        if image.dtype != np.uint8 or image.ndim not in (2, 3) or image.size == 0:
            raise ValueError(f"expected a non-empty uint8 grey or rgb frame, got {image.dtype} {image.shape}")
        size = image.shape[:2]
        if instances is not None and instances.shape != size:
            raise ValueError(f"instance map {instances.shape} does not match the image {size}")
        status = "ok"
        if min(size) < MIN_WORKING_SIDE:
            self.reset()
            return self._empty(stamp_ns, size, "too_small", start)
        reason = self._reset_reason(size, stamp_ns)
        if reason is not None:
            self.reset()
            self.resets += 1
            status = f"reset: {reason}"
        try:
            return self._segment(image, stamp_ns, instances, status, start)
        except Exception as error:  # every decodable frame gets a mask; the status says why it is empty
            self.reset()
            return self._empty(stamp_ns, size, f"failed: {type(error).__name__}: {error}".splitlines()[0], start)

    def _empty(self, stamp_ns: int, size: tuple[int, int], status: str, start: float) -> FrameResult:
        masks = render_masks(np.zeros(size, dtype=np.int32), np.zeros(0, dtype=np.int32), size)
        return FrameResult(stamp_ns, masks, status, np.zeros(0, dtype=np.int32), time.perf_counter() - start)

    def _segment(self, image: np.ndarray, stamp_ns: int, instances: np.ndarray | None, status: str,
                 start: float) -> FrameResult:
        size = image.shape[:2]
        h, w = self._working_size(*size)
        gray = cv2.resize(to_gray(image, "mono8" if image.ndim == 2 else "rgb8"), (w, h),
                          interpolation=cv2.INTER_AREA)
        previous, self._previous = self._previous, gray
        self._last_stamp, self._input_size = stamp_ns, size

        if instances is not None:
            instances = cv2.resize(instances.astype(np.int32), (w, h), interpolation=cv2.INTER_NEAREST)
        objects = self.config.method == "object_level" and instances is not None
        if self.config.method == "object_level":
            self._points.update(gray)
        labels = np.zeros((h, w), dtype=np.int32)
        dynamic_ids = np.zeros(0, dtype=np.int32)
        if previous is None:
            status = "warmup" if status == "ok" else status
            if objects:
                self._push_window(instances, None)
        elif objects:
            labels, dynamic_ids = self._decide_objects(instances, self._flow(previous, gray))
        else:
            labels, dynamic_ids, found = self._decide(previous, gray, instances)
            if not found and status == "ok":
                status = "no_geometry"
            if self.config.method == "object_level":
                self._window.reset()  # the window must hold consecutive frames; refill it from the next one
                status = "no_instances" if status == "ok" else status
        masks = render_masks(labels, dynamic_ids, size, self.config.mask_margin_px)
        return FrameResult(stamp_ns, masks, status, dynamic_ids, time.perf_counter() - start)

    def _push_window(self, labels: np.ndarray, flow: np.ndarray | None) -> None:
        self._window.push(WindowFrame(labels, flow, self._points.ids.copy(), self._points.points.copy()))

    def _decide_objects(self, labels: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Refit the object-level motion models every few frames (or when an object appears); in between,
        each instance keeps its last decision, carried by its id."""
        self._push_window(labels, flow)
        present = set(np.unique(labels).tolist()) - {0}
        appeared = bool(present - self._known_objects)
        self._known_objects |= present
        self._since_refit += 1
        if len(self._window) >= 3 and (self._since_refit >= self.config.refit_interval or appeared):
            result = segment_objects(*self._window.arrays(), config=self._segment_config,
                                     rng=np.random.default_rng(0))
            self._object_dynamic = result.object_ids[result.dynamic].astype(np.int32)
            self._since_refit = 0
        return labels, np.intersect1d(self._object_dynamic, np.array(sorted(present), dtype=np.int32))

    def _decide(self, previous: np.ndarray, gray: np.ndarray,
                instances: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, bool]:
        evidence = epipolar_residual(self._flow(gray, previous), self._flow(previous, gray), self.config.baseline)
        moving = evidence.residual > evidence.threshold
        if instances is not None:
            labels = instances
            ids = dynamic_instances(labels, moving, evidence.valid, self.config.instance_min_fraction)
        else:
            labels = self._tracker.update(propose_regions(moving, self.config.min_region_area))
            ids = np.array(sorted(i for i, age in self._tracker.ages.items()
                                  if age >= self.config.min_persistence), dtype=np.int32)
        return labels, ids, evidence.fundamental is not None
