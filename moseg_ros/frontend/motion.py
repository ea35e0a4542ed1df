"""A weight-free motion front-end: frames -> regions that move by themselves, with ids stable over time.

Two kinds of evidence, both residuals of the camera's own (dominant) rigid motion:

- sparse: KLT tracks over a causal window (their backward check shared with the dense flow back to the
  previous frame, frontend/tracks.py); a track moves when its epipolar distance, a median over the
  window's frame pairs, stands out, when its median signed parallax says it lies "behind infinity"
  (cheirality with camera_info's K or a guessed one), or, for a camera driving forward, when it lies farther
  than the road there (ground) or nearer than what is seen under it (footing; all in core/track_motion.py).
  The ground and footing tests also get the pair of the window's first and last frames: near the focus of
  expansion the short pairs' parallax is below their floor, and a car followed there has no other evidence.
  The ground test in pixels (a shortfall against the road) takes only tracks whose image can show motion along
  their parallax (``aperture_share``): on an edge running that way KLT's parallax comes out short.
  The epipolar distance counts only where the dense residual near the track corroborates it, or where it is
  far above its threshold (``TrackMotionConfig.corroboration``): KLT drifts where its window straddles a near
  edge, the dense flow does not. The residual is the last refit's, read where the track was in its frame, so
  that the track test needs nothing of the dense half of its own refit and can be handed over first.
  A track flagged in ``sticky_windows`` windows stays flagged until ``sticky_frames`` frames have passed
  without a flag (not while it lives: a track that slips off a mover onto the background would trail it
  forever); a refit that comes several frames after the one before (a background refit slower than the camera)
  counts its flags for each window it stands in for, so that a slow refit's flags stick as soon as every
  frame's refits' would. Flagged tracks closer than ``link_fraction`` of the image width are linked, and each
  group of ``min_group`` or more fills its hull (frontend/regions.py: the triangles between its tracks no longer
  than ``hull_reach`` times the link distance), unless the tracks that lived through the whole window unflagged
  make up more than 1 - ``hull_purity`` of the tracks inside its convex hull; flagged tracks within
  ``track_border`` of the image's border are not drawn. The flow view then grows each hull
  over the pixels whose dense flow follows the group's own flow model, and trims what follows the
  background's around it (``object_flow``, core/object_flow.py).
- dense: DIS flow at ``dense_width`` between the frame and the one ``dense_gap`` frames back, forward-backward
  checked and landing away from the earlier frame's border; pixels far from the dominant motion
  (core/baseline.py) where the image has texture (``min_texture``), or within ``texture_reach`` pixels of
  texture where the flow is at most ``smooth_max_flow`` (DIS carries a small motion from textured edges into
  the smooth body of an animal or a car, but not a large one: the near road of a driving camera), and pixels
  behind infinity by more than ``dense_cheir_px`` (core/track_motion.behind_infinity, textured or not: the
  smooth body of an object the camera follows has a flow of about zero, which its few tracks cannot fill; a
  smooth region only where it joins such pixels the flow can be trusted at, since far from any texture DIS's
  flow is its smoothing's guess, and a blank sky came out behind infinity), and,
  with ``dense_footing``, pixels nearer than the road under them (core/track_motion.nearer_than_road: the
  footing test of the tracks on every pixel, for the oncoming car).

The dense mask holds on for a frame where it goes on: of the last refit's dense mask, carried along the flow,
the regions that touch this refit's are kept (hysteresis, as in Canny's edges: a mover's residual flickers
around the threshold from frame to frame, a lone blob of noise is not repeated). A dense mask applied to a later
frame than its own (a background refit a frame or more behind the camera) keeps the pixels its residual flagged
only where that frame's backward flow still leaves the geometry of its tracks by ``late_dense_px`` (their
epipolar geometry), or by ``late_dense_planar_px`` (their homography) when the refit's residual was against a
homography (the F of a camera that only turns is degenerate and takes a slow mover's motion in: DAVIS cows): the
mask holds what moved between the two frames before, and a limb that stopped, or the background a mover uncovered,
comes along with it. The pixels the depth tests flagged stay (their motion lies in the epipolar plane).

Both are drawn at ``dense_width``. Their union is remembered (frontend/memory.py) for ``memory_frames`` frames:
evidence that drops out (a looming car's tracks and flow, a small fast mover's flicker) is carried along the
backward flow, unless ``memory_veto`` tracks that lived through the window unflagged lie in what is carried. A
region published ``coast_after`` frames in a row coasts as a tracker's object does when its detections drop out
(``coasted``): where its evidence, moved by the similarity of the tracks on it (once they have died, by their last
similarity and along the dense flow), is no longer covered by this frame's evidence, it is drawn there for up to
``coast_frames`` frames (a car passing the camera, whose tracks die of its growth and whose flow fails its check).
The result, closed and opened, is split into connected regions of ``min_region_area`` pixels or more, and the
InstanceTracker gives them persistent ids, matching them against the last frame's regions moved along the flow; a
region that took in two it had seen apart for ``keep_apart_after`` frames and that move apart is split between them
first (two movers that touch in the image keep their ids; two parts of one mover join).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from moseg_ros.core.baseline import (BaselineConfig, EpipolarResidual, epipolar_residual, homography_distance,
                                    sampson_pixels)
from moseg_ros.core.flow_field import MIN_WORKING_SIDE, away_from_border, shrink_scale
from moseg_ros.core.object_flow import ObjectFlowConfig, refine_by_flow
from moseg_ros.core.robust import fundamental_polished, homography_ransac
from moseg_ros.core.track_motion import PairEvidence, depth_moving, moving_tracks, pair_evidence
from moseg_ros.core.track_tests.cheirality import DenseParallax, behind_infinity, dense_parallax, guessed_camera_matrix
from moseg_ros.core.track_tests.epipolar import beyond_allowance
from moseg_ros.core.track_tests.footing import nearer_than_road
from moseg_ros.core.track_tests.ground import aperture_share, short_of_ground
from moseg_ros.core.track_tests.settings import TrackMotionConfig
from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.instances import InstanceTracker, propose_regions
from moseg_ros.frontend.memory import NO_EVIDENCE, Coast, carried, coasted, remembered
from moseg_ros.frontend.regions import hull_mask, linked_groups, touching
from moseg_ros.frontend.tracks import PointTracker, TrackerConfig
from moseg_ros.frontend.window import WindowFrame
from moseg_ros.timing import Stages


@dataclass(frozen=True)
class MotionFrontEndConfig:
    """Settings of the motion front-end (pixels at the working resolution unless a fraction of the width)."""

    window_length: int = 8
    # KLT's window at the tracking width (1280 px): a smaller window drifts less where it straddles a mover's
    # edge (fewer static points flagged on KT3DMoSeg) and follows smaller movers, and each point costs less;
    # 13 px rather than 17 once the dense flow was DIS medium (21 -> 17 with fast, whose coarse flow needed
    # the tracks' wider reach; docs/experiments.md has both measurements). Corners are found at the dense width, with
    # a quality floor low enough that as many are found there as at full size.
    tracks: TrackerConfig = field(default_factory=lambda: TrackerConfig(max_points=2000, window=13, quality=0.001,
                                                                        seed_width=640))
    track_motion: TrackMotionConfig = field(default_factory=TrackMotionConfig)
    sticky_windows: int = 2
    sticky_frames: int = 8
    link_fraction: float = 0.032
    # Three linked flagged tracks make a region: a pedestrian at 621 px holds two to five tracks (docs/experiments.md).
    min_group: int = 3
    # A moving object carries its tracks along, so tracks that lived through the whole window unflagged are
    # static evidence: a hull where they outnumber the flagged tracks is scattered noise (water, a crowd,
    # drifting tracks in foliage), not an object. Young tracks do not count: a moving car keeps gaining new
    # ones that the test has not flagged yet.
    hull_purity: float = 0.5
    # A group of four or more fills only the triangles of its tracks' Delaunay triangulation whose sides are at most
    # this many times the link distance, not its convex hull, which bridges the bays between its tracks: the gap
    # between a van and the few tracks flagged in a tree beside it, water around a swan (docs/experiments.md). At
    # 1.5 a car followed by a 30 Hz camera, whose few flagged tracks lie far apart, lost a seventh of its frames.
    # 0: the convex hull.
    hull_reach: float = 2.0
    dense: bool = True
    dense_gap: int = 1
    dense_width: int = 640
    # The dense frame holds at most this many pixels too (0: any; the pipeline's ``working_pixels``), so that a
    # tall frame costs what a KITTI one does.
    dense_pixels: int = 0
    # Matches landing within 5 % of the width (32 px at 640) of the earlier frame's border are not trusted: DIS
    # extrapolates there, and in a turn the band entering the view came out moving (docs/experiments.md).
    dense_baseline: BaselineConfig = field(default_factory=lambda: BaselineConfig(
        residual_threshold_px=1.0, residual_noise_factor=5.0, border_fraction=0.05))
    # The dense residual counts only beyond this share of each pixel's flow, as the track test's distance does
    # beyond ``TrackMotionConfig.epipole_allowance`` of its displacement: the frame pair's F is off by a small angle,
    # and near static surfaces that flow fast (a parked car or a wall at the image's side) came out moving. On
    # KITTI 07's 134 static frames it took the masked share from 0.79 to 0.49 %, at 0.3 points of KT3DMoSeg's
    # recall (docs/experiments.md). The residual that corroborates a track (``corroboration_reach``) counts the
    # same way. 0: off.
    dense_allowance: float = 0.06
    # The dense residual that corroborates a track's epipolar distance (``TrackMotionConfig.corroboration``) is
    # the largest within this many pixels of it at the dense width; where it reaches ``corroboration_floor`` of
    # the dense threshold it corroborates any distance (DIS at the dense width blurs a small far mover into
    # the background around it, and its residual comes out a fraction of its tracks'; docs/experiments.md).
    corroboration_floor: float = 0.25
    corroboration_reach: int = 2
    # The ground's shortfall test (``TrackMotionConfig.shortfall_px``) takes a track only where at least this
    # share of the image-gradient energy in a window of this many pixels (at the dense width) around it lies
    # along its parallax (``aperture_share``, from the principal point): tracks on kerbs and shadow edges near
    # the horizon came out farther than the road (docs/experiments.md). 0: every track.
    aperture_share: float = 0.25
    aperture_window: int = 7
    min_region_area: int = 80
    min_texture: float = 1e-3
    texture_reach: int = 12
    smooth_max_flow: float = 8.0
    close_px: int = 5
    dense_cheir_px: float = 1.0
    # The footing test on every pixel of the dense flow (core/track_motion.nearer_than_road, with the track test's
    # footing settings): a far oncoming car holds few tracks, and the first road track under it lies well below
    # the road it stands on (docs/experiments.md).
    dense_footing: bool = True
    # Its least excess over the footing, in the dense flow's pixels over ``dense_gap`` frames: a far oncoming car
    # moves 2-4 px a frame at 640 px, and the track test's 1 px (at full size over two frames) stopped it; 0.25 is
    # about that 1 px in these units. With the footing's allowance near the horizon at the road's tolerance, the far
    # car's excess is a fifth to a quarter of a pixel; 0.2 and 0.15 flagged no more of KITTI 07 (docs/experiments.md).
    dense_footing_px: float = 0.2
    # A pixel's footing counts only where its column holds road more than this share of the dense flow's height
    # below it: the road's tolerance lets a near parked car's own bumper pass for road where the image's lower edge
    # (and the border DIS is not trusted at) hides the road under it, and its number plate came out nearer than
    # that. On KITTI 07 the masked share fell from 0.33 to 0.27 %; more clearance (0.05, 0.08) took more of
    # KT3DMoSeg's movers near the image's bottom (docs/experiments.md). 0: any road under it.
    dense_footing_clearance: float = 0.03
    # Keep the last refit's dense regions that touch this one's (the module's docstring): regions rather than the
    # whole last mask, which flagged more static pixels for the same recall (docs/experiments.md).
    dense_hysteresis: bool = True
    # A late dense mask keeps its residual's pixels where this frame's flow leaves its tracks' epipolar geometry by
    # this much (dense pixels; the module's docstring). 0: keeps the whole mask.
    late_dense_px: float = 0.3
    # The same against the track pair's homography when the refit's residual was against one: its transfer error
    # counts a pixel's whole displacement, the Sampson distance about half of its part across the epipolar line.
    late_dense_planar_px: float = 0.6
    # Moving tracks closer to the image's border than this share of its width are not drawn: there KLT's window
    # and pyramid are clipped and what enters or leaves the view has half its support (KITTI 07's remaining
    # false hulls in its turn were there; docs/experiments.md).
    track_border: float = 0.03
    # The flow view around each hull (core/object_flow.py): grows smooth bodies, trims swallowed background.
    # None: hulls as drawn.
    object_flow: ObjectFlowConfig | None = field(default_factory=ObjectFlowConfig)
    # Frames the moving evidence is remembered after it drops out (``remembered``). One bridges a lost frame;
    # each more frame catches more of the synthetic looming and crossing cars and carries more false regions on
    # real streets (docs/experiments.md). 0: off.
    memory_frames: int = 1
    memory_veto: int = 3
    # A region published ``coast_after`` frames in a row whose evidence, moved by the similarity of the tracks on
    # it (``coast_tracks`` or more, of any age; with fewer, by their last similarity and along the dense flow), is
    # less than ``coast_cover`` evidence now is drawn there for up to ``coast_frames`` frames in a row (``coasted``):
    # a looming or small fast car's evidence drops out for a few frames. Each more frame (1-4) and a higher cover
    # (0.5-0.7) caught more of the synthetic cars at a few hundredths of a point of KT3DMoSeg's static points
    # (docs/experiments.md). 0: off.
    coast_frames: int = 4
    coast_after: int = 3
    coast_tracks: int = 4
    coast_cover: float = 0.7
    # Two regions seen apart for ``keep_apart_after`` frames in a row each keep their id when their evidence joins
    # (frontend/instances.kept_apart: each lies at least ``keep_apart_share`` inside the joined region), unless
    # their median flows differ by no more than ``keep_apart_motion`` of the faster one's (frontend/instances.
    # same_motion): then they are two parts of one mover, and join. 0: off (docs/experiments.md).
    keep_apart_after: int = 3
    keep_apart_share: float = 0.5
    keep_apart_motion: float = 0.3
    # The most track pairs of skipped frames a refit fits before its own, newest first (``_catch_up``): each costs
    # as much as the refit's own pair fit (one was the most a refit could afford while MAGSAC++ fitted them). 8:
    # every skipped frame's of a window of eight.
    catch_up_pairs: int = 8


def scaled_to(K: np.ndarray, size: tuple[int, int], resized: tuple[int, int]) -> np.ndarray:
    """K of an image of ``size`` (H, W) for the same image resized to ``resized``."""
    return np.diag([resized[1] / size[1], resized[0] / size[0], 1.0]) @ K


# A frame is halved by the Gaussian pyramid while the half keeps this share of the size it is shrunk to: the step
# after it, then a slight enlargement, is smooth (pyrDown's Gaussian already removed what would alias).
PYRAMID_SLACK = 0.9


def resized_to_width(gray: np.ndarray, width: int, max_pixels: int = 0) -> np.ndarray:
    """``gray`` shrunk to ``width`` pixels wide and, when ``max_pixels`` > 0, at most that many pixels, keeping its
    aspect and at least MIN_WORKING_SIDE px a side (``shrink_scale``: the pipeline's working size); returned as is
    when it is not larger.

    Halved by ``cv2.pyrDown`` while the half keeps ``PYRAMID_SLACK`` of that size, then resized the rest of the way
    (INTER_LINEAR up, INTER_AREA down): INTER_AREA at a factor like KITTI's 1226 -> 640 takes 1.2 ms on the frame
    path, the pyramid's halving and a 4 % linear enlargement 0.2 ms (docs/experiments.md)."""
    scale = shrink_scale(*gray.shape, width, max_pixels, MIN_WORKING_SIDE)
    if scale == 1.0:
        return gray
    size = (round(gray.shape[1] * scale), round(gray.shape[0] * scale))
    while gray.shape[1] // 2 >= PYRAMID_SLACK * size[0] and gray.shape[0] // 2 >= PYRAMID_SLACK * size[1]:
        gray = cv2.pyrDown(gray)
    if gray.shape[1::-1] == size:
        return gray
    return cv2.resize(gray, size, interpolation=cv2.INTER_LINEAR if gray.shape[1] < size[0] else cv2.INTER_AREA)


def dense_near(points: np.ndarray, residual: np.ndarray, reach: int) -> np.ndarray:
    """(N,) the largest of the (h, w) ``residual`` within ``reach`` pixels (a square) of each of the (N, 2)
    ``points`` (x, y at the residual's size; points outside take the nearest border pixel)."""
    if reach > 0:
        residual = cv2.dilate(residual, np.ones((2 * reach + 1, 2 * reach + 1), dtype=np.uint8))
    h, w = residual.shape
    xy = np.clip(np.rint(points).astype(np.int64), 0, [w - 1, h - 1])
    return residual[xy[:, 1], xy[:, 0]]


# The label of the depth tests' pixels in ``dense_labels`` (1: the rest of the dense mask).
DEPTH_LABEL = 2


def dense_labels(refit: Refit) -> np.ndarray:
    """(h, w) uint8 ``refit``'s dense mask as labels, carried along the flow as one: DEPTH_LABEL where the depth tests
    flagged a pixel (``Refit.dense_depth``, a part of the mask), 1 elsewhere in it, 0 outside."""
    labels = refit.dense.astype(np.uint8)
    if refit.dense_depth is not None:
        labels[refit.dense_depth] = DEPTH_LABEL
    return labels


@dataclass(frozen=True)
class Observation:
    """What the refit needs from one frame, taken on the frame path and not changed afterwards.

    Attributes:
        index: the frame's number since the last reset.
        camera_matrix: (3, 3) K at the tracking size (camera_info's, or guessed without it).
        flows: dense (backward now -> then, forward then -> now) flows at the dense size, or None; the frame
            path computes only the backward one (forward None), the refit the forward one from ``earlier``.
        gray: the frame at the dense size (for the texture gate).
        tracking_shape: (H, W) of the frame as tracked (``camera_matrix``'s size).
        window: (ids, points) of the window's frames, oldest first and this frame last, so that a refit that
            skipped frames fits their track pairs too (``MotionFrontEnd.refit``); empty: no tracks yet.
        gap: frames between the two frames of a short track pair (``TrackMotionConfig.gap``).
        backward: (frame, backward dense flow to the frame before) of the last frames, oldest first and this
            frame last, to carry an earlier refit's dense mask to this frame.
        earlier: the frame ``dense_gap`` back at the dense size (for the refit's forward flow), or None.
    """

    index: int
    camera_matrix: np.ndarray
    flows: tuple[np.ndarray, np.ndarray] | None
    gray: np.ndarray
    tracking_shape: tuple[int, int]
    window: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    gap: int = TrackMotionConfig().gap
    backward: tuple[tuple[int, np.ndarray], ...] = ()
    earlier: np.ndarray | None = None

    @property
    def first(self) -> int:
        """The frame number (``index``'s count) of the window's first frame: ``window[k]`` is frame ``first + k``."""
        return self.index - len(self.window) + 1

    @property
    def alive(self) -> np.ndarray:
        """Ids of the tracks living now."""
        return self.window[-1][0] if self.window else np.zeros(0, dtype=np.int64)

    @property
    def pair(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """(ids, points, ids, points) of the frames ``gap`` back and now, or None before the window holds both."""
        return (*self.window[-1 - self.gap], *self.window[-1]) if len(self.window) > self.gap else None

    @property
    def long_pair(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The same for the window's first frame and now, or None until the window holds more than ``gap`` + 1
        frames (near the focus of expansion the short pairs' parallax is below their floor, and the first frames
        of a stream would wait for the window to fill)."""
        return (*self.window[0], *self.window[-1]) if len(self.window) > self.gap + 1 else None

    @property
    def long_span(self) -> int:
        """Frames between the long pair's two frames (0 without one)."""
        return len(self.window) - 1 if self.long_pair is not None else 0


@dataclass(frozen=True)
class Refit:
    """The motion evidence fitted on one observation: which tracks move (the track test of frame ``index``), and
    the dense residual mask of frame ``dense_index`` (``index`` when both were fitted on it; an earlier frame's
    when the track test comes first, see ``MotionFrontEnd.refit_tracks``; -1 with no dense mask yet) and the part of
    it the depth tests flagged (``dense_depth``), and whether its residual was against a homography
    (``dense_planar``); ``stages`` times the work done for frame ``index``. ``depth_flagged``: the flagged tracks
    that the depth tests flagged (``depth_moving``), now or while they have stayed flagged since."""

    index: int
    flagged: np.ndarray
    dense: np.ndarray | None
    stages: dict[str, float]
    dense_index: int
    dense_depth: np.ndarray | None = None
    dense_planar: bool = False
    depth_flagged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


class MotionFrontEnd:
    """Turns a stream of grey frames into moving regions with persistent ids.

    Per frame, :meth:`update` is :meth:`observe` (tracks and flow: the frame path), :meth:`refit` (the fits
    and tests) and :meth:`apply` (hulls of the moving tracks where they are now, the dense mask carried to
    now, regions). A caller may run ``refit`` elsewhere (moseg_ros/refit.py) and apply the newest refit
    that is done: ``apply`` draws the tracks a refit flagged at their current positions and warps its dense
    mask along the flow of the frames since. ``refit`` touches only its own state (the window's pair fits
    and the sticky flags), ``observe`` and ``apply`` only theirs.
    """

    def __init__(self, config: MotionFrontEndConfig = MotionFrontEndConfig(), flow: DenseFlow | None = None) -> None:
        self.config = config
        self._points = PointTracker(config.tracks)
        self._flow = flow or DenseFlow("fast")
        # The refit's own: a DIS instance is not to be shared between threads.
        self._refit_flow = DenseFlow(self._flow.preset)
        self._regions = InstanceTracker(keep_apart_after=config.keep_apart_after,
                                        keep_apart_share=config.keep_apart_share,
                                        keep_apart_motion=config.keep_apart_motion)
        self.stages = Stages()
        self.reset()

    def reset(self) -> None:
        """Forget every frame, track and region."""
        self._points.reset()
        self._regions.reset()
        self._index = -1
        self._frames: collections.deque[tuple[np.ndarray, np.ndarray]] = collections.deque(
            maxlen=max(self.config.window_length, self.config.track_motion.gap + 1))
        self._grays: collections.deque[np.ndarray] = collections.deque(maxlen=self.config.dense_gap + 1)
        # The backward dense flow (frame -> the one before) of the last frames, to carry an older refit's
        # dense mask to the current frame.
        self._backward: collections.deque[tuple[int, np.ndarray]] = collections.deque(
            maxlen=self.config.window_length)
        self.reset_refit()
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

    def reset_refit(self) -> None:
        """Forget the refit's state: the window's pair fits, the sticky flags and the last dense mask."""
        # One (track ids, PairEvidence) per frame pair (m, m + gap) of the window: each pair is fitted once.
        self._pairs: collections.deque[tuple[np.ndarray, PairEvidence]] = collections.deque(
            maxlen=self.config.window_length - self.config.track_motion.gap)
        # Living tracks that were ever flagged (sorted ids), in how many windows, and the last frame flagged.
        self._flag_ids = np.zeros(0, dtype=np.int64)
        self._flag_counts = np.zeros(0, dtype=np.int64)
        self._flag_last = np.zeros(0, dtype=np.int64)
        self._depth_ids = np.zeros(0, dtype=np.int64)  # flagged tracks the depth tests flagged (Refit.depth_flagged)
        self._counted_through: int | None = None  # the frame of the last refit whose flags were counted
        # The last refit's own dense mask (before hysteresis) and its frame.
        self._last_dense: tuple[int, np.ndarray] | None = None
        # The newest frame whose track pair has been fitted (a refit that skipped frames fits theirs first).
        self._fitted_through = -1
        # The last dense residual (its frame, EpipolarResidual), which corroborates the next track tests, and the
        # last refit with a dense mask, whose dense part the next track tests' refits carry on.
        self._evidence: tuple[int, EpipolarResidual] | None = None
        self._published_dense: Refit | None = None

    def update(self, gray: np.ndarray, camera_matrix: np.ndarray | None = None) -> np.ndarray:
        """Take the next frame ((H, W) uint8, tracked at this size) and, when calibrated, its (3, 3) camera
        matrix at this size; returns (h, w) int32 moving regions with persistent ids at the dense size
        (``dense_width`` wide).

        ``moving`` then holds the frame's (h, w) bool evidence (hulls and dense residual) before grouping,
        ``moving_track_points`` the (M, 2) positions of its moving tracks (tracking pixels), and
        ``stages.seconds`` the time of each stage: tracks, flow (the dense flow back to the frame before), fit
        (pair fits and the track test), dense_flow (the dense flow forward, for the residual's check), dense_fit
        (the dense residual test) and regions (hulls, carrying, regions)."""
        observation = self.observe(gray, camera_matrix)
        refit = self.refit(observation)
        labels = self.apply(refit)
        self.stages.seconds.update(refit.stages)
        return labels

    def observe(self, gray: np.ndarray, camera_matrix: np.ndarray | None = None) -> Observation:
        """The frame path's part: compute the dense flow back to the frame before, track into ``gray``; returns
        what the refit needs.

        Clears ``stages`` (a new frame)."""
        self.stages.clear()
        self._index += 1
        with self.stages("tracks"):
            self._grays.append(resized_to_width(gray, self.config.dense_width, self.config.dense_pixels))
        flows, earlier = None, None
        if self.config.dense and len(self._grays) > self.config.dense_gap:
            with self.stages("flow"):
                earlier, now = self._grays[0], self._grays[-1]
                # Only the backward flow: the refit computes the forward one it needs off the frame path.
                flows = (self._flow(now, earlier), None)
            self._backward.append((self._index, flows[0]))
        with self.stages("tracks"):
            # The dense flow back to the previous frame is the tracks' starting guess (inverted) and backward
            # check too (frontend/tracks.py).
            self._points.update(gray, flows[0] if flows is not None and self.config.dense_gap == 1 else None,
                                self._grays[-1])
            self._frames.append((self._points.ids.copy(), self._points.points.copy()))
        K = guessed_camera_matrix(gray.shape) if camera_matrix is None else camera_matrix
        self._tracking_shape = gray.shape
        return Observation(self._index, K, flows, self._grays[-1], gray.shape, tuple(self._frames),
                           self.config.track_motion.gap, tuple(self._backward), earlier)

    def refit(self, observation: Observation) -> Refit:
        """The fits and tests of one observation: ``refit_tracks`` then ``refit_dense``."""
        return self.refit_dense(observation, self.refit_tracks(observation))

    def refit_tracks(self, observation: Observation) -> Refit:
        """The track test of one observation (the window's pairs with sticky flags), its epipolar distances
        corroborated by the last dense residual; the Refit carries the last dense mask (``dense_index``: its
        frame). The cheaper half of a refit, and the one whose age costs: a decision whose track flags are two
        frames old loses what one whose dense mask is three frames old does not (docs/experiments.md), so a
        background worker hands it over before it fits the dense half."""
        stages = Stages()
        with stages("fit"):
            flagged, depth = self._flagged(observation)
        if self._published_dense is None:
            return Refit(observation.index, flagged, None, stages.seconds, -1, depth_flagged=depth)
        return replace(self._published_dense, index=observation.index, flagged=flagged, depth_flagged=depth,
                       stages=stages.seconds)

    def refit_dense(self, observation: Observation, tracks: Refit) -> Refit:
        """``tracks`` (this observation's ``refit_tracks``) with this observation's dense residual mask, whose
        residual corroborates the next track tests; ``stages`` adds dense_flow and dense_fit."""
        stages = Stages()
        evidence = None
        if observation.flows is not None:
            backward, forward = observation.flows
            if forward is None:
                with stages("dense_flow"):
                    forward = self._refit_flow(observation.earlier, observation.gray)
            with stages("dense_fit"):
                evidence = self._counted(epipolar_residual(backward, forward, self.config.dense_baseline), backward)
        self._evidence = None if evidence is None else (observation.index, evidence)
        dense = depth = None
        if evidence is not None:
            with stages("dense_fit"):
                moving, depth = self._dense_mask(observation, evidence)
                dense = self._held(moving, observation)
        planar = evidence is not None and evidence.homography is not None
        refit = replace(tracks, dense=dense, dense_index=observation.index, dense_depth=depth, dense_planar=planar,
                        stages={**tracks.stages, **stages.seconds})
        self._published_dense = None if dense is None else refit
        return refit

    def apply(self, refit: Refit | None) -> np.ndarray:
        """Moving regions of the current frame from ``refit`` (this frame's or an older one; None: nothing)."""
        with self.stages("regions"):
            small = self._grays[-1].shape
            flagged = np.isin(self._points.ids, refit.flagged if refit is not None else np.zeros(0, dtype=np.int64))
            scale = small[1] / self._tracking_shape[1]
            here = flagged & away_from_border(self._points.points * scale, small, self.config.track_border * small[1])
            self.moving_track_points = self._points.points[here]
            # Tracks that lived through the window unflagged, at this size: static evidence.
            settled = self._points.points[np.isin(self._points.ids, self._frames[0][0]) & ~flagged] * scale
            link_px = self.config.link_fraction * small[1]
            points = self.moving_track_points * scale
            group = linked_groups(points, link_px, self.config.min_group)
            moving = hull_mask(points, small, link_px, self.config.min_group, settled, self.config.hull_purity, group,
                               self.config.hull_reach * link_px)
            if self.config.object_flow is not None:
                moving = self._refined(moving, here, group, scale, link_px)
            self._applied = (refit, here)
            if refit is not None and refit.dense is not None:
                moving |= self._confirmed(self._carried(refit), refit)
            moving = self._remembered(moving, settled)
            evidence = moving
            moving = self._coasted(moving, settled, scale)
            self.moving = moving
            labels = self._regions.update(propose_regions(moving, self.config.min_region_area, self.config.close_px),
                                          self._flow_here())
            self._published = (self._index, labels, evidence)
            return labels

    def window_frame(self, labels: np.ndarray) -> WindowFrame:
        """The current frame as an object-level window of this front-end's regions takes it (``Window(backward=
        True)``, frontend/window.py): ``labels`` (its regions, (h, w) at the dense size), its dense flow back to the
        frame before (None without one) and its tracks at the dense size."""
        ids, points = self._frames[-1]
        scale = self._grays[-1].shape[1] / self._tracking_shape[1]
        return WindowFrame(labels, self._flow_here(), ids.copy(), (points * scale).astype(np.float32))

    def depth(self) -> np.ndarray:
        """(h, w) bool at the dense size: the last applied frame's evidence that came from the depth tests
        (cheirality, the ground's, the footing: motion along the epipolar lines), the pixels under its drawn
        tracks that they flagged (``Refit.depth_flagged``) and its dense depth mask carried to it. Worked out when
        asked (methods/object_fusion.py), not on every frame."""
        small = self._grays[-1].shape
        depth = np.zeros(small, dtype=bool)
        if self._applied is None or self._applied[0] is None:
            return depth
        refit, here = self._applied
        scale = small[1] / self._tracking_shape[1]
        on_depth = here & np.isin(self._points.ids, refit.depth_flagged)
        xy = np.clip(np.rint(self._points.points[on_depth] * scale).astype(np.int64), 0, [small[1] - 1, small[0] - 1])
        depth[xy[:, 1], xy[:, 0]] = True
        if self._carry is not None and self._carry[1] == self._index:
            depth |= self._carry[2] == DEPTH_LABEL
        return depth

    def _coasted(self, moving: np.ndarray, settled: np.ndarray, scale: float) -> np.ndarray:
        """``moving`` with the last frame's lasting regions whose evidence dropped out drawn where their tracks
        went (``coasted``)."""
        last, config = self._published, self.config
        if config.coast_frames <= 0 or last is None or last[0] != self._index - 1 or len(self._frames) < 2:
            self._coasting = {}
            return moving
        _, now, before = self._seen_back(1)
        lasting = {region: self._coasting.get(region, Coast()) for region, age in self._regions.ages.items()
                   if age >= config.coast_after}
        out, self._coasting = coasted(moving, last[1], last[2], lasting, before * scale,
                                      now * scale, settled, config.coast_frames, config.coast_tracks,
                                      config.coast_cover, config.memory_veto, self._flow_here())
        return out

    def _remembered(self, fresh: np.ndarray, settled: np.ndarray) -> np.ndarray:
        """``fresh`` (h, w) bool with the evidence of the last ``memory_frames`` frames carried to this one
        (``remembered``, with ``settled`` (S, 2) points at this size)."""
        last = self._memory
        before = last[1] if last is not None and last[0] == self._index - 1 else None
        age = remembered(fresh, before, self._flow_here(), settled, self.config.memory_frames, self.config.memory_veto)
        self._memory = (self._index, age)
        return age != NO_EVIDENCE

    def _refined(self, moving: np.ndarray, here: np.ndarray, group: np.ndarray, scale: float,
                 link_px: float) -> np.ndarray:
        """``moving`` grown and trimmed by the flow view around each ``group`` (of the moving tracks, those
        ``here``), from the tracks' and the dense flow's motion back over ``dense_gap`` frames; unchanged
        without this frame's dense flow."""
        gap, flow = self.config.dense_gap, self._flow_here()
        if flow is None or len(self._frames) <= gap or not here.any():
            return moving
        rows, now, before = self._seen_back(gap)
        of_track = np.full(len(here), -1, dtype=np.int64)
        of_track[here] = group
        return refine_by_flow(moving, flow, now * scale, (before - now) * scale, of_track[rows], link_px,
                              self.config.object_flow)

    def _seen_back(self, frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The current frame's tracks also seen ``frames`` frames back (at most the window's length): (M,) their
        rows in the frame's track arrays, (M, 2) their positions now and then (tracking pixels), by increasing id.
        Worked out once a frame for each ``frames``: the coasting, the flow view and the late dense mask's test
        all ask it."""
        key = (self._index, frames)
        if self._seen is None or self._seen[0] != key:
            (before_ids, before), (now_ids, now) = self._frames[-1 - frames], self._frames[-1]
            _, rows, columns = np.intersect1d(now_ids, before_ids, assume_unique=True, return_indices=True)
            self._seen = (key, (rows, now[rows], before[columns]))
        return self._seen[1]

    def _flow_here(self) -> np.ndarray | None:
        """The current frame's dense flow back to the frame before, None when it has none."""
        return self._backward[-1][1] if self._backward and self._backward[-1][0] == self._index else None

    def _carried(self, refit: Refit) -> np.ndarray:
        """``refit``'s ``dense_labels`` warped from its frame to the current one along the backward flows since:
        one warp a frame while the same refit is applied frame after frame (the last frame's carried labels go one
        flow on, the same steps as warping from the refit's frame each time, and the labels are not drawn again)."""
        index = refit.dense_index
        last, flow = self._carry, self._flow_here()
        if last is not None and last[:2] == (index, self._index - 1) and flow is not None:
            here = carried(last[2], self._index - 1, ((self._index, flow),))
        else:
            here = carried(dense_labels(refit), index, tuple(self._backward))
        self._carry = (index, self._index, here)
        return here

    def _confirmed(self, here: np.ndarray, refit: Refit) -> np.ndarray:
        """(h, w) bool: ``refit``'s dense mask, ``here`` as ``dense_labels`` carried to this frame, with the pixels
        of a late one (of an earlier frame) kept where this frame's backward flow leaves its tracks' geometry by
        ``late_dense_px`` (``late_dense_planar_px`` from their homography) or the depth tests flagged them (the
        module's docstring); the whole of it when this frame's geometry is not known."""
        depth, here = here == DEPTH_LABEL, here > 0
        flow = self._flow_here()
        if refit.dense_index >= self._index or self.config.late_dense_px <= 0 or flow is None or not here.any():
            return here
        ys, xs = np.nonzero(here)
        points = np.stack([xs, ys], axis=1).astype(np.float32)
        distance = self._frame_distance(points, points + flow[ys, xs], refit.dense_planar,
                                        here.shape[1] / self._tracking_shape[1])
        if distance is None:
            return here
        still = distance >= (self.config.late_dense_planar_px if refit.dense_planar else self.config.late_dense_px)
        kept = depth.copy()
        kept[ys[still], xs[still]] = True
        return kept

    def _frame_distance(self, points: np.ndarray, matches: np.ndarray, planar: bool,
                        scale: float) -> np.ndarray | None:
        """(N,) distance in pixels of N correspondences of this frame ((N, 2) ``points`` here, ``matches`` in the
        frame before, at ``scale`` times the tracking pixels) from the geometry of the frame's pair of track
        positions: the transfer error of their homography when ``planar``, else the Sampson distance of their F.
        None without enough tracks seen in both, with too little motion to fix it, or with no model."""
        if len(self._frames) < 2:
            return None
        _, now, before = self._seen_back(1)
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

    def _held(self, dense: np.ndarray, observation: Observation) -> np.ndarray:
        """``dense`` with the regions of the last refit's dense mask, carried to this frame, that touch it
        (``dense_hysteresis``); as it is when the flows back to that refit are no longer held."""
        last, self._last_dense = self._last_dense, (observation.index, dense)
        if not self.config.dense_hysteresis or last is None or last[1].shape != dense.shape:
            return dense
        frames = [frame for frame, _ in observation.backward]
        if not frames or frames[0] > last[0] + 1:
            return dense
        return dense | touching(carried(last[1], last[0], observation.backward), dense)

    def _flagged(self, observation: Observation) -> tuple[np.ndarray, np.ndarray]:
        """Ids of the observed frame's tracks that move (this window, or sticky from earlier windows), and of
        those among them the depth tests flagged (this window, or in an earlier one while they stayed flagged:
        ``Refit.depth_flagged``); a track's epipolar distance counts only where the last dense residual near it
        corroborates it (``TrackMotionConfig.corroboration``, ``_dense_near``)."""
        self._catch_up(observation)
        newest = None
        if observation.pair is not None:
            newest = self._fit_pair(*observation.pair, observation)
            if newest is not None:
                self._pairs.append(newest)
        # The long pair is fitted only while the newest short pair decides a sign (a translating camera, F
        # not degenerate): the ground and footing tests need nothing else.
        long = None
        if observation.long_pair is not None and newest is not None and newest[1].signed is not None:
            long = self._fit_pair(*observation.long_pair, observation, observation.long_span)
        if not self._pairs:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        ids = np.unique(np.concatenate([pair[0] for pair in self._pairs]))
        # (distance, signed, ground, footing, shortfall) x (track, pair), NaN where a pair did not measure it; the
        # last column is the long pair's, which gives only the ground, footing and shortfall tests.
        tables = np.full((len(PairEvidence._fields), ids.size, len(self._pairs) + 1), np.nan, dtype=np.float32)
        named = dict(zip(PairEvidence._fields, tables))
        for m, (pair_ids, evidence) in enumerate(self._pairs):
            rows = np.searchsorted(ids, pair_ids)
            for table, values in zip(tables, evidence):
                if values is not None:
                    table[rows, m] = values
        if long is not None:
            long_ids, evidence = long
            known = np.isin(long_ids, ids)
            rows = np.searchsorted(ids, long_ids[known])
            for name in ("ground", "footing", "shortfall"):
                values = getattr(evidence, name)
                if values is not None:
                    named[name][rows, -1] = values[known]
        short = short_of_ground(named["shortfall"])
        measurable = self._measurable(ids, observation, short)
        by_depth = depth_moving(ids.size, self.config.track_motion, *tables[1:], measurable=measurable)
        flagged = ids[moving_tracks(tables[0], self.config.track_motion, dense=self._dense_near(ids, observation),
                                    depth=by_depth)]
        flagged = np.union1d(flagged, self._count_flags(flagged, observation.alive, observation.index))
        depth = ids[by_depth]
        self._depth_ids = np.union1d(np.intersect1d(self._depth_ids, flagged), np.intersect1d(depth, flagged))
        return flagged, self._depth_ids

    def _catch_up(self, observation: Observation) -> None:
        """Fit the track pairs of up to ``catch_up_pairs`` frames, the newest first, of those since the last refit
        that are still in ``observation``'s window: a background refit slower than the camera takes only the
        newest frame, and the window's track test would otherwise see only every second or third pair, and lose
        moving tracks (docs/experiments.md). Nothing to do when every frame is refitted."""
        gap, first = self.config.track_motion.gap, observation.first
        missed = range(max(self._fitted_through + 1, first + gap), observation.index)
        for index in missed[max(len(missed) - self.config.catch_up_pairs, 0):]:
            now = observation.window[index - first]
            fitted = self._fit_pair(*observation.window[index - first - gap], *now, observation)
            if fitted is not None:
                self._pairs.append(fitted)
        self._fitted_through = observation.index

    def _dense_near(self, ids: np.ndarray, observation: Observation) -> np.ndarray | None:
        """(len(ids),) the last dense residual (``_counted``, of an earlier frame than ``observation``'s) near each
        track of sorted ``ids`` where it was in that frame, in the units of the track test's distances (tracking
        pixels over ``gap`` frames; infinite where it reaches ``corroboration_floor`` of the dense threshold);
        NaN for tracks not seen then, None without dense evidence from a frame of the window or with the
        corroboration off. A frame earlier than the one tested: KLT's drift at a near edge stays where the edge
        is, and a track young enough to be born since has no pair yet (docs/experiments.md)."""
        first = observation.first
        if (self.config.track_motion.corroboration <= 0 or self._evidence is None or observation.pair is None
                or not first <= self._evidence[0] < observation.index):
            return None
        index, evidence = self._evidence
        if not np.isfinite(evidence.threshold):
            return None
        then_ids, then = observation.window[index - first]
        _, rows, columns = np.intersect1d(ids, then_ids, assume_unique=True, return_indices=True)
        scale = evidence.residual.shape[1] / observation.tracking_shape[1]
        near = dense_near(then[columns] * scale, evidence.residual, self.config.corroboration_reach)
        values = np.full(ids.size, np.nan, dtype=np.float32)
        values[rows] = np.where(near >= self.config.corroboration_floor * evidence.threshold, np.inf,
                                near / scale * self.config.track_motion.gap / self.config.dense_gap)
        return values

    def _measurable(self, ids: np.ndarray, observation: Observation, among: np.ndarray) -> np.ndarray | None:
        """(len(ids),) bool: of the tracks of sorted ``ids`` that are ``among`` (bool) the ones asked about, those
        seen now whose image can show their parallax (``aperture_share`` at least ``aperture_share``); None with
        the check off or before a pair."""
        if self.config.aperture_share <= 0 or observation.pair is None:
            return None
        _, _, now_ids, now = observation.pair
        _, rows, columns = np.intersect1d(ids[among], now_ids, assume_unique=True, return_indices=True)
        rows = np.flatnonzero(among)[rows]
        scale = observation.gray.shape[1] / observation.tracking_shape[1]
        centre = observation.camera_matrix[:2, 2] * scale
        measurable = np.zeros(ids.size, dtype=bool)
        measurable[rows] = aperture_share(observation.gray, now[columns] * scale, centre,
                                          self.config.aperture_window) >= self.config.aperture_share
        return measurable

    def _count_flags(self, flagged: np.ndarray, alive: np.ndarray, index: int) -> np.ndarray:
        """Count the windows since the last refit (one when every frame is refitted, and at the first) for each
        living flagged track (flagged at frame ``index``); returns the ids flagged in enough windows whose last flag
        is at most ``sticky_frames`` old."""
        keep = np.isin(self._flag_ids, alive)
        fresh = np.setdiff1d(flagged[np.isin(flagged, alive)], self._flag_ids)
        ids = np.concatenate([self._flag_ids[keep], fresh])
        counts = np.concatenate([self._flag_counts[keep], np.zeros(fresh.size, dtype=np.int64)])
        last = np.concatenate([self._flag_last[keep], np.full(fresh.size, index, dtype=np.int64)])
        order = np.argsort(ids)
        ids, counts, last = ids[order], counts[order], last[order]
        now = np.isin(ids, flagged)
        # Every frame's refit would have seen the skipped frames' windows, each mostly the same frames as this one's.
        windows = 1 if self._counted_through is None else min(max(index - self._counted_through, 1),
                                                                self.config.sticky_windows)
        counts[now] += windows
        self._counted_through = index
        last[now] = index
        self._flag_ids, self._flag_counts, self._flag_last = ids, counts, last
        return ids[(counts >= self.config.sticky_windows) & (index - last <= self.config.sticky_frames)]

    def _fit_pair(self, ids1: np.ndarray, x1: np.ndarray, ids2: np.ndarray, x2: np.ndarray, observation: Observation,
                  frames: int | None = None) -> tuple[np.ndarray, PairEvidence] | None:
        """(ids, evidence) of the tracks seen in both frames of a pair ``frames`` apart (default: ``gap``; a
        longer pair skips the planar check, see ``_flagged``) of ``observation``'s window, at its tracking size,
        guarded against a misjudged rotation whatever its K is (core/track_motion.py: in KITTI 07's corner
        camera_info's K let a house pass for a mover)."""
        config = self.config.track_motion.for_width(observation.tracking_shape[1])
        K = observation.camera_matrix
        if frames is not None:
            config = replace(config, max_rotation_deg=self._rotation_limit(frames))
        both, i1, i2 = np.intersect1d(ids1, ids2, assume_unique=True, return_indices=True)
        evidence = pair_evidence(x1[i1], x2[i2], config, K, guarded=True, planar_check=frames is None)
        return None if evidence is None else (both, evidence)

    def _rotation_limit(self, frames: int) -> float:
        """Degrees a pair ``frames`` apart may turn before it is ``turned``: ``max_rotation_deg`` holds for the
        track pairs (``gap`` frames), so the limit per frame is the same for every pair."""
        return self.config.track_motion.max_rotation_deg / self.config.track_motion.gap * frames

    def _reliable(self, gray: np.ndarray, flow: np.ndarray) -> np.ndarray:
        """(h, w) bool: pixels whose dense flow the residual test may trust: textured ones (the smaller
        structure-tensor eigenvalue above ``min_texture``), and smooth ones within ``texture_reach`` of texture
        whose ``flow`` (h, w, 2) is at most ``smooth_max_flow`` long."""
        textured = (cv2.cornerMinEigenVal(gray, 5, 3) > self.config.min_texture).astype(np.uint8)
        if self.config.texture_reach <= 0:
            return textured > 0
        side = 2 * self.config.texture_reach + 1
        near = cv2.dilate(textured, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))) > 0
        slow = np.hypot(flow[..., 0], flow[..., 1]) <= self.config.smooth_max_flow
        return (textured > 0) | (near & slow)

    def _counted(self, evidence: EpipolarResidual, flow: np.ndarray) -> EpipolarResidual:
        """``evidence`` whose residual counts only beyond ``dense_allowance`` of each pixel's ``flow`` (h, w, 2),
        for the dense mask and the tracks' corroboration alike; a homography's transfer error stays whole: it has
        no epipolar line to be off."""
        if evidence.homography is not None or self.config.dense_allowance <= 0:
            return evidence
        return replace(evidence, residual=beyond_allowance(evidence.residual, flow, self.config.dense_allowance))

    def _dense_mask(self, observation: Observation, evidence: EpipolarResidual) -> tuple[np.ndarray, np.ndarray]:
        """(h, w) bool the dense mask of ``evidence`` (the module's docstring), and its part the depth tests flagged
        (``_against_parallax``)."""
        backward, _ = observation.flows
        gray = observation.gray
        depth = np.zeros(gray.shape, dtype=bool)
        if evidence.fundamental is None and evidence.homography is None:
            return depth, depth
        moving = (evidence.residual > evidence.threshold) & evidence.valid
        reliable = self._reliable(gray, backward) if self.config.min_texture > 0 else None
        if reliable is not None:
            moving &= reliable
        if evidence.homography is None and (self.config.dense_cheir_px > 0 or self.config.dense_footing):
            K = scaled_to(observation.camera_matrix, observation.tracking_shape, gray.shape)
            limit = self._rotation_limit(self.config.dense_gap)
            parallax = dense_parallax(backward, evidence.valid, evidence.fundamental, K, self.config.track_motion,
                                      inlier_px=self.config.dense_baseline.ransac_threshold_px, max_rotation_deg=limit)
            if parallax is not None:
                depth = self._against_parallax(parallax, evidence.valid, reliable)
                moving |= depth
        return moving, depth

    def _against_parallax(self, parallax: DenseParallax, valid: np.ndarray,
                          reliable: np.ndarray | None = None) -> np.ndarray:
        """(h, w) bool: the pixels the dense parallax puts behind infinity (``dense_cheir_px``; in regions that
        reach ``reliable`` ones, ``_reliable``, None: all) or, of the reliable ones, nearer than the road under them
        (``dense_footing``)."""
        moving = np.zeros(valid.shape, dtype=bool)
        if self.config.dense_cheir_px > 0:
            # Not gated by texture: a followed object's body is often smooth, and its flow is ~0 there. But only
            # the regions that reach pixels whose flow is reliable: in the middle of a blank sky DIS's flow is
            # interpolated, and a patch of it came out behind infinity (docs/experiments.md).
            behind = behind_infinity(parallax, valid, self.config.track_motion,
                                     threshold_px=self.config.dense_cheir_px, guarded=True)
            moving |= behind if reliable is None else touching(behind, behind & reliable)
        near = (nearer_than_road(parallax, valid, self.config.track_motion, excess_px=self.config.dense_footing_px,
                                 clearance=self.config.dense_footing_clearance)
                if self.config.dense_footing else None)
        if near is None:
            return moving
        # Gated as the residual is: on KITTI 07 the smooth panes of near parked cars' windows came out nearer than
        # the road under them (docs/experiments.md); an oncoming car's smooth body keeps its pixels near texture
        # while its flow is small (``smooth_max_flow``).
        return moving | (near if reliable is None else near & reliable)
