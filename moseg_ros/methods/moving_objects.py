"""``moving_objects`` (the default): finds the moving objects itself, with no weights and no instances.

The motion front-end (frontend/motion.py) tracks KLT points at ``track_width`` and flags those that leave the
camera's dominant epipolar geometry over a causal window; groups of flagged tracks fill their convex hulls, united
with the dense flow's epipolar residual and cheirality at the working resolution; regions keep their ids over time.
The cheirality tests use camera_info's K when it comes, a guessed one otherwise. With ``object_fusion`` (the
default) the paper's fused object-level decision (frontend/fusion.py) takes back the regions whose models over
the window fall in the background's motion cluster, unless the depth tests flagged them; without it every region the
front-end reports moves. With upstream instances, they are the objects instead: an instance moves when
``instance_min_fraction`` of its pixels lie in the regions the method would publish without them (the front-end's
regions grown by the published margin, so that an instance never loses what the mask alone would have covered), and,
once flagged, while ``instance_hold_fraction`` of them still do (a hysteresis per instance, followed by its overlap
from frame to frame: the evidence of a car passing the image's corner drops out as it leaves its tracks and the flow
behind, the object does not). With ``instance_unknown_regions`` the method's own regions that lie mostly outside
every instance are published beside them (``with_unknown_regions``): a segmenter that does not know a kind of mover
takes nothing away from what the method finds alone.

With ``refit`` "background" the fits and tests (the front-end's ``refit``) run on a worker thread
(moseg_ros/refit.py): a frame is tracked, its flow computed and its mask drawn from the newest refit that is done,
whose moving tracks are drawn where they are now and whose dense mask is carried along the flow. Each refit hands
over its track test first and its dense half (two thirds of its time) after it: a frame often gets a refit's track
flags with the refit before's dense mask, since flags a frame younger gain more than a dense mask a frame older
loses. ``Decision.refit_age`` says how many frames old the track flags are; with ``refit_wait_ms`` a frame waits
that long at most for the whole refit of its own observation (age 0 when it comes in time), with -1 (the default) as
long as the camera leaves before its next frame (``FrameInput.next_frame_at``) when a refit fits in it, or for the
track half alone when only that fits. The stream's first decisions, from the second frame after a start or a reset
to the first with a pair for the track test (``gap`` frames apart), always wait for their own refits (the last of
them for its track half): before them there is nothing, or only one frame pair's dense evidence, to apply. "inline"
refits every frame on the frame path (deterministic: the offline tools). With "background" the fused decision runs
on a worker of its own too (resting so that it fits a tenth of the time at most, ``FUSION_DUTY``): a frame pushes
its regions into the decision's window, hands the window over and applies the newest decision done, by region id
(``Decision.fusion_age`` says how many frames old); a new window (a new stream) voids the decisions on the last.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import cv2
import numpy as np

from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.evidence import Refit
from moseg_ros.frontend.motion import MotionFrontEnd
from moseg_ros.frontend.motion_config import MotionFrontEndConfig
from moseg_ros.frontend.observe import Observation, resized_to_width, scaled_to
from moseg_ros.methods.base import Decision, FrameInput, Status
from moseg_ros.frontend.fusion import FUSION_DUTY, FusionDecision, FusionJob, ObjectFusion
from moseg_ros.refit import BackgroundRefit, RefitError
from moseg_ros.frontend.instance_decisions import InstanceDecisions, published_regions, with_unknown_regions


if TYPE_CHECKING:
    from moseg_ros.config import PipelineConfig


# The longest each of the stream's first decisions waits for its refit (a refit takes tens of milliseconds; a worker
# that takes longer leaves the frame with what there is, as before any refit).
FIRST_REFIT_WAIT_S = 1.0
# With ``refit_wait_ms`` -1 a frame waits for its refit at most this share of the time left until the camera's next
# frame (and only when the last refit took no longer): the rest is for drawing the decision and rendering the
# masks, so that the next frame starts on time.
AUTO_WAIT_SHARE = 0.75


def front_end_config(config: PipelineConfig) -> MotionFrontEndConfig:
    """The front-end's settings from the pipeline's (one declaration per setting: PipelineConfig)."""
    base = MotionFrontEndConfig()
    return replace(base, window_length=config.window_length,
                   tracks=replace(base.tracks, max_points=config.max_tracks, seed_width=config.working_width,
                                  seed_pixels=config.working_pixels),
                   dense_width=config.working_width, dense_pixels=config.working_pixels,
                   min_region_area=config.min_region_area)


class MovingObjects:
    """Weight-free moving-object regions from sparse and dense epipolar evidence."""

    name = "moving_objects"
    # DIS balanced (medium's resolution) resolves the flow down to half the working size: small, fast movers (a
    # car crossing 35 m ahead moves 8-14 px a frame at 621 px, and is 15 px tall) come out of the fast preset's
    # quarter-size flow as background. It costs the frame path and the refit more time than fast; fast stays a
    # setting for speed (docs/experiments.md has the presets' figures).
    flow_preset = "balanced"

    def __init__(self, config: PipelineConfig) -> None:
        self.config = config
        self._instance_decisions = InstanceDecisions(config.instance_min_fraction, config.instance_hold_fraction)
        self._front_end = MotionFrontEnd(front_end_config(config), DenseFlow(config.dis_preset()))
        self._fusion = ObjectFusion(config.window_length) if config.object_fusion else None
        self._fusion_worker = (BackgroundRefit(self._fusion.fuse, name="moseg-fusion", nice=config.refit_nice,
                                               duty=FUSION_DUTY)
                               if self._fusion is not None and config.refit == "background" else None)
        # How long the worker's last track half (refit_tracks) and last whole refit took, and the time between the
        # last two frames' submissions (the camera's frame interval as the worker sees it).
        self._track_seconds = self._whole_seconds = self._frame_interval = 0.0
        self._submitted_at: float | None = None
        self._worker = (BackgroundRefit(self._fit_in_background, nice=config.refit_nice, duty=config.refit_duty)
                        if config.refit == "background" else None)
        self.reset()

    def reset(self) -> None:
        """Forget every track and region (and, with a worker, the refit it runs or waits with)."""
        if self._worker is None:
            self._reset_refit()
        else:
            self._worker.clear(self._reset_refit)
        self._applied: tuple[int, int] | None = None
        self._whole_wanted = -1  # the newest frame that waits for its whole refit
        self._warmed_up = False
        self._instance_decisions.reset()
        if self._fusion is not None:
            self._fusion.reset()
        if self._fusion_worker is not None:
            self._fusion_worker.clear()
        self._fusion_windows = 0  # counts the fusion's windows: a decision on an earlier one's ids is void
        self._fusion_applied: FusionDecision | None = None

    def _reset_refit(self) -> None:
        """The front-end's reset and the worker's own count (run while no refit runs)."""
        self._front_end.reset()
        self._without_dense = 0  # the worker's refits since its last dense half

    def close(self) -> None:
        """Stop the refit and fusion workers, if any."""
        for worker in (self._worker, self._fusion_worker):
            if worker is not None:
                worker.stop()

    def step(self, frame: FrameInput) -> Decision:
        """Track, test and group; the front-end's regions are the moving objects."""
        tracking = resized_to_width(frame.full, self.config.track_width)
        K = None if frame.camera_matrix is None else scaled_to(frame.camera_matrix, frame.full.shape, tracking.shape)
        observation = self._front_end.observe(tracking, K)
        refit, waited = self._refit(observation, self._wait_seconds(frame))
        labels = self._front_end.apply(refit)
        first = observation.index == 0
        if frame.instances is not None:
            decision = self._decide_instances(frame.instances, labels, frame.full.shape[1], first)
            if self._fusion is not None:  # its window holds consecutive frames of the method's own regions
                self._fusion.reset()
        else:
            moving, fusion = self._moving_regions(labels, observation.index)
            decision = Decision(labels, status=Status.WARMUP) if first or refit is None else Decision(labels, moving)
            if fusion is not None:
                decision.fusion_age = observation.index - fusion.index
                if fusion is not self._fusion_applied:
                    decision.fusion_seconds = fusion.seconds
                    self._fusion_applied = fusion
        decision.stages = dict(self._front_end.stages.seconds)
        if waited > 0:
            decision.stages["refit_wait"] = waited
        if refit is not None:
            decision.refit_age = observation.index - refit.index
            if (refit.index, refit.dense_index) != self._applied:
                decision.refit_stages = dict(refit.stages)
                self._applied = (refit.index, refit.dense_index)
            if self._worker is None:
                decision.stages.update(refit.stages)
        return decision

    def _moving_regions(self, labels: np.ndarray, index: int) -> tuple[np.ndarray, FusionDecision | None]:
        """(D,) int32 ids of the front-end's regions that move: every one, or with ``object_fusion`` all but those
        the fused object-level decision takes back (frontend/fusion.py: every frame goes into its window),
        with the decision applied (None before the first on this window). With a background refit the decision
        runs on a worker of its own and a frame applies the newest one done (on the region ids, which the
        front-end keeps from frame to frame); inline, on its own frame."""
        regions = np.unique(labels[labels > 0]).astype(np.int32)
        if self._fusion is None:
            return regions, None
        with self._front_end.stages("fusion"):  # timed with the frame's stages (on the worker: only the hand-over)
            standing = np.unique(labels[self._front_end.depth() & (labels > 0)]).astype(np.int32)
            window = self._fusion.push(self._front_end.window_frame(labels))
            if window is None:
                self._fusion_windows += 1
                return regions, None
            job = FusionJob(index, self._fusion_windows, window, regions, standing)
            if self._fusion_worker is None:
                fusion = self._fusion.fuse(job)
            else:
                self._raise_worker_error(self._fusion_worker)
                self._fusion_worker.submit(job)
                fusion = self._fusion_worker.latest()
                if fusion is not None and fusion.windows != self._fusion_windows:
                    fusion = None
            if fusion is None:
                return regions, None
            return regions[~np.isin(regions, fusion.taken_back) | np.isin(regions, standing)], fusion

    def _wait_seconds(self, frame: FrameInput) -> tuple[float, bool]:
        """How long this frame may wait for its own background refit, and whether for the whole of it (else for
        its track half): ``refit_wait_ms`` for the whole, or with -1 a share of the time until the camera's next
        frame, for the whole refit when it fits in that time, else for its track half when that does (none when the
        next frame's time is not known)."""
        if self.config.refit_wait_ms >= 0:
            return self.config.refit_wait_ms / 1e3, True
        if frame.next_frame_at is None or self._worker is None:
            return 0.0, True
        budget = AUTO_WAIT_SHARE * (frame.next_frame_at - time.monotonic())
        # A wait shorter than a refit takes would end with the same older refit and only make the frame later (at
        # 30 Hz it made the node skip half of the frames).
        if budget >= self._whole_seconds:
            return budget, True
        return (budget, False) if budget >= self._track_seconds else (0.0, True)

    def _refit(self, observation: Observation, wait: tuple[float, bool]) -> tuple[Refit | None, float]:
        """This frame's refit (inline), or the newest one the worker has done (background), after waiting up to
        ``wait`` seconds (the first of the pair) for this frame's own, the whole of it or (the second False) its
        track half; and the seconds it waited."""
        if self._worker is None:
            return self._front_end.refit(observation), 0.0
        self._raise_worker_error(self._worker)
        seconds, whole = wait
        if observation.index > 0 and not self._warmed_up:
            # Before the first refit of two frames there is only an empty mask to apply, and before the first with
            # a pair for the track test only one frame pair's dense evidence (at 30 Hz the stream's third and fourth
            # frames got a third less of KT3DMoSeg's moving points): the stream's first decisions, up to the first
            # with a track pair, wait for their own refits (once a stream: a flag reset with it); the first with a
            # pair for its track half unless ``wait`` asks for the whole, as the frames after it take their dense
            # mask a frame late (its whole refit made it the stream's slowest frame: KITTI 07, 68 against 40 ms,
            # at the same KT3DMoSeg figures).
            whole = (seconds > 0 and whole) or observation.pair is None
            seconds = max(seconds, FIRST_REFIT_WAIT_S)
            self._warmed_up = observation.pair is not None
        if seconds > 0 and whole:
            self._whole_wanted = observation.index  # before the submission: the worker fits its dense half
        now = time.monotonic()
        if self._submitted_at is not None:
            self._frame_interval = now - self._submitted_at
        self._submitted_at = now
        self._worker.submit(observation)
        if seconds <= 0:
            return self._worker.latest(), 0.0
        start = time.perf_counter()
        if whole:
            self._worker.wait_for(lambda refit: refit.dense_index >= observation.index, seconds)
        else:
            self._worker.wait_for(lambda refit: refit.index >= observation.index, seconds)
        waited = time.perf_counter() - start
        self._raise_worker_error(self._worker)
        return self._worker.latest(), waited

    def _fit_in_background(self, observation: Observation) -> Refit:
        """The worker's fit: the track test, handed over at once, then the dense half (a decision whose track
        flags are a frame younger gains more than one whose dense mask is a frame older loses:
        docs/experiments.md). While whole refits, with the worker's rests (``refit_duty``), take longer than the
        camera's frame interval, only every ``refit_dense_every``-th refit fits its dense half, and that of a frame
        that waits for its whole refit: the worker comes to the next track test sooner."""
        start = time.perf_counter()
        tracks = self._front_end.evidence.refit_tracks(observation)
        self._track_seconds = time.perf_counter() - start
        self._without_dense += 1
        behind = self._whole_seconds / self.config.refit_duty > self._frame_interval
        if behind and self._without_dense < self.config.refit_dense_every and observation.index != self._whole_wanted:
            return tracks
        self._without_dense = 0
        self._worker.hand_over(tracks)
        refit = self._front_end.evidence.refit_dense(observation, tracks)
        self._whole_seconds = time.perf_counter() - start
        return refit

    @staticmethod
    def _raise_worker_error(worker: BackgroundRefit) -> None:
        error = worker.take_error()
        if error is not None:
            raise RefitError.of(error)

    def _decide_instances(self, instances: np.ndarray, labels: np.ndarray, full_width: int,
                          first: bool) -> Decision:
        """Upstream ``instances`` as the objects, judged by the regions the method would publish (``labels``
        grown by the margin, see ``published_regions``) with a hold (``InstanceDecisions``)."""
        if first:  # the method's reset, which comes with every first frame, forgot the held instances
            return Decision(instances, status=Status.WARMUP)
        if labels.shape != instances.shape:  # once, for the regions and the unknown ones alike
            labels = cv2.resize(labels, instances.shape[::-1], interpolation=cv2.INTER_NEAREST)
        margin = round(self.config.mask_margin_px * instances.shape[1] / full_width)
        regions = published_regions(labels, instances.shape, margin)
        moving = self._instance_decisions.update(instances, regions)
        if not self.config.instance_unknown_regions:
            return Decision(instances, moving)
        combined, own = with_unknown_regions(instances, labels)
        return Decision(combined, np.concatenate([moving, own]))


METHOD = MovingObjects
