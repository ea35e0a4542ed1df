"""The sliding window: the last W frames' instance labels, forward flows and point tracks, in bounded memory."""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np


@dataclass
class WindowFrame:
    """One frame of the window.

    Attributes:
        labels: (H, W) int32 instance ids (0 = background).
        flow: (H, W, 2) float32 forward flow from the previous frame of the window to this one, or None for the
            window's first frame.
        track_ids: (N,) int64 ids of the points tracked in this frame.
        track_points: (N, 2) float32 their positions (x, y).
    """

    labels: np.ndarray
    flow: np.ndarray | None
    track_ids: np.ndarray
    track_points: np.ndarray


class Window:
    """A ring buffer of the last ``length`` frames, exported as the arrays the motion core takes."""

    def __init__(self, length: int = 8) -> None:
        if length < 2:
            raise ValueError(f"a window needs at least 2 frames, got {length}")
        self._frames: collections.deque[WindowFrame] = collections.deque(maxlen=length)

    def __len__(self) -> int:
        return len(self._frames)

    def reset(self) -> None:
        """Drop every frame."""
        self._frames.clear()

    def push(self, frame: WindowFrame) -> None:
        """Append the newest frame (the oldest falls out when full)."""
        self._frames.append(frame)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The window as (labels (F, H, W), flows (F-1, H, W, 2), tracks_xy (N, F, 2), visible (N, F)).

        The first frame's flow (from a frame no longer in the window) is left out; every point seen in the
        window is a trajectory, NaN where it is not visible.
        """
        frames = list(self._frames)
        labels = np.stack([f.labels for f in frames])
        flows = np.stack([f.flow for f in frames[1:]])
        ids = np.unique(np.concatenate([f.track_ids for f in frames]))
        tracks = np.full((ids.size, len(frames), 2), np.nan, dtype=np.float32)
        for t, f in enumerate(frames):
            tracks[np.searchsorted(ids, f.track_ids), t] = f.track_points
        return labels, flows, tracks, ~np.isnan(tracks[..., 0])
