"""The motion front-end's settings: its stages' parameters (``ObserveSettings``, ``RegionSettings``: the method's
settings) and its constants (``MotionFrontEndConfig``, which holds both); pixels at the dense width unless a share."""

from __future__ import annotations

from dataclasses import dataclass, field

from moseg_ros.core.baseline import BaselineConfig
from moseg_ros.core.object_flow import ObjectFlowConfig
from moseg_ros.core.track_tests.settings import TrackMotionConfig
from moseg_ros.frontend.tracks import TrackerConfig
from moseg_ros.params import setting


@dataclass(frozen=True)
class ObserveSettings:
    """The observe stage's settings: how many frames the window holds, how finely and densely the frame is
    tracked."""

    window_length: int = setting(8, "frames in the sliding window", low=3, high=60)
    track_width: int = setting(1280, "KLT tracks run at this width (pixels)", low=64, high=4096)
    max_tracks: int = setting(2000, "points tracked per frame", low=50, high=20000)


@dataclass(frozen=True)
class RegionSettings:
    """The regions stage's settings."""

    min_region_area: int = setting(60, "smallest moving region kept (working pixels)", low=1, high=100000)


@dataclass(frozen=True)
class MotionFrontEndConfig(RegionSettings, ObserveSettings):
    """Settings of the motion front-end: its stages' parameters and its constants (pixels at the working
    resolution unless a fraction of the width). ``tracks.max_points`` is ``max_tracks``'s."""

    # KLT's window at the tracking width (1280 px): a smaller window drifts less where it straddles a mover's
    # edge (fewer static points flagged) and follows smaller movers, and each point costs less; a dense flow at half
    # resolution guesses each point closely enough for it, where a quarter-resolution flow leaves the tracks more to
    # reach (docs/experiments.md, ``tracks``). Corners are found at the dense width, with a quality floor low enough
    # that as many are found there as at full size.
    tracks: TrackerConfig = field(default_factory=lambda: TrackerConfig(max_points=2000, window=13, quality=0.001,
                                                                        seed_width=640))
    track_motion: TrackMotionConfig = field(default_factory=TrackMotionConfig)
    sticky_windows: int = 2
    sticky_frames: int = 8
    link_fraction: float = 0.032
    # Three linked flagged tracks make a region: a small far pedestrian holds only a few tracks
    # (docs/experiments.md, ``min_group``).
    min_group: int = 3
    # A moving object carries its tracks along, so tracks that lived through the whole window unflagged are
    # static evidence: a hull where they outnumber the flagged tracks is scattered noise (water, a crowd,
    # drifting tracks in foliage), not an object. Young tracks do not count: a moving car keeps gaining new
    # ones that the test has not flagged yet.
    hull_purity: float = 0.5
    # A group of four or more fills only the triangles of its tracks' Delaunay triangulation whose sides are at most
    # this many times the link distance, not its convex hull, which bridges the bays between its tracks: the gap
    # between a vehicle and the few tracks flagged in a tree beside it, the water around a swimming animal. Less
    # reach loses frames of a car that a high-rate camera follows, whose few flagged tracks lie far apart
    # (docs/experiments.md, ``hull_reach``). 0: the convex hull.
    hull_reach: float = 2.0
    dense: bool = True
    dense_gap: int = 1
    dense_width: int = 640
    # The dense frame holds at most this many pixels too (0: any; the pipeline's ``working_pixels``), so that a
    # tall (4:3) frame costs about what a wide street camera's does.
    dense_pixels: int = 0
    # Matches landing within 5 % of the width (32 px at 640) of the earlier frame's border are not trusted: DIS
    # extrapolates there, and in a turn the band entering the view came out moving (docs/experiments.md).
    dense_baseline: BaselineConfig = field(default_factory=lambda: BaselineConfig(
        residual_threshold_px=1.0, residual_noise_factor=5.0, border_fraction=0.05))
    # The dense residual counts only beyond this share of each pixel's flow, as the track test's distance does
    # beyond ``TrackMotionConfig.epipole_allowance`` of its displacement: the frame pair's F is off by a small angle,
    # and near static surfaces that flow fast (a parked car or a wall at the image's side) came out moving; the
    # allowance clears most of them for little recall (docs/experiments.md, ``dense_allowance``). The residual that
    # corroborates a track (``corroboration_reach``) counts the same way. 0: off.
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
    # moves only a few pixels a frame at the dense width, and the track test's 1 px (at full size over two frames)
    # stops it; 0.25 is about that 1 px in these units. With the footing's allowance near the horizon at the road's
    # tolerance, such a car's excess is a fraction of a pixel, and a floor that low adds no false positives on a
    # static street (docs/experiments.md, ``dense_footing``).
    dense_footing_px: float = 0.2
    # A pixel's footing counts only where its column holds road more than this share of the dense flow's height
    # below it: the road's tolerance lets a near parked car's own bumper pass for road where the image's lower edge
    # (and the border DIS is not trusted at) hides the road under it, and its number plate came out nearer than
    # that. More clearance loses movers near the image's lower edge (docs/experiments.md,
    # ``dense_footing_clearance``). 0: any road under it.
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
    # and pyramid are clipped and what enters or leaves the view has half its support (in a turn, false hulls
    # gather there; docs/experiments.md, ``track_border``).
    track_border: float = 0.03
    # The flow view around each hull (core/object_flow.py): grows smooth bodies, trims swallowed background.
    # None: hulls as drawn.
    object_flow: ObjectFlowConfig | None = field(default_factory=ObjectFlowConfig)
    # Frames the moving evidence is remembered after it drops out (``remembered``). One bridges a lost frame;
    # each more frame catches more looming and crossing cars and carries more false regions on static streets
    # (docs/experiments.md, ``memory_frames``). 0: off.
    memory_frames: int = 1
    memory_veto: int = 3
    # A region published ``coast_after`` frames in a row whose evidence, moved by the similarity of the tracks on
    # it (``coast_tracks`` or more, of any age; with fewer, by their last similarity and along the dense flow), is
    # less than ``coast_cover`` evidence now is drawn there for up to ``coast_frames`` frames in a row (``coasted``):
    # a looming or small fast car's evidence drops out for a few frames. More frames and a higher cover catch more
    # of such cars for few static pixels (docs/experiments.md, ``coast_frames``). 0: off.
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
    # as much as the refit's own pair fit, which the polished fits keep cheap (docs/experiments.md,
    # ``catch_up_pairs``). 8: every skipped frame's of a window of eight.
    catch_up_pairs: int = 8
