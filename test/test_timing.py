"""Stage timing and pacing at a camera's rate."""

from __future__ import annotations

import collections
import time

import pytest

import moseg_ros.timing as timing
from moseg_ros.timing import Pacer, Stages, next_arrival, sleep_until


class TestStages:
    def test_a_stage_entered_twice_adds_up_and_clear_forgets(self):
        stages = Stages()
        for _ in range(2):
            with stages("tracks"):
                time.sleep(0.01)
        assert set(stages.seconds) == {"tracks"} and stages.seconds["tracks"] >= 0.02
        stages.clear()
        assert stages.seconds == {}


class TestSleepUntil:
    def test_waits_for_a_moment_ahead(self):
        start = time.monotonic()
        sleep_until(start + 0.05)
        assert time.monotonic() - start >= 0.05

    def test_returns_at_once_for_a_moment_past(self):
        start = time.monotonic()
        sleep_until(start - 10.0)
        assert time.monotonic() - start < 5.0  # not the 10 s a sign error would wait, on any busy machine


class FakeClock:
    """time.monotonic and time.sleep on a clock that only sleeping moves; records each sleep."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []
        monkeypatch.setattr(timing.time, "monotonic", lambda: self.now)
        monkeypatch.setattr(timing.time, "sleep", self.sleep)

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


class TestPacer:
    def test_frames_come_at_the_rate_from_the_first_on(self, monkeypatch):
        clock = FakeClock(monkeypatch)
        pacer = Pacer(10.0)
        due = []
        for work in (0.0, 0.03, 0.02):
            pacer.wait()
            due.append(round(clock.now - 100.0, 6))
            clock.now += work  # the frame's processing
        assert due == [0.0, 0.1, 0.2]

    def test_a_late_frame_starts_at_once_and_the_next_keeps_to_the_schedule(self, monkeypatch):
        clock = FakeClock(monkeypatch)
        pacer = Pacer(10.0)
        pacer.wait()
        clock.now += 0.25  # a frame that took two and a half periods
        pacer.wait()
        pacer.wait()
        assert clock.sleeps == []  # frames 1 and 2 were due at 0.1 and 0.2, and it is 0.25
        pacer.wait()
        assert round(clock.now - 100.0, 6) == 0.3  # frame 3 waits for its own time

    def test_back_to_back_never_sleeps(self, monkeypatch):
        clock = FakeClock(monkeypatch)
        pacer = Pacer(0.0)
        for _ in range(3):
            pacer.wait()
        assert clock.sleeps == []

    def test_a_negative_rate_is_refused(self):
        with pytest.raises(ValueError, match="rate must be >= 0"):
            Pacer(-1.0)

    def test_next_due_is_the_frame_after_the_last_one_let_through(self, monkeypatch):
        clock = FakeClock(monkeypatch)
        pacer = Pacer(10.0)
        assert pacer.next_due is None  # before the first frame
        pacer.wait()
        assert pacer.next_due == pytest.approx(100.1)
        clock.now += 0.25  # late: frame 1 was due at 100.1
        pacer.wait()
        assert pacer.next_due == pytest.approx(100.2) and pacer.next_due < clock.now  # already due: no time

    def test_back_to_back_has_no_next_due(self, monkeypatch):
        FakeClock(monkeypatch)
        pacer = Pacer(0.0)
        pacer.wait()
        assert pacer.next_due is None


class TestNextArrival:
    def test_needs_two_arrivals(self):
        assert next_arrival([]) is None and next_arrival([5.0]) is None

    def test_the_newest_plus_the_median_interval(self):
        assert next_arrival([1.0, 1.1, 1.2, 1.3]) == pytest.approx(1.4)

    def test_a_lost_frame_does_not_move_the_period(self):
        arrivals = [0.0, 0.1, 0.2, 0.4, 0.5, 0.6]  # 0.3 never came
        assert next_arrival(arrivals) == pytest.approx(0.7)

    def test_only_the_last_frames_count(self):
        arrivals = [0.0, 1.0, 2.0, 3.0] + [3.0 + 0.1 * k for k in range(1, 9)]  # 1 Hz, then 10 Hz
        assert next_arrival(arrivals, frames=8) == pytest.approx(3.9)

    def test_takes_the_nodes_deque(self):
        assert next_arrival(collections.deque([0.0, 0.5, 1.0], maxlen=100)) == pytest.approx(1.5)
