"""Stage timing and pacing at a camera's rate."""

from __future__ import annotations

import time

from moseg_ros.timing import Stages, sleep_until


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
