"""What the node counts and measures, and the values of its /diagnostics status (no ROS here: the node sends them)."""

from __future__ import annotations

import collections
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from moseg_ros.timing import next_arrival


@dataclass
class Counters:
    """Frames since the start, by what happened to them."""

    frames_in: int = 0
    frames_out: int = 0
    dropped: int = 0
    carried: int = 0
    bad_input: int = 0
    resets: int = 0
    failures: int = 0
    no_instances: int = 0

    @property
    def problems(self) -> int:
        """Frames dropped, carried, refused as bad input or failed."""
        return self.dropped + self.carried + self.bad_input + self.failures


@dataclass
class NodeStatistics:
    """The node's counters, the statuses of its frames, and its recent arrivals, departures, latencies and the
    method's telemetry (the last few hundred frames)."""

    counters: Counters = field(default_factory=Counters)
    statuses: collections.Counter[str] = field(default_factory=collections.Counter)
    latencies: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=500))
    telemetry: collections.deque[dict[str, float]] = field(default_factory=lambda: collections.deque(maxlen=500))
    arrivals: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=100))
    departures: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=100))

    def arrived(self, now: float) -> None:
        """A frame arrived at ``now`` (``time.monotonic()``)."""
        self.counters.frames_in += 1
        self.arrivals.append(now)

    def next_arrival(self) -> float | None:
        """When the camera's next frame is expected (``timing.next_arrival``)."""
        return next_arrival(self.arrivals)

    def processed(self, status: str, telemetry: dict[str, float]) -> None:
        """A frame's ``status`` (``kind`` or ``kind: reason``) and its method's ``telemetry``."""
        self.statuses[status.split(":")[0]] += 1
        self.telemetry.append(telemetry)

    def published(self, arrived: float, done: float) -> None:
        """A frame that arrived at ``arrived`` got its masks published at ``done``."""
        self.latencies.append(done - arrived)
        self.departures.append(done)
        self.counters.frames_out += 1

    def values(self) -> dict[str, object]:
        """The diagnostics' values: the counters, rates, latency percentiles, the method's telemetry (each key's
        last, max and mean) and the count of each status."""
        c = self.counters
        latencies = np.array(self.latencies) * 1e3 if self.latencies else np.zeros(1)
        return {
            "frames_in": c.frames_in, "frames_out": c.frames_out, "dropped": c.dropped, "carried": c.carried,
            "bad_input": c.bad_input, "resets": c.resets, "failures": c.failures,
            "frames_without_instances": c.no_instances,
            "input_rate_hz": f"{rate(self.arrivals):.2f}", "output_rate_hz": f"{rate(self.departures):.2f}",
            "latency_ms_p50": f"{np.percentile(latencies, 50):.1f}",
            "latency_ms_p95": f"{np.percentile(latencies, 95):.1f}",
            **telemetry_values(self.telemetry),
            **{f"status_{kind}": count for kind, count in sorted(self.statuses.items())},
        }


def rate(times: Iterable[float]) -> float:
    """Events a second over the (sorted) ``times``; 0 with fewer than two."""
    times = list(times)
    if len(times) < 2 or times[-1] <= times[0]:
        return 0.0
    return (len(times) - 1) / (times[-1] - times[0])


def telemetry_values(recent: Iterable[dict[str, float]]) -> dict[str, str]:
    """``{key}_last``, ``{key}_max`` and ``{key}_mean`` of every key of the recent frames' telemetry
    (``FrameResult.telemetry``, published as the method gives it), over the frames that have the key; whole
    numbers as such, the mean with two decimals."""
    values: dict[str, list[float]] = {}
    for telemetry in recent:
        for key, value in telemetry.items():
            values.setdefault(key, []).append(value)
    out: dict[str, str] = {}
    for key, seen in values.items():
        out.update({f"{key}_last": _number(seen[-1]), f"{key}_max": _number(max(seen)),
                    f"{key}_mean": f"{np.mean(seen):.2f}"})
    return out


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:.4g}"
