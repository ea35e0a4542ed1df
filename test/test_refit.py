"""The refit off the frame path: moseg_ros/refit.py's worker, and the pipeline with a background refit."""

from __future__ import annotations

import gc
import os
import sys
import threading
import time
import weakref

import numpy as np
import pytest

from conftest import textured_frames
from moseg_ros.frontend.evidence import MotionEvidence
from moseg_ros.methods.base import Status
from moseg_ros.pipeline import Pipeline, PipelineConfig
from moseg_ros.refit import BackgroundRefit


class TestBackgroundRefit:
    def test_newest_submission_wins_and_results_come_back(self) -> None:
        gate = threading.Event()
        seen: list[int] = []

        def fit(value: int) -> int:
            gate.wait(5)
            seen.append(value)
            return value * 10

        worker = BackgroundRefit(fit)
        try:
            for value in range(5):
                worker.submit(value)
                time.sleep(0.01)
            gate.set()
            assert worker.wait_idle(5)
            assert worker.latest() == 40 and seen[-1] == 4
            assert worker.replaced >= 1 and len(seen) < 5 and worker.fitted == len(seen)
        finally:
            worker.stop()

    @staticmethod
    def _gap_between_two_fits(duty: float) -> float:
        """Seconds between the end of a 0.3 s fit and the start of the next, submitted while the first ran."""
        started: list[float] = []
        ended: list[float] = []

        def fit(value: int) -> int:
            started.append(time.monotonic())
            time.sleep(0.3)
            ended.append(time.monotonic())
            return value

        worker = BackgroundRefit(fit, duty=duty)
        try:
            worker.submit(1)
            time.sleep(0.05)
            worker.submit(2)
            assert worker.wait_idle(5) and worker.fitted == 2 and worker.latest() == 2
        finally:
            worker.stop()
        return started[1] - ended[0]

    def test_a_fit_hands_over_its_first_half_before_it_ends(self) -> None:
        gate = threading.Event()
        worker: BackgroundRefit[int, int]

        def fit(value: int) -> int:
            worker.hand_over(value)
            gate.wait(5)
            return value * 10

        worker = BackgroundRefit(fit)
        try:
            worker.submit(4)
            assert worker.wait_for(lambda result: result == 4, 5)
            assert not worker.wait_idle(0.05)  # the fit still runs
            gate.set()
            assert worker.wait_for(lambda result: result == 40, 5)
        finally:
            gate.set()
            worker.stop()

    def test_with_a_duty_below_one_the_worker_rests_after_each_fit(self) -> None:
        assert self._gap_between_two_fits(0.5) >= 0.25  # rests as long as the fit took
        assert self._gap_between_two_fits(1.0) < 0.25  # back to back

    def test_stop_ends_a_rest(self) -> None:
        worker = BackgroundRefit(lambda value: time.sleep(0.1) or value, duty=0.02)  # rests about 5 s
        worker.submit(1)
        assert worker.wait_idle(5)
        start = time.monotonic()
        worker.stop()
        assert not worker._thread.is_alive() and time.monotonic() - start < 2

    @pytest.mark.parametrize("duty", [0.0, 1.5])
    def test_a_duty_outside_zero_to_one_is_refused(self, duty: float) -> None:
        with pytest.raises(ValueError, match="duty"):
            BackgroundRefit(lambda value: value, duty=duty)

    @pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread niceness is Linux's")
    @pytest.mark.parametrize("nice", [0, 5])
    def test_the_fit_runs_at_the_niceness_asked_and_the_caller_keeps_its_own(self, nice: int) -> None:
        base = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

        def fit(_: int) -> int:
            return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

        worker = BackgroundRefit(fit, nice=nice)
        try:
            worker.submit(1)
            assert worker.wait_idle(5)
            assert worker.latest() == min(base + nice, 19) == worker.niceness
            assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base
        finally:
            worker.stop()

    def test_clear_drops_a_fit_started_before_it(self) -> None:
        started, release = threading.Event(), threading.Event()
        state = {"resets": 0}

        def fit(value: int) -> int:
            started.set()
            release.wait(5)
            return value

        worker = BackgroundRefit(fit)
        try:
            worker.submit(1)
            assert started.wait(5)
            clearing = threading.Thread(target=worker.clear, args=(lambda: state.update(resets=1),))
            clearing.start()
            time.sleep(0.05)
            assert state["resets"] == 0  # clear waits for the running fit
            release.set()
            clearing.join(5)
            assert state["resets"] == 1 and worker.latest() is None  # its result was dropped
            worker.submit(2)
            assert worker.wait_idle(5) and worker.latest() == 2
        finally:
            worker.stop()

    def test_an_error_is_handed_over_once(self) -> None:
        def fit(value: int) -> int:
            if value < 0:
                raise ArithmeticError("negative")
            return value

        worker = BackgroundRefit(fit)
        try:
            worker.submit(-1)
            assert worker.wait_idle(5)
            error = worker.take_error()
            assert isinstance(error, ArithmeticError) and worker.take_error() is None
            worker.submit(3)
            assert worker.wait_idle(5) and worker.latest() == 3
        finally:
            worker.stop()

    def test_wait_for_returns_once_an_accepted_fit_is_done(self) -> None:
        gate = threading.Event()

        def fit(value: int) -> int:
            gate.wait(5)
            return value

        worker = BackgroundRefit(fit)
        try:
            worker.submit(1)
            assert not worker.wait_for(lambda result: result >= 1, 0.05)  # the fit is held at the gate
            gate.set()
            assert worker.wait_for(lambda result: result >= 1, 5) and worker.latest() == 1
            worker.submit(2)
            assert worker.wait_for(lambda result: result >= 2, 5) and worker.latest() == 2
        finally:
            worker.stop()

    def test_wait_for_ends_on_an_error(self) -> None:
        def fit(value: int) -> int:
            raise ArithmeticError("no fit")

        worker = BackgroundRefit(fit)
        try:
            worker.submit(1)
            assert worker.wait_for(lambda result: True, 5)
            assert isinstance(worker.take_error(), ArithmeticError) and worker.latest() is None
        finally:
            worker.stop()


