"""Frames in -> masks out: the one path that the node and the command-line tools both call.

``Pipeline.process`` takes one decoded frame (and optionally an upstream instance map with the same stamp)
and always returns masks for that frame. The first frame of a stream, or the first after a reset, has no
motion evidence yet and gets an empty dynamic mask with status ``warmup``. The method (methods/, chosen by
``PipelineConfig.method``) decides; the pipeline is the shell they share. A frame smaller than
``MIN_WORKING_SIDE`` on either side gets an empty mask with status ``too_small`` before any OpenCV call (DIS
flow crashes the process on working heights below 32 px, OpenCV 5.0), and a frame whose method raises gets an
empty mask with status ``failed: <reason>``; both restart the window.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from moseg_ros.config import PipelineConfig
from moseg_ros.core.flow_field import MIN_WORKING_SIDE, shrink_scale
from moseg_ros.frontend.torch_instances import TorchScriptInstances
from moseg_ros.io.image import to_gray
from moseg_ros.methods import method_class
from moseg_ros.methods.base import FrameInput, Status
from moseg_ros.render import Masks, render_masks
from moseg_ros.timing import Stages
from moseg_ros.wait import wait_policy

__all__ = ["FrameResult", "Pipeline", "PipelineConfig"]

@dataclass
class FrameResult:
    """What the pipeline says about one input frame.

    Attributes:
        stamp_ns: the input's stamp, unchanged.
        masks: masks at the input size.
        kind: the Status (methods/base.py): ok, warmup, no_geometry, no_instances, reset (window cleared
            before this frame), too_small (a side below MIN_WORKING_SIDE: empty mask) or failed (the method
            raised: empty mask, window cleared).
        dynamic_ids: (D,) ids of the instances flagged as moving.
        seconds: processing time of this frame.
        reason: why, for reset and failed.
        refit_stages: seconds per stage of the refit the frame applies, on the first frame that applies it.
        telemetry: the method's ``Decision.telemetry`` (moving_objects: ``refit_age`` and ``fusion_age``, frames
            between this frame and the refit and fused decision it applies; ``fusion_seconds`` on the first frame
            that applies a fused decision).
        stages: seconds per stage of this frame: prepare (grey, instances resized), the method's own stages (for
            moving_objects: tracks, fit, flow, dense_flow, dense_fit, regions and method_other; "decision" for
            methods that report none), render.
    """

    stamp_ns: int
    masks: Masks
    kind: Status
    dynamic_ids: np.ndarray
    seconds: float
    reason: str = ""
    stages: dict[str, float] = field(default_factory=dict)
    refit_stages: dict[str, float] = field(default_factory=dict)
    telemetry: dict[str, float] = field(default_factory=dict)

    @property
    def status(self) -> str:
        """The status as text: ``kind`` or ``kind: reason``."""
        return f"{self.kind.value}: {self.reason}" if self.reason else self.kind.value


def _stage_seconds(shell: dict[str, float], method: dict[str, float]) -> dict[str, float]:
    """The shell's stages with "decision" split into the method's own stages when it reports them (and
    "method_other", the rest of the method's time)."""
    if not method:
        return shell
    other = max(0.0, shell["decision"] - sum(method.values()))
    return {"prepare": shell["prepare"], **method, "method_other": other, "render": shell["render"]}


@contextmanager
def opencv_threads(count: int) -> Iterator[None]:
    """OpenCV's thread count set to ``count`` (0: left as it is) inside the block, and set back after it (the
    count is the whole process's)."""
    before = cv2.getNumThreads()
    if count > 0:
        cv2.setNumThreads(count)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


class Pipeline:
    """Streaming motion segmentation: the shell every method shares (checks, resets, resizing, masks, timing)."""

    def __init__(self, config: PipelineConfig = PipelineConfig(), *, live: bool = False) -> None:
        """``live``: frames come from a camera (the node), so refit ``auto`` runs on a worker thread; offline
        (the tools) every frame waits for its own refit and the same frames always give the same masks."""
        config.validate()
        self.config = replace(config, refit=config.refit_mode(live))
        self.method = method_class(config.method)(self.config)
        self._instance_model = TorchScriptInstances(config.instance_model) if config.instance_model else None
        self._last_stamp: int | None = None
        self._input_size: tuple[int, int] | None = None
        self.resets = 0
        self._threads = ExitStack()
        self._threads.enter_context(opencv_threads(self.config.opencv_thread_count()))

    def close(self) -> None:
        """Stop the method's refit worker, if it has one, and give OpenCV back the threads it had before (the
        pipeline takes no frames afterwards)."""
        self.method.close()
        self._threads.close()

    def __enter__(self) -> Pipeline:
        return self

    def __exit__(self, *exc_info: object) -> None:
        """Close: a worker left running when the interpreter exits is killed inside OpenCV, which aborts the
        process ("FATAL: exception not rethrown")."""
        self.close()

    def reset(self) -> None:
        """Clear the window (the next frame starts a new stream)."""
        self._last_stamp = None
        self._input_size = None
        self.method.reset()
        if self._instance_model is not None:
            self._instance_model.reset()

    def _working_size(self, height: int, width: int) -> tuple[int, int]:
        scale = shrink_scale(height, width, self.config.working_width, self.config.working_pixels, MIN_WORKING_SIDE)
        return round(height * scale), round(width * scale)

    def _reset_reason(self, size: tuple[int, int], stamp_ns: int) -> str | None:
        if self._input_size is not None and size != self._input_size:
            return f"image size changed from {self._input_size} to {size}"
        if self._last_stamp is not None and stamp_ns <= self._last_stamp:
            return "time went backwards" if stamp_ns < self._last_stamp else "repeated stamp"
        return None

    def process(self, image: np.ndarray, stamp_ns: int, instances: np.ndarray | None = None,
                camera_matrix: np.ndarray | None = None, next_frame_at: float | None = None) -> FrameResult:
        """Segment one frame.

        Args:
            image: (H, W) grey or (H, W, 3) rgb uint8 frame.
            stamp_ns: the frame's stamp; a stamp not after the previous one resets the window.
            instances: optional (H, W) int upstream instance ids for this frame (0 or negative = none); without
                them, the ``instance_model``'s, when one is set.
            camera_matrix: optional (3, 3) K of the camera at the image's size (camera_info).
            next_frame_at: when (``time.monotonic()``) the next frame is expected (a live camera's pace; None:
                not known): ``refit_wait_ms`` -1 waits for the refit within the time until then.

        Returns:
            The frame's masks and status.
        """
        start = time.perf_counter()
        if image.dtype != np.uint8 or image.ndim not in (2, 3) or image.size == 0:
            raise ValueError(f"expected a non-empty uint8 grey or rgb frame, got {image.dtype} {image.shape}")
        size = image.shape[:2]
        if instances is not None and instances.shape != size:
            raise ValueError(f"instance map {instances.shape} does not match the image {size}")
        if min(size) < MIN_WORKING_SIDE:
            self.reset()
            return self._empty(stamp_ns, size, Status.TOO_SMALL, "", start)
        reason = self._reset_reason(size, stamp_ns)
        if reason is not None:
            self.reset()
            self.resets += 1
        stages = Stages()
        try:
            with stages("prepare"):
                if instances is None and self._instance_model is not None:
                    instances = self._instance_model(image)
                frame = self._frame_input(image, instances, camera_matrix, next_frame_at)
            with stages("decision"):
                decision = self.method.step(frame)
        except Exception as error:  # every decodable frame gets a mask; the status says why it is empty
            return self.failed(stamp_ns, size, error, start)
        self._last_stamp, self._input_size = stamp_ns, size
        with stages("render"):
            masks = render_masks(decision.labels, decision.dynamic_ids, size, self.config.mask_margin_px)
        kind = Status.RESET if reason is not None else decision.status
        return FrameResult(stamp_ns, masks, kind, decision.dynamic_ids, time.perf_counter() - start,
                           reason=reason or "", stages=_stage_seconds(stages.seconds, decision.stages),
                           refit_stages=decision.refit_stages, telemetry=decision.telemetry)

    def _frame_input(self, image: np.ndarray, instances: np.ndarray | None, camera_matrix: np.ndarray | None,
                     next_frame_at: float | None) -> FrameInput:
        full = to_gray(image, "mono8" if image.ndim == 2 else "rgb8")
        h, w = self._working_size(*full.shape)
        if instances is not None:  # ids <= 0 are no instance (segmenters mark "none" with 0 or -1)
            instances = cv2.resize(np.maximum(instances, 0).astype(np.int32), (w, h), interpolation=cv2.INTER_NEAREST)
        return FrameInput(full, (h, w), instances, camera_matrix, wait_policy(self.config.refit_wait_ms, next_frame_at))

    def failed(self, stamp_ns: int, size: tuple[int, int], error: BaseException,
               start: float | None = None) -> FrameResult:
        """The result of a frame of ``size`` (H, W) whose processing raised ``error``, in the method or in a caller's
        own step around ``process``: an empty mask with status failed, and the window cleared. ``start``: the
        ``time.perf_counter()`` its processing began (default: now)."""
        self.reset()
        return self._empty(stamp_ns, size, Status.FAILED, f"{type(error).__name__}: {error}".splitlines()[0],
                           time.perf_counter() if start is None else start)

    def _empty(self, stamp_ns: int, size: tuple[int, int], kind: Status, reason: str, start: float) -> FrameResult:
        masks = render_masks(np.zeros(size, dtype=np.int32), np.zeros(0, dtype=np.int32), size)
        return FrameResult(stamp_ns, masks, kind, np.zeros(0, dtype=np.int32), time.perf_counter() - start,
                           reason=reason)
