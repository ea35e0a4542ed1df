"""What every method takes and returns, and the status vocabulary the pipeline, node and tools share."""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, Protocol

import cv2
import numpy as np

from moseg_ros.wait import WaitPolicy

if TYPE_CHECKING:
    from moseg_ros.config import PipelineConfig


class Status(str, enum.Enum):
    """Why a frame's mask looks as it does; the pipeline adds a free-text reason to some."""

    OK = "ok"
    WARMUP = "warmup"            # no motion evidence yet (first frames of a stream)
    NO_GEOMETRY = "no_geometry"  # the camera's motion could not be estimated: nothing flagged
    NO_INSTANCES = "no_instances"  # a method that needs upstream instances got none for this frame
    RESET = "reset"              # the window was cleared before this frame (reason: why)
    TOO_SMALL = "too_small"      # below the minimum working size: empty mask
    FAILED = "failed"            # the method raised (reason: the error): empty mask, window cleared


@dataclass
class FrameInput:
    """One frame as a method sees it.

    Attributes:
        full: (H, W) uint8 frame at the input resolution (for methods that track at their own resolution).
        working_size: (h, w) of the working resolution.
        instances: (h, w) int32 upstream instance ids at the working resolution, or None.
        camera_matrix: (3, 3) K at the input resolution (from camera_info), or None when uncalibrated.
        wait: how long the frame may wait for the method's background work (the pipeline's ``WaitPolicy``).
    """

    full: np.ndarray
    working_size: tuple[int, int]
    instances: np.ndarray | None = None
    camera_matrix: np.ndarray | None = None
    wait: WaitPolicy = field(default_factory=WaitPolicy)

    @functools.cached_property
    def gray(self) -> np.ndarray:
        """(h, w) uint8 frame at the working resolution, resized (INTER_AREA) on first use: a method that works
        at its own resolutions (moving_objects) never pays for it."""
        h, w = self.working_size
        if (h, w) == self.full.shape:
            return self.full
        return cv2.resize(self.full, (w, h), interpolation=cv2.INTER_AREA)


@dataclass
class Decision:
    """A method's answer for one frame: labels at the working resolution and which of them move."""

    labels: np.ndarray
    dynamic_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    status: Status = Status.OK
    stages: dict[str, float] = field(default_factory=dict)  # seconds per stage of this frame, when measured
    refit_stages: dict[str, float] = field(default_factory=dict)  # that refit's stages, on its first frame only
    # What the method's background work says of this frame, published by the node as it is (each key's last, max
    # and mean over the recent frames): how many frames old the decisions it applies are, how long they took.
    telemetry: dict[str, float] = field(default_factory=dict)


class Method(Protocol):
    """A small stateful segmenter; ``name`` is the value of the node's ``method`` parameter."""

    name: ClassVar[str]
    flow_preset: ClassVar[str]  # the DIS preset that flow_preset ``auto`` stands for with this method

    def __init__(self, config: PipelineConfig) -> None: ...

    def reset(self) -> None:
        """Forget the stream (the next frame starts a new one)."""

    def step(self, frame: FrameInput) -> Decision:
        """Decide one frame."""

    def close(self) -> None:
        """Release what the method holds beyond the stream (a refit worker)."""