def _slow_refit(monkeypatch: pytest.MonkeyPatch, seconds: float) -> None:
    """Each refit takes ``seconds`` more, in its first half (the track test, which a background worker hands over
    before the dense half)."""
    original = MotionEvidence.refit_tracks

    def slow(self, observation):
        time.sleep(seconds)
        return original(self, observation)

    monkeypatch.setattr(MotionEvidence, "refit_tracks", slow)


class TestPipelineWithBackgroundRefit:
    def test_a_slow_refit_never_holds_a_frame_back(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """Refits take 0.3 s; 16 frames coming every 50 ms still get their own masks at the camera's pace, from
        older refits."""
        _slow_refit(monkeypatch, 0.3)
        frames = textured_frames(16)
        pipeline = Pipeline(PipelineConfig(), live=True)
        try:
            start = time.perf_counter()
            results = []
            for i, frame in enumerate(frames):
                time.sleep(max(0.0, start + 0.05 * i - time.perf_counter()))  # a camera, not back to back
                results.append(pipeline.process(frame, 1_000 + i * 100_000_000))
            elapsed = time.perf_counter() - start
        finally:
            pipeline.close()
        assert [r.stamp_ns for r in results] == [1_000 + i * 100_000_000 for i in range(16)]
        assert all(r.masks.dynamic.shape == frames[0].shape[:2] for r in results)
        assert elapsed < 0.5 * 16 * 0.3  # waiting for every refit would take 4.8 s
        ages = [r.telemetry.get("refit_age") for r in results if r.telemetry.get("refit_age") is not None]
        assert ages and max(ages) >= 2  # the worker fell behind, and the frames went on with older refits
        assert results[0].kind is Status.WARMUP

    def test_background_finds_the_mover_as_inline_does(self) -> None:
        frames = textured_frames(20)
        inline = Pipeline(PipelineConfig(refit="inline"))
        # At the frame path's priority: under a busy machine's other processes a niced worker would lag
        # (what refit_nice is for), and this test is about what a refit finds, not when.
        background = Pipeline(PipelineConfig(refit="background", refit_nice=0))
        try:
            masks = {}
            for name, pipeline in (("inline", inline), ("background", background)):
                results = []
                for i, frame in enumerate(frames):
                    results.append(pipeline.process(frame, 1_000 + i * 100_000_000))
                    time.sleep(0.1)  # a 10 Hz camera: the worker keeps up
                masks[name] = [r.masks.dynamic > 0 for r in results]
                assert {r.telemetry.get("refit_age") for r in results[5:]} <= ({0} if name == "inline" else {0, 1, 2})
        finally:
            background.close()
        block = (slice(188 // 6 + 3 * 19, 188 // 6 + 3 * 19 + 62), slice(621 // 4, 621 // 4 + 77))
        for name in masks:
            assert masks[name][-1][block].mean() > 0.5, name
        overlap = [np.logical_and(a, b).sum() / max(np.logical_or(a, b).sum(), 1)
                   for a, b in zip(masks["inline"][8:], masks["background"][8:])]
        assert np.mean(overlap) > 0.7

    def test_the_first_decisions_up_to_the_first_track_pair_wait_for_their_own_refits_and_no_later_one_does(
            self, monkeypatch: pytest.MonkeyPatch) -> None:
        """Refits take 0.2 s and frames come back to back: the second frame (the first with a decision) and the
        third (the first with a pair for the track test, two frames apart) get their own refits; the frames after
        them go on with older ones."""
        _slow_refit(monkeypatch, 0.2)
        pipeline = Pipeline(PipelineConfig(), live=True)
        try:
            results = [pipeline.process(frame, 1_000 + i * 100_000_000) for i, frame in enumerate(textured_frames(6))]
        finally:
            pipeline.close()
        assert results[0].kind is Status.WARMUP and results[0].telemetry.get("refit_age") is None
        assert results[1].telemetry.get("refit_age") == results[2].telemetry.get("refit_age") == 0
        assert min(r.telemetry.get("refit_age") for r in results[3:]) >= 1

    def test_the_first_decisions_wait_once_a_stream_even_when_their_refits_are_late(
            self, monkeypatch: pytest.MonkeyPatch) -> None:
        """Refits take 0.3 s and the first decisions may wait 50 ms: the second and third frames time out, and no
        later frame waits; after a reset the new stream's first decisions wait again."""
        import moseg_ros.frontend.refit_schedule as refit_schedule

        _slow_refit(monkeypatch, 0.3)
        monkeypatch.setattr(refit_schedule, "FIRST_REFIT_WAIT_S", 0.05)
        waits: list[float] = []
        wait_for = BackgroundRefit.wait_for

        def recorded(self, accept, timeout):
            waits.append(timeout)
            return wait_for(self, accept, timeout)

        monkeypatch.setattr(BackgroundRefit, "wait_for", recorded)
        pipeline = Pipeline(PipelineConfig(), live=True)
        frames = textured_frames(6)
        try:
            for i, frame in enumerate(frames):
                pipeline.process(frame, 1_000 + i * 100_000_000)
            assert waits == [0.05, 0.05]
            pipeline.method.reset()
            for i, frame in enumerate(frames[:4]):
                pipeline.process(frame, 10_000_000_000 + i * 100_000_000)
            assert waits == [0.05] * 4
        finally:
            pipeline.close()

    def test_frames_that_wait_for_their_own_refit_get_the_inline_masks(self) -> None:
        frames = textured_frames(12)
        inline = Pipeline(PipelineConfig(refit="inline"))
        waiting = Pipeline(PipelineConfig(refit="background", refit_wait_ms=1000.0))
        try:
            runs = {name: [pipeline.process(frame, 1_000 + i * 100_000_000) for i, frame in enumerate(frames)]
                    for name, pipeline in (("inline", inline), ("waiting", waiting))}
        finally:
            waiting.close()
        assert {r.telemetry.get("refit_age") for r in runs["waiting"][1:]} == {0}
        for a, b in zip(runs["inline"], runs["waiting"]):
            assert np.array_equal(a.masks.dynamic, b.masks.dynamic)
        assert any(r.masks.dynamic.any() for r in runs["waiting"])

    def test_a_frame_waits_no_longer_than_asked(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """Refits take 0.3 s, frames come at 10 Hz and each waits at most 20 ms for its own refit: they go on
        with older refits (a frame that waited for its own would have age 0)."""
        _slow_refit(monkeypatch, 0.3)
        pipeline = Pipeline(PipelineConfig(refit="background", refit_wait_ms=20.0))
        results = []
        try:
            for i, frame in enumerate(textured_frames(12)):
                results.append(pipeline.process(frame, 1_000 + i * 100_000_000))
                time.sleep(0.1)
        finally:
            pipeline.close()
        ages = [r.telemetry.get("refit_age") for r in results if r.telemetry.get("refit_age") is not None]
        assert ages[:2] == [0, 0]  # the stream's first decisions wait for their own refits, whatever the setting
        assert min(ages[2:]) >= 1 and max(ages) >= 2

    def test_auto_waits_for_its_own_refit_only_when_the_camera_leaves_time(
            self, monkeypatch: pytest.MonkeyPatch) -> None:
        """``refit_wait_ms`` -1 (the default), refits of 0.1 s: with the next frame a second away every frame waits
        for its own refit (age 0, the wait among its stages); with the next frame due now, or not known, none
        does after the stream's first decisions."""
        _slow_refit(monkeypatch, 0.1)
        frames = textured_frames(6)
        runs = {}
        with Pipeline(PipelineConfig(), live=True) as pipeline:
            for name, spare in (("spare", 1.0), ("due", 0.0), ("unknown", None)):
                pipeline.reset()
                runs[name] = [pipeline.process(frame, 1_000 + i * 100_000_000,
                                               next_frame_at=None if spare is None else time.monotonic() + spare)
                              for i, frame in enumerate(frames)]
        assert [r.telemetry.get("refit_age") for r in runs["spare"][1:]] == [0] * 5
        assert all(r.stages["refit_wait"] > 0.03 for r in runs["spare"][3:])
        for name in ("due", "unknown"):
            assert min(r.telemetry.get("refit_age") for r in runs[name][3:]) >= 1, name
            assert all("refit_wait" not in r.stages for r in runs[name][3:]), name

    def test_auto_waits_at_most_a_share_of_the_time_to_the_next_frame_and_only_when_a_refit_fits(
            self, monkeypatch: pytest.MonkeyPatch) -> None:
        """The next frame 0.1 s after each frame starts; the first refits are quick, the later ones take 0.5 s.
        Frames after a quick refit wait, but no longer than AUTO_WAIT_SHARE of what is left of that 0.1 s; once
        a refit took longer than that, no frame waits (the wait could not bring its own refit)."""
        from moseg_ros.wait import AUTO_WAIT_SHARE

        original = MotionEvidence.refit_tracks
        sleeps = iter([0.0] * 3 + [0.5] * 20)

        def varying(self, observation):
            time.sleep(next(sleeps))
            return original(self, observation)

        monkeypatch.setattr(MotionEvidence, "refit_tracks", varying)
        results = []
        with Pipeline(PipelineConfig(), live=True) as pipeline:
            for i, frame in enumerate(textured_frames(16)):
                results.append(pipeline.process(frame, 1_000 + i * 100_000_000, next_frame_at=time.monotonic() + 0.1))
        waits = [r.stages.get("refit_wait", 0.0) for r in results]
        assert 0 < max(waits[2:5]) and max(waits[2:]) <= AUTO_WAIT_SHARE * 0.1 + 0.01, waits
        assert waits[-4:] == [0.0] * 4, waits  # the first slow refit is done by then
        assert min(r.telemetry.get("refit_age") for r in results[-4:]) >= 1

    def test_the_track_half_comes_before_the_dense_half(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """The dense half of each refit takes 0.3 s more, frames come at 10 Hz and never wait but the stream's
        first: the track flags the frames apply are handed over at once (about 2 frames old on average, where
        waiting for the whole refit would give about 4), and the first decisions still wait: the second frame, with
        no track pair, for its whole refit (its mask is the dense half's alone, as inline), the third, the first
        with a pair, for its track half (its dense mask the second frame's, as every frame's after it)."""
        original = MotionEvidence.refit_dense

        def slow(self, observation, tracks):
            time.sleep(0.3)
            return original(self, observation, tracks)

        frames = textured_frames(20)
        with Pipeline(PipelineConfig(refit="inline")) as inline:
            expected = [inline.process(frame, 1_000 + i * 100_000_000).masks.dynamic for i, frame in enumerate(frames)]
        monkeypatch.setattr(MotionEvidence, "refit_dense", slow)
        pipeline = Pipeline(PipelineConfig(refit="background", refit_wait_ms=0.0, refit_nice=0))
        try:
            results = []
            for i, frame in enumerate(frames):
                results.append(pipeline.process(frame, 1_000 + i * 100_000_000))
                time.sleep(0.1)
        finally:
            pipeline.close()
        assert expected[1].any() and np.array_equal(results[1].masks.dynamic, expected[1])
        assert results[2].telemetry.get("refit_age") == 0 and results[2].masks.dynamic.any()
        assert not np.array_equal(results[2].masks.dynamic, expected[2])  # the dense mask a frame late
        ages = [r.telemetry.get("refit_age") for r in results[4:]]
        assert 1 <= np.mean(ages) < 3, ages

    @pytest.mark.parametrize("dense_seconds, every, skips", [(0.3, 3, True), (0.3, 1, False), (0.0, 3, False)])
    def test_a_refit_slower_than_the_camera_leaves_out_dense_halves(self, monkeypatch: pytest.MonkeyPatch,
                                                                    dense_seconds: float, every: int,
                                                                    skips: bool) -> None:
        """Frames every 0.1 s that never wait but the stream's first: with each dense half taking 0.3 s more the
        whole refits cannot keep up, and with ``refit_dense_every`` 3 only about every third refit fits its dense
        half (every one with 1); refits that keep up (no delay) always fit it. The first decisions, which wait for
        their whole refits, always get them."""
        calls = {"tracks": 0, "dense": 0}
        tracks_half, dense_half = MotionEvidence.refit_tracks, MotionEvidence.refit_dense

        def counted_tracks(self, observation):
            calls["tracks"] += 1
            return tracks_half(self, observation)

        def counted_dense(self, observation, tracks):
            calls["dense"] += 1
            time.sleep(dense_seconds)
            return dense_half(self, observation, tracks)

        monkeypatch.setattr(MotionEvidence, "refit_tracks", counted_tracks)
        monkeypatch.setattr(MotionEvidence, "refit_dense", counted_dense)
        config = PipelineConfig(refit="background", refit_wait_ms=0.0, refit_nice=0, refit_dense_every=every)
        with Pipeline(config) as pipeline:
            results = []
            for i, frame in enumerate(textured_frames(20)):
                results.append(pipeline.process(frame, 1_000 + i * 100_000_000))
                time.sleep(0.1)
            pipeline.method._refits.worker.wait_idle(5)
        assert [r.telemetry.get("refit_age") for r in results[1:3]] == [0, 0]
        if skips:
            assert calls["tracks"] / 3 - 1 <= calls["dense"] < calls["tracks"] - 2, calls
        else:
            assert calls["dense"] == calls["tracks"], calls

    def test_auto_waits_for_the_track_half_when_only_it_fits(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """The next frame 0.4 s after each frame starts, and the dense half of each refit takes 0.33 s more: the
        whole refit never fits in the time left (three quarters of it), its track half does, and the worker (fitting
        back to back) is free again before the next frame, so every frame after the first decisions gets its own
        track flags (age 0), waiting no longer than AUTO_WAIT_SHARE of that 0.4 s."""
        from moseg_ros.wait import AUTO_WAIT_SHARE

        original = MotionEvidence.refit_dense

        def slow(self, observation, tracks):
            time.sleep(0.33)
            return original(self, observation, tracks)

        monkeypatch.setattr(MotionEvidence, "refit_dense", slow)
        results = []
        with Pipeline(PipelineConfig(refit_duty=1.0), live=True) as pipeline:
            for i, frame in enumerate(textured_frames(12)):
                due = time.monotonic() + 0.4
                results.append(pipeline.process(frame, 1_000 + i * 100_000_000, next_frame_at=due))
                time.sleep(max(0.0, due - time.monotonic()))
        assert [r.telemetry.get("refit_age") for r in results[4:]] == [0] * 8
        waits = [r.stages.get("refit_wait", 0.0) for r in results[4:]]
        assert max(waits) <= AUTO_WAIT_SHARE * 0.4 + 0.01, waits

    def test_a_refit_that_raises_gives_a_failed_frame_then_recovers(self, monkeypatch: pytest.MonkeyPatch) -> None:
        original = MotionEvidence.refit_tracks
        calls = {"n": 0}

        def flaky(self, observation):
            calls["n"] += 1
            if calls["n"] == 3:
                raise FloatingPointError("degenerate pair")
            return original(self, observation)

        monkeypatch.setattr(MotionEvidence, "refit_tracks", flaky)
        pipeline = Pipeline(PipelineConfig(refit="background"))
        try:
            kinds = []
            for i, frame in enumerate(textured_frames(12)):
                kinds.append(pipeline.process(frame, 1_000 + i * 100_000_000))
                pipeline.method._refits.worker.wait_idle(5)
        finally:
            pipeline.close()
        failed = [r for r in kinds if r.kind is Status.FAILED]
        assert len(failed) == 1 and "RefitError: FloatingPointError: degenerate pair" in failed[0].status
        assert kinds[-1].kind is Status.OK and kinds[-1].masks.dynamic.any()

    def test_a_failed_refit_frees_what_it_held(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """Without the cycle collector, the failed fit's locals are gone once its frame has its status (a
        traceback kept alive, or tied into a cycle, made the node's memory grow with every failure)."""
        held: list[weakref.ref] = []

        class Arrays:  # stands for the observation and flows a real fit holds
            pass

        def failing(self, observation):
            arrays = Arrays()
            held.append(weakref.ref(arrays))
            raise FloatingPointError("degenerate pair")

        monkeypatch.setattr(MotionEvidence, "refit_tracks", failing)
        pipeline = Pipeline(PipelineConfig(refit="background"))
        gc.disable()
        try:
            statuses = []
            for i, frame in enumerate(textured_frames(8)):
                statuses.append(pipeline.process(frame, 1_000 + i * 100_000_000).kind)
                pipeline.method._refits.worker.wait_idle(5)
        finally:
            gc.enable()
            pipeline.close()
        assert statuses.count(Status.FAILED) >= 2 and len(held) >= 2
        assert all(ref() is None for ref in held[:-1])
