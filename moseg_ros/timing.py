"""Wall time per named stage of one frame, for the benchmarks and the node's diagnostics; pacing at a camera's rate,
and when a camera's next frame is due."""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

import numpy as np


class Stages:
    """Seconds per stage ("tracks", "flow", ...) of the current frame; ``with stages("name"):`` adds to one.

    ``clear()`` starts the next frame; ``seconds`` is the frame's {stage: seconds}.
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    def clear(self) -> None:
        """Forget the last frame's times."""
        self.seconds = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start


def sleep_until(moment: float) -> None:
    """Sleep until ``time.monotonic()`` reaches ``moment``; return at once when it already has (a frame that
    comes due while the one before still runs starts late, not skipped)."""
    delay = moment - time.monotonic()
    if delay > 0:
        time.sleep(delay)


class Pacer:
    """Frames at a camera's pace: ``wait()`` before each frame sleeps until that frame's time, ``rate`` frames a
    second from the first call on (0: back to back, never sleeps)."""

    def __init__(self, rate: float) -> None:
        if rate < 0:
            raise ValueError(f"rate must be >= 0 frames a second, got {rate}")
        self.period = 1.0 / rate if rate > 0 else 0.0
        self._start: float | None = None
        self._frames = 0

    def wait(self) -> None:
        """Sleep until the next frame is due (at once when it is late or the pace is back to back)."""
        if self._start is None:
            self._start = time.monotonic()
        sleep_until(self._start + self._frames * self.period)
        self._frames += 1

    @property
    def next_due(self) -> float | None:
        """When (``time.monotonic()``) the frame after the one ``wait()`` let through last is due; None back to back
        or before the first frame."""
        if self._start is None or self.period == 0:
            return None
        return self._start + self._frames * self.period


def next_arrival(arrivals: Iterable[float], frames: int = 8) -> float | None:
    """When the frame after the newest of ``arrivals`` (each frame's ``time.monotonic()`` on arrival, oldest first)
    is expected: the newest plus the median of the last ``frames`` intervals (a camera's period, robust to a late
    or lost frame); None before two arrivals."""
    last = np.fromiter(arrivals, dtype=np.float64)[-frames - 1:]
    if last.size < 2:
        return None
    return float(last[-1] + np.median(np.diff(last)))
