"""Where the evidence stage (the refit) runs, and how long a frame waits for it.

"inline": every frame's refit on the frame path (deterministic: the offline tools). "background": on a
``BackgroundRefit`` worker; a frame submits its ``Observation`` and applies the newest ``Refit`` done. Each refit
hands its track half over first and its dense half after it; while whole refits take longer than the camera's frame
interval, only every ``refit_dense_every``-th fits its dense half. How long a frame may wait for its own refit is
the pipeline's ``WaitPolicy`` (moseg_ros/wait.py); within an adaptive budget it waits for the whole refit when that
fits, else for its track half; the stream's first decisions, up to the first with a track pair, always wait.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from moseg_ros.frontend.evidence import Refit
from moseg_ros.frontend.motion import MotionFrontEnd
from moseg_ros.frontend.observe import Observation
from moseg_ros.refit import BackgroundRefit, raise_worker_error
from moseg_ros.wait import WaitPolicy

if TYPE_CHECKING:
    from moseg_ros.config import PipelineConfig

# The longest each of the stream's first decisions waits for its refit: a worker that takes longer leaves the frame
# with what there is, as before any refit.
FIRST_REFIT_WAIT_S = 1.0


@dataclass(frozen=True)
class RefitJob:
    """What the frame path hands the worker: the observation, whether its frame waits for the whole refit, and the
    camera's frame interval (seconds) as the frame path saw it."""

    observation: Observation
    whole_wanted: bool
    frame_interval: float


@dataclass(frozen=True)
class TimedRefit:
    """What the worker hands back: the refit, and how long (seconds) its last track half and last whole refit took."""

    refit: Refit
    track_seconds: float
    whole_seconds: float


class RefitSchedule:
    """The front-end's refits, inline or on a worker, each frame given the refit it may apply."""

    def __init__(self, front_end: MotionFrontEnd, config: PipelineConfig) -> None:
        self.config = config
        self._front_end = front_end
        self.worker = (BackgroundRefit(self._fit_in_background, nice=config.refit_nice, duty=config.refit_duty)
                       if config.refit == "background" else None)
        # The frame path's: the time between the last two frames' submissions (the camera's frame interval).
        self._frame_interval = 0.0
        self._submitted_at: float | None = None
        # The worker's own: how long its last track half and last whole refit took.
        self._track_seconds = self._whole_seconds = 0.0
        self.reset()

    def reset(self) -> None:
        """Forget every frame, track and region (with a worker: once no refit runs, dropping the one waiting)."""
        if self.worker is None:
            self._reset_front_end()
        else:
            self.worker.clear(self._reset_front_end)
        self._applied: tuple[int, int] | None = None
        self._warmed_up = False

    def _reset_front_end(self) -> None:
        """The front-end's reset and the worker's own count (run while no refit runs)."""
        self._front_end.reset()
        self._without_dense = 0  # the worker's refits since its last dense half

    def close(self) -> None:
        """Stop the worker, if any."""
        if self.worker is not None:
            self.worker.stop()

    def refit(self, observation: Observation, wait: WaitPolicy) -> tuple[Refit | None, float, bool]:
        """The refit ``observation``'s frame applies (its own inline; on the worker the newest done, after waiting
        as the module's docstring says), the seconds it waited, and whether this is the first frame to apply that
        refit (its ``stages`` are then new)."""
        if self.worker is None:
            refit, waited = self._front_end.refit(observation), 0.0
        else:
            refit, waited = self._background(observation, self._wait_seconds(wait))
        new = refit is not None and (refit.index, refit.dense_index) != self._applied
        if new:
            self._applied = (refit.index, refit.dense_index)
        return refit, waited, new

    def _wait_seconds(self, wait: WaitPolicy) -> tuple[float, bool]:
        """How long this frame waits for its own refit, and whether for the whole of it (else its track half): a
        fixed budget (the pipeline's ``WaitPolicy``) for the whole; an adaptive one for the whole refit when it fits
        in it, else for its track half when that does, else not at all."""
        budget, fixed = wait.budget()
        if fixed:
            return budget, True
        latest = self.worker.latest()
        track, whole = (0.0, 0.0) if latest is None else (latest.track_seconds, latest.whole_seconds)
        # A wait shorter than a refit takes would end with the same older refit and only make the frame later.
        if budget >= whole:
            return budget, True
        return (budget, False) if budget >= track else (0.0, True)

    def _background(self, observation: Observation, wait: tuple[float, bool]) -> tuple[Refit | None, float]:
        """Submit ``observation`` and take the newest refit done, after waiting up to ``wait`` seconds (the first
        of the pair) for this frame's own, the whole of it or (the second False) its track half."""
        raise_worker_error(self.worker)
        seconds, whole = wait
        if observation.index > 0 and not self._warmed_up:
            # Before the first refit of two frames there is only an empty mask to apply, and before the first with
            # a pair for the track test only one frame pair's dense evidence: those decisions wait for their own
            # refits, the first with a pair for its track half unless ``wait`` asks for the whole.
            whole = (seconds > 0 and whole) or observation.pair is None
            seconds = max(seconds, FIRST_REFIT_WAIT_S)
            self._warmed_up = observation.pair is not None
        now = time.monotonic()
        if self._submitted_at is not None:
            self._frame_interval = now - self._submitted_at
        self._submitted_at = now
        self.worker.submit(RefitJob(observation, seconds > 0 and whole, self._frame_interval))
        if seconds <= 0:
            return self._newest(), 0.0
        start = time.perf_counter()
        if whole:
            self.worker.wait_for(lambda done: done.refit.dense_index >= observation.index, seconds)
        else:
            self.worker.wait_for(lambda done: done.refit.index >= observation.index, seconds)
        waited = time.perf_counter() - start
        raise_worker_error(self.worker)
        return self._newest(), waited

    def _newest(self) -> Refit | None:
        """The newest refit the worker has done (None before the first)."""
        latest = self.worker.latest()
        return None if latest is None else latest.refit

    def _fit_in_background(self, job: RefitJob) -> TimedRefit:
        """The worker's fit: the track half, handed over at once, then the dense half (track flags a frame younger
        gain more than a dense mask a frame older loses). While whole refits, with the worker's rests
        (``refit_duty``), take longer than the camera's frame interval, only every ``refit_dense_every``-th refit
        and that of a frame that waits for its whole refit fit their dense half."""
        evidence, observation = self._front_end.evidence, job.observation
        start = time.perf_counter()
        tracks = evidence.refit_tracks(observation)
        self._track_seconds = time.perf_counter() - start
        self._without_dense += 1
        behind = self._whole_seconds / self.config.refit_duty > job.frame_interval
        if behind and self._without_dense < self.config.refit_dense_every and not job.whole_wanted:
            return TimedRefit(tracks, self._track_seconds, self._whole_seconds)
        self._without_dense = 0
        self.worker.hand_over(TimedRefit(tracks, self._track_seconds, self._whole_seconds))
        refit = evidence.refit_dense(observation, tracks)
        self._whole_seconds = time.perf_counter() - start
        return TimedRefit(refit, self._track_seconds, self._whole_seconds)
