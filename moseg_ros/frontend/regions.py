"""Stage 3, regions: the moving evidence of a frame drawn and grouped into regions with lasting ids.

``RegionStage`` runs on the frame path and reads the frame only from its ``Observation`` and the evidence only
from a ``Refit``: hulls of the flagged tracks where they are now (frontend/hulls.py), grown and trimmed by the flow
view around each group (core/object_flow.py), the refit's dense mask carried along the flow, evidence remembered
for a frame and lasting regions coasting where theirs drops out (frontend/memory.py), ids kept by overlap
(frontend/instances.py).
"""

from __future__ import annotations


import cv2
import numpy as np

from moseg_ros.core.baseline import homography_distance, sampson_pixels
from moseg_ros.core.flow_field import away_from_border
from moseg_ros.core.object_flow import refine_by_flow
from moseg_ros.core.robust import fundamental_polished, homography_ransac
from moseg_ros.frontend.evidence import DEPTH_LABEL, Refit, dense_labels
from moseg_ros.frontend.hulls import hull_mask, linked_groups
from moseg_ros.frontend.instances import InstanceTracker, propose_regions
from moseg_ros.frontend.memory import NO_EVIDENCE, Coast, carried, coasted, remembered
from moseg_ros.frontend.motion_config import MotionFrontEndConfig
from moseg_ros.frontend.observe import Observation
from moseg_ros.frontend.window import WindowFrame
from moseg_ros.timing import Stages


