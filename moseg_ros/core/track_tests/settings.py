"""The track tests' settings (``TrackMotionConfig``): pixels at ``REFERENCE_WIDTH``, scaled to a tracking width."""

from __future__ import annotations

from dataclasses import dataclass, replace




# The tracking width that the width-relative pixel settings are given at (``TrackMotionConfig.for_width``): KITTI's.
REFERENCE_WIDTH = 1242


@dataclass(frozen=True)
class TrackMotionConfig:
    """Settings of the per-track epipolar test (pixels at the tracking resolution; ``shortfall_strong_px`` at
    ``REFERENCE_WIDTH``, see ``for_width``)."""

    gap: int = 2
    # The homographies' RANSAC threshold; F's inliers are the tracks within ``inlier_px`` of its epipolar lines
    # (Sampson distance) under a plain RANSAC F refitted by least squares on them (core.robust.fundamental_polished),
    # as good as MAGSAC++ and much cheaper. KLT's error over ``gap`` frames needs the wider band: at 1 px F's
    # inliers left out tracks it fits and more static points were flagged (docs/experiments.md).
    ransac_px: float = 1.0
    inlier_px: float = 2.0
    factor: float = 3.0
    floor_px: float = 1.0
    # With the dense residual near each track (``moving_tracks``' ``dense``), a distance flags a track only where
    # the dense flow departs from the epipolar geometry by at least this share of it too: KLT drifts where its
    # window straddles a near object's edge (a tree trunk against the far street) and the dense flow there does
    # not (docs/experiments.md, ``corroboration``). 0: off. A distance ``evident_factor`` times the threshold needs no
    # corroboration (KLT's drift stays within a few times it; a mover's distance often goes far beyond).
    corroboration: float = 0.75
    evident_factor: float = 3.0
    min_tracks: int = 20
    min_parallax_px: float = 0.5
    cheir_px: float = 2.0
    cheir_consensus: float = 0.8
    cheir_decided_px: float = 1.0
    cheir_min_votes: int = 20
    max_rotation_deg: float = 2.0
    behind_share: float = 0.25
    homography_preference: float = 0.9
    gric_min_sigma_px: float = 0.1
    # The full homography fit (MAGSAC++, the costliest fit of a refit on a street) runs only where a quick one
    # (plain RANSAC, ``screen_iterations``, on every ``screen_stride``-th track) explains at least this share
    # of F's inliers: a street's dominant plane holds well under half of them, and a pair that is planar screens
    # far above half (docs/experiments.md, ``homography_screen``).
    homography_screen: float = 0.5
    screen_stride: int = 4
    screen_iterations: int = 50
    ground_ratio: float = 0.3
    # The ratio alone is decided only where the floor's parallax is at least this many times the pair's noise (the
    # robust sigma of F's inliers' distances), so that its bar lies five sigmas under the floor: near the horizon
    # the floor is a pixel or two, and there the far end of a street in a noisy pair came out farther than the road,
    # while a car followed ahead under the same floor in a pair of low noise is decided (docs/experiments.md,
    # ``ground_ratio_noise``). The shortfall test, in pixels, decides the rest.
    ground_ratio_noise: float = 7.0
    # The ground test in pixels (the module's docstring; docs/experiments.md): the parallax short of the floor's by
    # this many pixels and below this share of it.
    shortfall_px: float = 1.0
    shortfall_ratio: float = 0.6
    # A track short by this many pixels needs only this share of the floor: the 0.6 guards against a floor read
    # at the wrong row (the road in front of an object taken for its foot), an error of a share that shrinks as
    # the parallax grows (a row more or less matters less below the horizon than near it), while a pedestrian
    # walking away keeps most of the road's parallax. 0: off. Pixels at ``REFERENCE_WIDTH``, in proportion at
    # other tracking widths (``for_width``): the walker's shortfall is a share of its parallax, which shrinks with
    # the image, and at half that width the 4 px it falls short by there are 2 (docs/experiments.md,
    # ``shortfall_strong_px``).
    shortfall_strong_px: float = 4.0
    shortfall_strong_ratio: float = 0.9
    # The shortfall is measured at the row the track's object stands on: the lowest track of its column at its own
    # inverse depth within this share (a looser bound lets the road in front of a static object pass for it).
    shortfall_same_depth: float = 0.1
    ground_min_px: float = 1.0
    ground_bands: int = 12
    ground_band_tracks: int = 10
    ground_quantile: float = 10.0
    ground_min_forward: float = 0.8
    # The footing's margin is the road's tolerance (``nearer_than_road``: a static object's lower part passes for
    # road within it) and a share for what overhangs the road seen under it (a parked car's bumper over the road
    # beneath its body, which lies that much farther): ``footing_overhang`` camera heights, a share of the
    # footing's inverse depth of the overhang over the footing's depth, which over a level road is the overhang
    # over the camera's height times the tangent of the footing's angle below the horizon. 1: a car's 0.8-1 m
    # over a dashcam's 1.65 m with room to spare; a flat margin instead leaves a far oncoming car's first frames
    # unflagged or flags near parked cars' bumpers (docs/experiments.md, ``footing_margin``).
    footing_margin: float = 0.3
    footing_overhang: float = 1.0
    footing_px: float = 1.0
    footing_band: float = 0.01
    footing_support: int = 3
    footing_road_tol: float = 0.3
    footing_same_depth: float = 0.25
    # A track's footing is decided only where its column holds a footing candidate more than this share of the
    # tracks' vertical extent below its object's lowest track: a near parked van cut by the image's lower edge
    # stands out of view, and the column's tracks beside its edge (the kerb behind it) are no footing; such an edge
    # spans a few hundredths of the extent (docs/experiments.md, ``footing_clearance``).
    footing_clearance: float = 0.08
    # A fitted F's epipolar lines are off by a small angle, so a static track's distance from its line grows
    # with how far it moved: its distance counts only beyond this share of its displacement (radians of line
    # direction; 0.03 is 1.7 degrees). Tracks on near static surfaces (parked cars' windows, glints) move far over
    # a pair and, flagged, lie just under this share of it from their lines; flagged movers move less and lie at
    # several times that share (docs/experiments.md, ``epipole_allowance``).
    epipole_allowance: float = 0.03

    def for_width(self, width: int) -> TrackMotionConfig:
        """These settings for tracks at ``width`` pixels: ``shortfall_strong_px`` in proportion to
        ``REFERENCE_WIDTH``, every other one as it is."""
        return replace(self, shortfall_strong_px=self.shortfall_strong_px * width / REFERENCE_WIDTH)
