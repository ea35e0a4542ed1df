"""The pipeline's wait policy: how long a frame may wait for its method's background work (the refit)."""

from __future__ import annotations

import time
from dataclasses import dataclass

# With ``refit_wait_ms`` -1 a frame waits at most this share of the time left until the camera's next frame: the
# rest is for drawing the decision and rendering the masks, so that the next frame starts on time.
AUTO_WAIT_SHARE = 0.75


@dataclass(frozen=True)
class WaitPolicy:
    """How long a frame may wait, as the pipeline's settings say (``refit_wait_ms``).

    Attributes:
        fixed_seconds: ``refit_wait_ms`` >= 0 in seconds: the frame waits that long for the whole of its own work;
            None: adaptive (-1).
        next_frame_at: when (``time.monotonic()``) the camera's next frame is expected; None: not known, or frames
            come back to back (an adaptive policy then leaves no time).
    """

    fixed_seconds: float | None = None
    next_frame_at: float | None = None

    def budget(self) -> tuple[float, bool]:
        """(seconds the frame may wait from now, whether it is fixed): ``fixed_seconds``, or
        ``AUTO_WAIT_SHARE`` × (``next_frame_at`` − now), which a method spends only on work that fits in it; (0, True)
        when the next frame's time is not known."""
        if self.fixed_seconds is not None:
            return self.fixed_seconds, True
        if self.next_frame_at is None:
            return 0.0, True
        return AUTO_WAIT_SHARE * (self.next_frame_at - time.monotonic()), False


def wait_policy(refit_wait_ms: float, next_frame_at: float | None) -> WaitPolicy:
    """The policy of a frame from ``refit_wait_ms`` (-1: adaptive) and when the next frame is expected."""
    return WaitPolicy(refit_wait_ms / 1e3 if refit_wait_ms >= 0 else None, next_frame_at)
