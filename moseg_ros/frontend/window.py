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
        flow: (H, W, 2) float32 flow between the previous frame of the window and this one, or None for the
            window's first frame: forward from the previous frame (read at its pixels), or, in a ``Window`` with
            ``backward``, from this frame back to the previous one (read at this frame's pixels).
        track_ids: (N,) int64 ids of the points tracked in this frame.
        track_points: (N, 2) float32 their positions (x, y).
    """

    labels: np.ndarray
    flow: np.ndarray | None
    track_ids: np.ndarray
    track_points: np.ndarray


class Window:
    """A ring buffer of the last ``length`` frames, exported as the arrays the motion core takes.

    With ``backward`` the frames' flows run back to the frame before (a front-end that computes those on its frame
    path: frontend/motion.py) and ``arrays`` gives the window newest first, in which order they run forward: the
    core's models are those of a pair of frames, whichever of the two comes first in time.
    """

    def __init__(self, length: int = 8, backward: bool = False) -> None:
        if length < 2:
            raise ValueError(f"a window needs at least 2 frames, got {length}")
        self.backward = backward
        self._frames: collections.deque[WindowFrame] = collections.deque(maxlen=length)

    def __len__(self) -> int:
        return len(self._frames)

    def reset(self) -> None:
        """Drop every frame."""
        self._frames.clear()

    def push(self, frame: WindowFrame) -> None:
        """Append the newest frame (the oldest falls out when full)."""
        self._frames.append(frame)

    def copy(self) -> Window:
        """A window of the same frames (not copied: a frame is not changed once pushed) that later pushes leave
        as it is: what a worker decides on while the frame path goes on."""
        window = Window(self._frames.maxlen, self.backward)
        window._frames.extend(self._frames)
        return window

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The window as (labels (F, H, W), flows (F-1, H, W, 2), tracks_xy (N, F, 2), visible (N, F)).

        The first frame's flow (from or to a frame no longer in the window) is left out; every point seen in the
        window is a trajectory, NaN where it is not visible. With ``backward`` every array is newest first.
        """
        frames = list(self._frames)[::-1] if self.backward else list(self._frames)
        labels = np.stack([f.labels for f in frames])
        flows = np.stack([f.flow for f in (frames[:-1] if self.backward else frames[1:])])
        ids = np.unique(np.concatenate([f.track_ids for f in frames]))
        tracks = np.full((ids.size, len(frames), 2), np.nan, dtype=np.float32)
        for t, f in enumerate(frames):
            tracks[np.searchsorted(ids, f.track_ids), t] = f.track_points
        return labels, flows, tracks, ~np.isnan(tracks[..., 0])
