"""Wall time per named stage of one frame, for the benchmarks and the node's diagnostics."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


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