class RegionStage:
    """Stage 3, regions: the moving evidence of one frame grouped into regions whose ids last (the module's
    docstring); runs on the frame path and reads the frame only from its ``Observation``."""

    def __init__(self, config: MotionFrontEndConfig) -> None:
        self.config = config
        self._regions = InstanceTracker(keep_apart_after=config.keep_apart_after,
                                        keep_apart_share=config.keep_apart_share,
                                        keep_apart_motion=config.keep_apart_motion)
        self.reset()

    def reset(self) -> None:
        """Forget every region and what the last frames drew."""
        self._regions.reset()
        self._observation: Observation | None = None  # the frame last applied
        self.moving_track_points = np.zeros((0, 2), dtype=np.float32)
        self.moving = np.zeros((0, 0), dtype=bool)
        # The refit the last frame applied and which of its tracks it drew (``depth``).
        self._applied: tuple[Refit | None, np.ndarray] | None = None
        # The last frame's evidence ages (``remembered``) and its index.
        self._memory: tuple[int, np.ndarray] | None = None
        # The refit dense mask the last frame applied: (refit's frame, the frame it was carried to, the mask there).
        self._carry: tuple[int, int, np.ndarray] | None = None
        # The last frame's published regions (its index, labels, its evidence before coasting) and each lasting
        # region's coasting.
        self._published: tuple[int, np.ndarray, np.ndarray] | None = None
        self._coasting: dict[int, Coast] = {}
        # ``_seen_back``'s last answer and what it answered: ((frame, frames back), (rows, now, then)).
        self._seen: tuple[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None

    def apply(self, observation: Observation, refit: Refit | None, stages: Stages) -> np.ndarray:
        """(h, w) int32 moving regions with persistent ids of ``observation``'s frame from ``refit`` (this frame's
        or an older one; None: nothing), timed in ``stages`` (regions)."""
        self._observation = observation
        ids, positions = observation.window[-1]
        with stages("regions"):
            small = observation.gray.shape
            flagged = np.isin(ids, refit.flagged if refit is not None else np.zeros(0, dtype=np.int64))
            scale = small[1] / observation.tracking_shape[1]
            here = flagged & away_from_border(positions * scale, small, self.config.track_border * small[1])
            self.moving_track_points = positions[here]
            # Tracks that lived through the window unflagged, at this size: static evidence.
            settled = positions[np.isin(ids, observation.window[0][0]) & ~flagged] * scale
            link_px = self.config.link_fraction * small[1]
            points = self.moving_track_points * scale
            group = linked_groups(points, link_px, self.config.min_group)
            moving = hull_mask(points, small, link_px, self.config.min_group, settled, self.config.hull_purity, group,
                               self.config.hull_reach * link_px)
            if self.config.object_flow is not None:
                moving = self._refined(observation, moving, here, group, scale, link_px)
            self._applied = (refit, here)
            if refit is not None and refit.dense is not None:
                moving |= self._confirmed(observation, self._carried(observation, refit), refit)
            moving = self._remembered(observation, moving, settled)
            evidence = moving
            moving = self._coasted(observation, moving, settled, scale)
            self.moving = moving
            labels = self._regions.update(propose_regions(moving, self.config.min_region_area, self.config.close_px),
                                          observation.flow_here)
            self._published = (observation.index, labels, evidence)
            return labels

    def window_frame(self, labels: np.ndarray) -> WindowFrame:
        """The current frame as an object-level window of this front-end's regions takes it (``Window(backward=
        True)``, frontend/window.py): ``labels`` (its regions, (h, w) at the dense size), its dense flow back to the
        frame before (None without one) and its tracks at the dense size."""
        observation = self._observation
        ids, points = observation.window[-1]
        scale = observation.gray.shape[1] / observation.tracking_shape[1]
        return WindowFrame(labels, observation.flow_here, ids.copy(), (points * scale).astype(np.float32))

    def depth(self) -> np.ndarray:
        """(h, w) bool at the dense size: the last applied frame's evidence that came from the depth tests
        (cheirality, the ground's, the footing: motion along the epipolar lines), the pixels under its drawn
        tracks that they flagged (``Refit.depth_flagged``) and its dense depth mask carried to it. Worked out when
        asked (frontend/fusion.py), not on every frame."""
        observation = self._observation
        ids, points = observation.window[-1]
        small = observation.gray.shape
        depth = np.zeros(small, dtype=bool)
        if self._applied is None or self._applied[0] is None:
            return depth
        refit, here = self._applied
        scale = small[1] / observation.tracking_shape[1]
        on_depth = here & np.isin(ids, refit.depth_flagged)
        xy = np.clip(np.rint(points[on_depth] * scale).astype(np.int64), 0, [small[1] - 1, small[0] - 1])
        depth[xy[:, 1], xy[:, 0]] = True
        if self._carry is not None and self._carry[1] == observation.index:
            depth |= self._carry[2] == DEPTH_LABEL
        return depth

    def _coasted(self, observation: Observation, moving: np.ndarray, settled: np.ndarray,
                 scale: float) -> np.ndarray:
        """``moving`` with the last frame's lasting regions whose evidence dropped out drawn where their tracks
        went (``coasted``)."""
        last, config = self._published, self.config
        if config.coast_frames <= 0 or last is None or last[0] != observation.index - 1 or len(observation.window) < 2:
            self._coasting = {}
            return moving
        _, now, before = self._seen_back(observation, 1)
        lasting = {region: self._coasting.get(region, Coast()) for region, age in self._regions.ages.items()
                   if age >= config.coast_after}
        out, self._coasting = coasted(moving, last[1], last[2], lasting, before * scale,
                                      now * scale, settled, config.coast_frames, config.coast_tracks,
                                      config.coast_cover, config.memory_veto, observation.flow_here)
        return out

    def _remembered(self, observation: Observation, fresh: np.ndarray, settled: np.ndarray) -> np.ndarray:
        """``fresh`` (h, w) bool with the evidence of the last ``memory_frames`` frames carried to this one
        (``remembered``, with ``settled`` (S, 2) points at this size)."""
        last = self._memory
        before = last[1] if last is not None and last[0] == observation.index - 1 else None
        age = remembered(fresh, before, observation.flow_here, settled, self.config.memory_frames,
                         self.config.memory_veto)
        self._memory = (observation.index, age)
        return age != NO_EVIDENCE

    def _refined(self, observation: Observation, moving: np.ndarray, here: np.ndarray, group: np.ndarray,
                 scale: float, link_px: float) -> np.ndarray:
        """``moving`` grown and trimmed by the flow view around each ``group`` (of the moving tracks, those
        ``here``), from the tracks' and the dense flow's motion back over ``dense_gap`` frames; unchanged
        without this frame's dense flow."""
        gap, flow = self.config.dense_gap, observation.flow_here
        if flow is None or len(observation.window) <= gap or not here.any():
            return moving
        rows, now, before = self._seen_back(observation, gap)
        of_track = np.full(len(here), -1, dtype=np.int64)
        of_track[here] = group
        return refine_by_flow(moving, flow, now * scale, (before - now) * scale, of_track[rows], link_px,
                              self.config.object_flow)

    def _seen_back(self, observation: Observation, frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The current frame's tracks also seen ``frames`` frames back (at most the window's length): (M,) their
        rows in the frame's track arrays, (M, 2) their positions now and then (tracking pixels), by increasing id.
        Worked out once a frame for each ``frames``: the coasting, the flow view and the late dense mask's test
        all ask it."""
        key = (observation.index, frames)
        if self._seen is None or self._seen[0] != key:
            (before_ids, before), (now_ids, now) = observation.window[-1 - frames], observation.window[-1]
            _, rows, columns = np.intersect1d(now_ids, before_ids, assume_unique=True, return_indices=True)
            self._seen = (key, (rows, now[rows], before[columns]))
        return self._seen[1]

    def _carried(self, observation: Observation, refit: Refit) -> np.ndarray:
        """``refit``'s ``dense_labels`` warped from its frame to the current one along the backward flows since:
        one warp a frame while the same refit is applied frame after frame (the last frame's carried labels go one
        flow on, the same steps as warping from the refit's frame each time, and the labels are not drawn again)."""
        index = refit.dense_index
        last, flow = self._carry, observation.flow_here
        if last is not None and last[:2] == (index, observation.index - 1) and flow is not None:
            here = carried(last[2], observation.index - 1, ((observation.index, flow),))
        else:
            here = carried(dense_labels(refit), index, observation.backward)
        self._carry = (index, observation.index, here)
        return here

    def _confirmed(self, observation: Observation, here: np.ndarray, refit: Refit) -> np.ndarray:
        """(h, w) bool: ``refit``'s dense mask, ``here`` as ``dense_labels`` carried to this frame, with the pixels
        of a late one (of an earlier frame) kept where this frame's backward flow leaves its tracks' geometry by
        ``late_dense_px`` (``late_dense_planar_px`` from their homography) or the depth tests flagged them (the
        module's docstring); the whole of it when this frame's geometry is not known."""
        depth, here = here == DEPTH_LABEL, here > 0
        flow = observation.flow_here
        if refit.dense_index >= observation.index or self.config.late_dense_px <= 0 or flow is None or not here.any():
            return here
        ys, xs = np.nonzero(here)
        points = np.stack([xs, ys], axis=1).astype(np.float32)
        distance = self._frame_distance(observation, points, points + flow[ys, xs], refit.dense_planar,
                                        here.shape[1] / observation.tracking_shape[1])
        if distance is None:
            return here
        still = distance >= (self.config.late_dense_planar_px if refit.dense_planar else self.config.late_dense_px)
        kept = depth.copy()
        kept[ys[still], xs[still]] = True
        return kept

    def _frame_distance(self, observation: Observation, points: np.ndarray, matches: np.ndarray, planar: bool,
                        scale: float) -> np.ndarray | None:
        """(N,) distance in pixels of N correspondences of this frame ((N, 2) ``points`` here, ``matches`` in the
        frame before, at ``scale`` times the tracking pixels) from the geometry of the frame's pair of track
        positions: the transfer error of their homography when ``planar``, else the Sampson distance of their F.
        None without enough tracks seen in both, with too little motion to fix it, or with no model."""
        if len(observation.window) < 2:
            return None
        _, now, before = self._seen_back(observation, 1)
        config = self.config.track_motion
        if len(now) < config.min_tracks:
            return None
        if np.median(np.linalg.norm(now - before, axis=1)) < config.min_parallax_px:
            return None
        now, before, inlier_px = now * scale, before * scale, config.inlier_px * scale
        if planar:
            homography, _ = homography_ransac(now, before, cv2.RANSAC, inlier_px)
            return None if homography is None else homography_distance(homography, points, matches)
        fundamental, _ = fundamental_polished(now, before, inlier_px)
        return None if fundamental is None else sampson_pixels(fundamental, points, matches)
