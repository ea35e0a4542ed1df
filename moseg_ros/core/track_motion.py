"""Which point trajectories move by themselves: a robust epipolar test per track over a window.

The camera's own motion is the dominant rigid motion of the tracked points, so for every frame pair (m, m+g)
of the window a RANSAC fundamental matrix is fitted to the tracks seen in both frames, and every track gets
its Sampson distance (Hartley & Zisserman eq. 11.9, in pixels) under it. A track moves when the median of its
distances over the pairs it spans exceeds ``max(factor x the median over all tracks, floor)``: the median
over pairs forgives one bad pair (a KLT slip), the median over tracks scales the threshold with the window's
noise. When one homography explains about as many tracks as F does (a camera that only rotates, or a scene
that is mostly one plane), F is not determined by the data and a wrong member of its family can swallow a
mover; the distance is then the homography's transfer error (the model-selection idea of Torr's GRIC, as in
core/baseline.py). This residual test is blind to motion inside the epipolar plane.

Part of that blind spot is closed by cheirality (Hartley & Zisserman 9.6.3). With the camera's K, or a
guessed one (focal 0.9 x width, principal point at the centre; only a sign is used, so the guess barely
matters: 0.58, 0.9 and 1.2 x width gave the same on KITTI), E = K^T F K gives R and t, and the infinite homography
K R K^-1 maps x1 to where a point at infinite depth would land. A static point's image moves away from there
as its inverse depth grows, so its signed parallax is positive; a car pulling away ahead gets a negative one.
The sign of t is voted by F's inliers with |parallax| > ``cheir_decided_px``; a pair counts only with
``cheir_consensus`` agreement, which drops pure rotations and pairs dominated by a mover; 0.8 rather than
0.9, because a camera that pans after an object keeps it still in the image, and such a mover votes
"behind infinity" with every track it holds (DAVIS car-roundabout: at 0.9 not one pair was signed). A track
moves when its median signed parallax is below -``cheir_px``. The rotation recovered from F is misjudged by a
share of the image motion it gives, most in a turn and most with a guessed K: static foliage came out 'behind
infinity' (KITTI odometry 07, 3-4.5 degrees per pair, K guessed), and with camera_info's K a house in the corner
of frames 26-35, a shop's awning and a hedge top against a tree (docs/experiments.md). With ``guarded`` (the
front-end's choice for every K) a track is then behind infinity only by at least ``behind_share`` of the
rotation's image motion at it (one less far behind counts as at infinity), and in pairs turning more than
``max_rotation_deg`` nothing else is signed and the ground and footing tests are off. An object the panning
camera follows (DAVIS libby: 2 degrees a frame) stays still in the image, behind infinity by all of it. An
oncoming car projects exactly like a nearer static point in every pair and stays invisible to both tests.

A car followed at the camera's own speed, or one pulling away slowly, has parallax near zero: in front of
infinity, but farther than the ground it stands on. Below the horizon no static point can be farther than
the ground along its ray (the road is the farthest surface there), and a plane's inverse depth is an affine
function of the pixel, so for a camera that moves forward over a level ground the road's inverse depth grows
linearly with the row below the epipole. ``ground_parallax_ratio`` fits that floor to the lowest inverse
depths of the tracks, band by band below the epipole (a low quantile: the road, not the objects on it), and
gives each track its parallax over the parallax the floor would have there; a track moves when its median
ratio is below ``ground_ratio``. Pixels where the floor's parallax is below ``ground_min_px`` (near the
horizon) are not decided, and the ratio test alone takes only those where it reaches ``ground_ratio_noise``
times the pair's noise. A track also moves when, in most pairs, its parallax falls short of the floor's by
more than ``shortfall_px`` and below ``shortfall_ratio`` of it (the mirror of the footing test below: a margin
and pixels rather than the ratio alone, whose low bar is set by the noise near the horizon), the floor taken at
the row its object stands on (``standing_rows``: its column's lowest track at its own inverse depth) rather
than at its own: a pedestrian crossing ahead walks nearly along the epipolar lines, towards the focus of
expansion, and looks farther than the road under its feet from every one of its tracks, while the road at the
rows of its upper tracks lies farther still. A shortfall of ``shortfall_strong_px`` or more needs only to be below
``shortfall_strong_ratio`` of the floor: the 0.6 guards against a floor read at the wrong row, an error of a share
that shrinks as the parallax grows, and a pedestrian walking away along the road keeps 0.7-0.9 of the road's
parallax. That test asks the track to measure its parallax at all
(``moving_tracks``' ``measurable``): on an edge that runs along the parallax (a kerb near the horizon) KLT cannot
see motion along the edge, and its parallax comes out short (the aperture problem; ``aperture_share``).
Whatever rides with the camera below the horizon (a vehicle's own bonnet in a dashcam's view) has no parallax
and is flagged like a followed car: crop it away upstream.

An oncoming car is the opposite case: it closes in faster than the camera drives, so it projects like a static
point nearer than it is, and nearer than the ground it stands on. Below the horizon a static surface is never
nearer than what is visible under it in the same column (the road under an upright object is nearer towards the
camera, and the object's own lower part is as near), so ``footing_excess`` compares each track's inverse depth with
a low order statistic (``footing_support``) of the inverse depths of the tracks below it in its column band
(``footing_band`` of the tracks' horizontal extent): a track moves when its parallax exceeds what that footing
would give it, times ``footing_allowance`` (a margin that grows as the footing nears the camera, for what overhangs
it), by more than ``footing_px`` (median over the pairs). Tracks the ground test flags (followed cars) are no
footing; an order statistic rather than the minimum, because KLT tracks right under a moving object's lower edge
often follow the object. Where the road under an object holds few tracks, that statistic comes from road far nearer
the camera, and an oncoming car slower than the camera passes under it. The road itself gives a second, tighter
footing: the object stands at or above the first road track below it (a track within ``footing_road_tol`` of the
ground's parallax), and no higher than its own lowest track (the lowest one under it at its inverse depth, within
``footing_same_depth``: beside a thin pole's trunk the road behind the pole is visible, and it is no footing), so
the fitted ground's inverse depth at the lower of those rows bounds it. A road track is never the object's own: an
oncoming car seems as near as the road some way in front of it, and that road, seen under the car's columns, would
otherwise pass for the car's lowest part. And the footing is decided only where the column holds a candidate more
than ``footing_clearance`` of the tracks' vertical extent below the object's lowest track: where nothing lies
clearly under the object (a near parked van cut by the image's lower edge), what the column holds lies beside its
edge (the kerb behind it), not under it.

The dense flow gives the footing test what the tracks lack while an oncoming car is far: ``nearer_than_road``
runs it on every pixel of a flow's ``dense_parallax`` (the cheirality vote ``behind_infinity`` reads too), with the
road's inverse depth fitted to the flow's own pixels and the first road pixel under each pixel in its column as
its footing. DIS smears the car's flow a few rows onto the road under it (docs/experiments.md), so the footing
comes out a little nearer than the car's foot; it still lies far closer to the foot than the first road track.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np

from moseg_ros.core.flow_field import pixel_grid
from moseg_ros.core.geometry import homography_preferred, homography_transfer_error, sampson_distance
from moseg_ros.core.robust import fundamental_polished, homography_ransac


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
    # not (docs/experiments.md). 0: off. A distance ``evident_factor`` times the threshold needs no corroboration (KLT's
    # drift stays within 1-3 times it; a mover's distance often goes far beyond).
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
    # of F's inliers: a street's dominant plane holds a third of them, and no pair that came out planar on
    # KITTI or DAVIS screened below three quarters (docs/experiments.md).
    homography_screen: float = 0.5
    screen_stride: int = 4
    screen_iterations: int = 50
    ground_ratio: float = 0.3
    # The ratio alone is decided only where the floor's parallax is at least this many times the pair's noise (the
    # robust sigma of F's inliers' distances), so that its bar lies five sigmas under the floor: near the horizon
    # the floor is a pixel or two, and there the far end of a synthetic street (sigma 0.55 px over the window's
    # long pair at 621 px) came out farther than the road, while a car followed 30 m ahead under the same floor
    # with sigma 0.14 px is decided (docs/experiments.md). The shortfall test, in pixels, decides the rest.
    ground_ratio_noise: float = 7.0
    # The ground test in pixels (the module's docstring; docs/experiments.md): the parallax short of the floor's by
    # this many pixels and below this share of it.
    shortfall_px: float = 1.0
    shortfall_ratio: float = 0.6
    # A track short by this many pixels needs only this share of the floor: the 0.6 guards against a floor read
    # at the wrong row (the road in front of an object taken for its foot), an error of a share that shrinks as
    # the parallax grows (a row more or less matters less below the horizon than near it), while a pedestrian
    # walking away keeps 0.7-0.9 of the road's parallax. 0: off. Pixels at ``REFERENCE_WIDTH``, in proportion at
    # other tracking widths (``for_width``): the walker's shortfall is a share of its parallax, which shrinks with
    # the image, and at 621 px the 4 px it falls short by at KITTI's size are 2 (docs/experiments.md).
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
    # over a dashcam's 1.65 m with room to spare; a flat 0.4 instead left a far oncoming car's first frames
    # unflagged and flagged near parked cars' bumpers on KITTI 07 (docs/experiments.md).
    footing_margin: float = 0.3
    footing_overhang: float = 1.0
    footing_px: float = 1.0
    footing_band: float = 0.01
    footing_support: int = 3
    footing_road_tol: float = 0.3
    footing_same_depth: float = 0.25
    # A track's footing is decided only where its column holds a footing candidate more than this share of the
    # tracks' vertical extent below its object's lowest track: a near parked van cut by the image's lower edge
    # stands out of view, and the column's tracks beside its edge (the kerb behind it) are no footing. On KITTI 07
    # the van's edge was 1.8-3.7 % of frames 46-49; 0.08 is 30 rows at 375 (docs/experiments.md).
    footing_clearance: float = 0.08
    # A fitted F's epipolar lines are off by a small angle, so a static track's distance from its line grows
    # with how far it moved: its distance counts only beyond this share of its displacement (radians of line
    # direction; 0.03 is 1.7 degrees). On KITTI 07 the tracks flagged on near parked cars' windows and glints
    # moved 52 px over a pair at the median (the flagged movers of KT3DMoSeg 17 px), their distance 0.027 of
    # it (the movers' 0.16; docs/experiments.md).
    epipole_allowance: float = 0.03

    def for_width(self, width: int) -> TrackMotionConfig:
        """These settings for tracks at ``width`` pixels: ``shortfall_strong_px`` in proportion to
        ``REFERENCE_WIDTH``, every other one as it is."""
        return replace(self, shortfall_strong_px=self.shortfall_strong_px * width / REFERENCE_WIDTH)


def guessed_camera_matrix(image_size: tuple[int, int], focal_fraction: float = 0.9) -> np.ndarray:
    """(3, 3) K of an uncalibrated camera: focal ``focal_fraction`` x width, principal point at the centre."""
    h, w = image_size
    f = focal_fraction * w
    return np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])


def rotation_degrees(R: np.ndarray) -> float:
    """The angle of a (3, 3) rotation matrix, in degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


@dataclass(frozen=True)
class Parallax:
    """Translational parallax of one frame pair's tracks against the plane at infinity.

    Attributes:
        signed: (N,) float32 pixels along the direction a static point moves as its inverse depth grows
            (positive = in front of infinity).
        gain: (N,) float32 pixels of parallax per unit of inverse depth at each track (the baseline is of
            unit length, so inverse depths compare within the pair only).
        epipole_row: the row of the epipole in the pair's earlier image (where the translation points), or
            None when the camera does not move forward (``ground_min_forward`` of its unit translation along
            the optical axis).
        rotation: (3, 3) K R K^-1, the infinite homography.
        translation: (3,) K t, oriented by the vote (``oriented_parallax`` of it is positive for static points).
        focal: K's vertical focal length in pixels: a row's offset from the epipole row over it is the tangent of
            its angle below the horizon (``footing_allowance``).
        turned: the pair turned more than its limit: ``epipole_row`` is None (no ground or footing test),
            and the cheirality test takes only the points ``far_behind`` infinity (``guarded_signs``).
    """

    signed: np.ndarray
    gain: np.ndarray
    epipole_row: float | None
    rotation: np.ndarray
    translation: np.ndarray
    focal: float
    turned: bool = False


def oriented_parallax(x1: np.ndarray, x2: np.ndarray, rotation: np.ndarray,
                      translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parallax of N correspondences along the direction a point moves as its inverse depth rho grows.

    x2(rho) = (a_xy + rho b_xy) / (a_z + rho b_z) with a = rotation @ (x1, 1) and b = translation.

    Args:
        x1, x2: (N, 2) correspondences (float32 or float64; the result follows them).
        rotation: (3, 3) the infinite homography K R K^-1.
        translation: (3,) K t.

    Returns:
        signed (N,) pixels (positive = in front of infinity for the translation's orientation) and gain
        (N,) pixels per unit of inverse depth.
    """
    dtype = np.result_type(x1, np.float32)
    H, b = rotation.astype(dtype), translation.astype(dtype)
    x, y = x1[:, 0], x1[:, 1]
    a = [H[i, 0] * x + H[i, 1] * y + H[i, 2] for i in range(3)]  # rotated rays, pixels x depth
    # A ray turned behind the camera (a_z ~ 0) only comes from a wrong decomposition; keep it finite.
    a[2] = np.where(np.abs(a[2]) < 1e-9, np.copysign(1e-9, a[2]), a[2])
    direction_x, direction_y = b[0] * a[2] - b[2] * a[0], b[1] * a[2] - b[2] * a[1]
    norm = np.sqrt(direction_x ** 2 + direction_y ** 2)
    gain = norm / a[2] ** 2  # |d x2 / d rho| at rho = 0
    signed = ((x2[:, 0] - a[0] / a[2]) * direction_x + (x2[:, 1] - a[1] / a[2]) * direction_y) / (norm + 1e-12)
    return signed, gain


def signed_parallax(x1: np.ndarray, x2: np.ndarray, fundamental: np.ndarray, inliers: np.ndarray,
                    K: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                    max_rotation_deg: float = np.inf) -> Parallax | None:
    """Signed parallax in pixels from the infinite homography (positive = positive depth), and its gain.

    Args:
        x1, x2: (N, 2) float64 correspondences, x2^T F x1 = 0.
        fundamental: (3, 3) F.
        inliers: (N,) bool RANSAC inliers of F (they vote on the sign).
        K: (3, 3) camera matrix (from camera_info, or ``guessed_camera_matrix``).
        config: the cheirality settings.
        max_rotation_deg: a pair that turns more is ``turned`` (the infinite homography's error grows with the
            rotation: see ``guarded_signs``), and gives None when ``config.behind_share`` is infinite.

    Returns:
        None when the pair does not decide the sign (too few votes, no consensus, or too much rotation with
        an infinite ``behind_share``). The translation's sign is the one the votes choose, for ``signed``
        and ``epipole_row`` alike.
    """
    R1, R2, t = cv2.decomposeEssentialMat(K.T @ fundamental @ K)
    # Of the two rotations the true one is the small one (the other is turned 180 degrees about the baseline).
    R = R1 if np.trace(R1) >= np.trace(R2) else R2
    turned = rotation_degrees(R) > max_rotation_deg
    if turned and not np.isfinite(config.behind_share):
        return None
    rotation, b = K @ R @ np.linalg.inv(K), (K @ t).ravel()
    signed, gain = oriented_parallax(x1, x2, rotation, b)
    votes = signed[inliers & (np.abs(signed) > config.cheir_decided_px)]
    if len(votes) < config.cheir_min_votes:
        return None
    positive = float(np.mean(votes > 0))
    if max(positive, 1.0 - positive) < config.cheir_consensus:
        return None
    sign = 1.0 if positive >= 0.5 else -1.0
    # X2 = R X1 + t: a camera driving forward moves the points towards it, so t points backwards.
    forward = -sign * float(t.ravel()[2])  # t is of unit length
    earlier = np.linalg.solve(rotation, b)  # K R^T t: the epipole in the earlier image, where x1 lies
    epipole_row = float(earlier[1] / earlier[2]) if forward >= config.ground_min_forward and not turned else None
    return Parallax((sign * signed).astype(np.float32), gain.astype(np.float32), epipole_row, rotation, sign * b,
                    float(K[1, 1]), turned)


def far_behind(x1: np.ndarray, signed: np.ndarray, rotation: np.ndarray, share: float) -> np.ndarray:
    """(N,) bool: points whose parallax lies behind infinity by at least ``share`` of the image motion the
    rotation alone gives them, |K R K^-1 x1 - x1|.

    The rotation recovered from F is off by a share of its own image motion (most with a guessed K, and in a
    turn with any), and static points come out behind infinity by about that much; an object the panning camera
    follows stays still in the image, so it lies behind infinity by all of it.

    Args:
        x1: (N, 2) points in the earlier image.
        signed: (N,) their signed parallax (``oriented_parallax``, oriented by the vote).
        rotation: (3, 3) the infinite homography K R K^-1.
        share: the least share of the rotation's motion.
    """
    rotated = x1 @ rotation[:, :2].T + rotation[:, 2]
    motion = np.hypot(rotated[:, 0] / rotated[:, 2] - x1[:, 0], rotated[:, 1] / rotated[:, 2] - x1[:, 1])
    return -signed >= share * motion


def guarded_signs(x1: np.ndarray, parallax: Parallax, share: float) -> np.ndarray:
    """(N,) the signed parallax the cheirality test takes from a guarded pair (``pair_evidence``): a point
    ``far_behind`` infinity (by ``share`` of the rotation's image motion) keeps its value; one less far behind
    counts as at infinity (0), and in a ``turned`` pair every other point is undecided (NaN). The ground and
    footing tests keep ``parallax.signed``: a followed car's small negative parallax is theirs."""
    far = far_behind(x1, parallax.signed, parallax.rotation, share)
    if parallax.turned:
        return np.where(far, parallax.signed, np.nan)
    return np.where((parallax.signed >= 0) | far, parallax.signed, 0.0)


class DenseParallax(NamedTuple):
    """The signed parallax of every pixel of a dense flow (``dense_parallax``).

    Attributes:
        vote: the sampled pixels' ``signed_parallax`` (its rotation and oriented translation hold for every pixel).
        signed: (H, W) float32 pixels, positive in front of infinity.
        gain: (H, W) float32 pixels of parallax per unit of inverse depth.
        epipole_row: the epipole's row in the flow's own frame when the camera moves along its axis (at least
            ``ground_min_forward`` of its translation, forward or back: the flow runs from the current frame to
            the previous one) and the pair is not ``turned``; else None.
    """

    vote: Parallax
    signed: np.ndarray
    gain: np.ndarray
    epipole_row: float | None


def dense_parallax(to_previous: np.ndarray, valid: np.ndarray, fundamental: np.ndarray, K: np.ndarray,
                   config: TrackMotionConfig = TrackMotionConfig(), *, step: int = 10, inlier_px: float = 0.5,
                   max_rotation_deg: float = np.inf) -> DenseParallax | None:
    """The cheirality of ``signed_parallax`` for every pixel of a dense flow: the translation's sign voted by every
    ``step``-th reliable pixel within ``inlier_px`` of its epipolar line, then each pixel's parallax against the
    plane at infinity. ``behind_infinity`` and ``nearer_than_road`` read it.

    Args:
        to_previous: (H, W, 2) flow from the current frame to the previous one.
        valid: (H, W) bool pixels whose flow is reliable (forward-backward).
        fundamental: (3, 3) F with x_prev^T F x_cur = 0 (core/baseline.epipolar_residual's).
        K: (3, 3) camera matrix at the flow's size.
        config: the sign's vote (``cheir_consensus`` and friends) and ``ground_min_forward``.
        step, inlier_px: which pixels vote.
        max_rotation_deg: as in ``signed_parallax``.

    Returns:
        None when the vote does not decide the translation's sign.
    """
    h, w = valid.shape
    grid = pixel_grid(h, w)
    landing = grid + to_previous
    sampled = valid[::step, ::step]
    here, there = grid[::step, ::step][sampled], landing[::step, ::step][sampled]
    if len(here) < config.cheir_min_votes:
        return None
    near_line = np.sqrt(sampson_distance(fundamental[None], here, there)[0]) < inlier_px
    vote = signed_parallax(here.astype(np.float64), there.astype(np.float64), fundamental, near_line, K, config,
                           max_rotation_deg)
    if vote is None:
        return None
    signed, gain = oriented_parallax(grid.reshape(-1, 2), landing.reshape(-1, 2), vote.rotation, vote.translation)
    t = np.linalg.solve(K, vote.translation)
    along = abs(t[2]) / max(float(np.linalg.norm(t)), 1e-12)
    epipole = np.linalg.solve(vote.rotation, vote.translation)  # in the current frame, where the grid lies
    epipole_row = float(epipole[1] / epipole[2]) if along >= config.ground_min_forward and not vote.turned else None
    return DenseParallax(vote, signed.reshape(h, w), gain.reshape(h, w), epipole_row)


def behind_infinity(parallax: DenseParallax, valid: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(), *,
                    threshold_px: float = 1.0, guarded: bool = False) -> np.ndarray:
    """(H, W) bool: reliable pixels whose signed parallax is below -``threshold_px`` (the cheirality test of
    ``signed_parallax`` for every pixel: the body of an object the camera follows, or of a car pulling away,
    where tracks are few).

    Args:
        parallax: the flow's ``dense_parallax``.
        valid: (H, W) bool pixels whose flow is reliable.
        config: ``behind_share``.
        threshold_px: parallax below minus this moves.
        guarded: the rotation may be misjudged (a guessed K, a turn): a pixel is behind infinity only by at
            least ``config.behind_share`` of the rotation's image motion there (``far_behind``).
    """
    h, w = valid.shape
    behind = (parallax.signed < -threshold_px).ravel()
    if guarded:  # tested where behind only: a few pixels of the frame
        where = np.flatnonzero(behind)
        behind[where] = far_behind(pixel_grid(h, w).reshape(-1, 2)[where].astype(np.float64),
                                   parallax.signed.ravel()[where], parallax.vote.rotation, config.behind_share)
    return behind.reshape(h, w) & valid


def nearer_than_road(parallax: DenseParallax, valid: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(), *,
                     excess_px: float | None = None, clearance: float = 0.0,
                     sample_step: int = 4) -> np.ndarray | None:
    """(H, W) bool: reliable pixels below the epipole that look nearer than the road where they stand, the footing
    test (``footing_excess``) for every pixel of a dense flow.

    The road's inverse depth is ``ground_slope`` fitted to every ``sample_step``-th reliable pixel. A pixel of the
    road is one within ``footing_road_tol`` of it; a pixel stands no lower than the first road pixel under it in
    its column, so the road's inverse depth there bounds a static pixel's own. A pixel moves when its parallax
    exceeds the parallax that bound gives it, times ``footing_allowance``, by more than ``excess_px``. An
    oncoming car closes in faster than the camera drives and looks nearer than the road it stands on; its
    tracks are few while it is far, and the first road track under it lies well below the road it stands on
    (docs/experiments.md), while the dense flow sees the road up to a few pixels under its bumper. The lower part
    of a static object is as near as its foot, so it passes for road within the tolerance, and a margin at least
    the tolerance keeps the object above it unflagged; the allowance's overhang share keeps a parked car's bumper
    over the farther road under its body.

    Args:
        parallax: the flow's ``dense_parallax``.
        valid: (H, W) bool pixels whose flow is reliable.
        config: the footing and ground settings.
        excess_px: the least excess in the flow's own pixels (default ``footing_px``, which is in the tracks').
        clearance: a footing counts only where its column holds road more than this share of the height below it.
        sample_step: the stride of the pixels the road's slope is fitted to.

    Returns:
        None without an epipole row (the camera does not move along its axis, or the pair turned) or a road.
    """
    if parallax.epipole_row is None:
        return None
    h, w = valid.shape
    sample = (slice(None, None, sample_step), slice(None, None, sample_step))
    keep = valid[sample]
    pixels = pixel_grid(h, w)[sample][keep].astype(np.float64)
    sampled = replace(parallax.vote, signed=parallax.signed[sample][keep], gain=parallax.gain[sample][keep],
                      epipole_row=parallax.epipole_row)
    slope = ground_slope(pixels, sampled, config)
    if slope is None:
        return None
    rows = np.arange(h, dtype=np.float32)[:, None]
    below = rows > parallax.epipole_row
    road_depth = slope * np.maximum(rows - parallax.epipole_row, 0.0)  # (H, 1) inverse depth x baseline
    road_px = road_depth * parallax.gain
    depth = parallax.signed / np.maximum(parallax.gain, 1e-12)
    road = valid & below & (road_px >= config.ground_min_px) & (
        np.abs(depth - road_depth) <= config.footing_road_tol * road_depth)
    # The first road row at or under each pixel of its column (h: none), a running minimum from the image's bottom
    # up; in the smallest integer type that holds h, twice as fast as in floats.
    index = np.arange(h, dtype=np.min_scalar_type(h))[:, None]
    first_road = np.minimum.accumulate(np.where(road, index, index.dtype.type(h))[::-1], axis=0)[::-1]
    footing_px = slope * np.maximum(first_road.astype(np.float32) - parallax.epipole_row, 0.0) * parallax.gain
    # The tolerance lets an object's own lowest part pass for road where the road under it is out of view (a parked
    # car cut by the image's lower edge): a footing counts only where the road goes on clearly below it.
    further = first_road.astype(np.intp) + int(np.ceil(clearance * h))
    confirmed = (further < h) & (np.take_along_axis(first_road, np.minimum(further, h - 1), axis=0) < h)
    decided = valid & below & confirmed & (footing_px >= config.ground_min_px)
    excess_px = config.footing_px if excess_px is None else excess_px
    allowed = footing_allowance(first_road, parallax.epipole_row, parallax.vote.focal, config) * footing_px
    return decided & (parallax.signed > allowed + excess_px)


def ground_slope(x1: np.ndarray, parallax: Parallax, config: TrackMotionConfig = TrackMotionConfig()) -> float | None:
    """The ground's inverse depth (x the pair's baseline) per row below the epipole (see
    ``ground_parallax_ratio``); None when the camera does not move forward or fewer than three bands hold
    ``ground_band_tracks`` tracks."""
    if parallax.epipole_row is None:
        return None
    height = x1[:, 1] - parallax.epipole_row
    depth = parallax.signed / np.maximum(parallax.gain, 1e-12)  # inverse depth x baseline
    usable = (height > 0) & (parallax.gain > 0) & (depth > 0)
    if usable.sum() < 3 * config.ground_band_tracks:
        return None
    edges = np.linspace(0.0, float(height[usable].max()) + 1e-6, config.ground_bands + 1)
    band = np.digitize(height, edges) - 1
    slopes = []
    for k in range(config.ground_bands):
        members = usable & (band == k)
        if members.sum() >= config.ground_band_tracks:
            slopes.append(np.percentile(depth[members], config.ground_quantile) / (0.5 * (edges[k] + edges[k + 1])))
    return float(np.percentile(slopes, 25)) if len(slopes) >= 3 else None


def ground_parallax_ratio(x1: np.ndarray, parallax: Parallax, config: TrackMotionConfig = TrackMotionConfig(),
                          slope: float | None = None) -> np.ndarray | None:
    """(N,) float32 each track's signed parallax over the parallax the ground would have at its pixel.

    The ground's inverse depth is taken as ``slope x (row - epipole row)`` below the epipole: in each of
    ``ground_bands`` bands of rows there, the ``ground_quantile`` percentile of the tracks' inverse depths
    (signed / gain) over the band's distance from the epipole gives a slope, and the lower quartile of the
    bands' slopes is the floor's (the road holds the lowest inverse depths of a band; bands seeing only
    objects on it give steeper slopes).

    Args:
        x1: (N, 2) positions in the pair's earlier frame (where ``parallax`` was measured).
        parallax: the pair's ``signed_parallax``.
        config: the ground settings.
        slope: the pair's ``ground_slope`` when the caller has it (computed here otherwise).

    Returns:
        Ratios, NaN above the epipole and where the floor's parallax is below ``ground_min_px``; None when
        the camera does not move forward or fewer than three bands hold ``ground_band_tracks`` tracks.
    """
    floor = ground_floor(x1, parallax, config, slope)
    return None if floor is None else (parallax.signed / floor).astype(np.float32)


def ground_floor(x1: np.ndarray, parallax: Parallax, config: TrackMotionConfig = TrackMotionConfig(),
                 slope: float | None = None, rows: np.ndarray | None = None) -> np.ndarray | None:
    """(N,) float64 the parallax in pixels the ground would have at each track's pixel, or in its column at its
    ``rows`` when given (``ground_parallax_ratio`` describes the floor); NaN above the epipole and where it is
    below ``ground_min_px``, None without a slope."""
    if slope is None:
        slope = ground_slope(x1, parallax, config)
    if slope is None:
        return None
    rows = x1[:, 1] if rows is None else rows
    floor = slope * np.maximum(rows - parallax.epipole_row, 0.0) * parallax.gain
    return np.where(floor >= config.ground_min_px, floor, np.nan)


def standing_shortfall(x1: np.ndarray, parallax: Parallax, ground: np.ndarray | None,
                       config: TrackMotionConfig = TrackMotionConfig(), slope: float | None = None,
                       columns: FootingColumns | None = None) -> np.ndarray | None:
    """(N,) float32 pixels by which each track falls short of the ground where it stands by both of the shortfall
    test's measures: min(floor - signed - ``shortfall_px``, ``shortfall_ratio`` x floor - signed), the floor
    being ``ground_floor`` at its ``standing_rows``, or by both of its strong measures (``shortfall_strong_px``
    and ``shortfall_strong_ratio``) where that is more. Positive: farther than the ground there by more than
    ``shortfall_px`` and below ``shortfall_ratio`` of it, or by more than ``shortfall_strong_px`` and below
    ``shortfall_strong_ratio`` of it (one pair's verdict on both, so that the window's majority,
    ``short_of_ground``, asks both of the same pairs); NaN and None as ``ground_floor``. ``columns``: the pair's
    ``footing_columns`` when the caller has them."""
    floor = ground_floor(x1, parallax, config, slope, standing_rows(x1, parallax, ground, config, columns))
    if floor is None:
        return None
    # Each measure asks for the larger of its pixels and its share of the floor; the track meets the lesser ask.
    needed = np.maximum(config.shortfall_px, (1.0 - config.shortfall_ratio) * floor)
    if config.shortfall_strong_px > 0:
        strong = np.maximum(config.shortfall_strong_px, (1.0 - config.shortfall_strong_ratio) * floor)
        needed = np.minimum(needed, strong)
    return (floor - parallax.signed - needed).astype(np.float32)


def standing_rows(x1: np.ndarray, parallax: Parallax, ground: np.ndarray | None,
                  config: TrackMotionConfig = TrackMotionConfig(),
                  columns: FootingColumns | None = None) -> np.ndarray:
    """(N,) float64 the row each track's object stands on at least: the lowest track below it in its column
    (``footing_columns``) at its own inverse depth within ``shortfall_same_depth``, or its own row (above the
    epipole, and without such a track).

    An upright static object is as near as the ground where it stands, and that lies at or below its lowest
    track; a pedestrian walking away looks farther than the ground under its feet from every one of its tracks,
    while its upper tracks look nearer than the road at their own rows (which lies farther away). ``columns``:
    the pair's ``footing_columns`` when the caller has them."""
    rows = x1[:, 1].astype(np.float64)
    if parallax.epipole_row is None:
        return rows
    tested, index, under, depth = footing_columns(x1, parallax, ground, config) if columns is None else columns
    if tested.size:
        rows[tested] = _footing_base(rows[tested], x1[index, 1], under, depth[index], depth[tested],
                                     config.shortfall_same_depth)
    return rows


def footing_excess(x1: np.ndarray, parallax: Parallax, ground: np.ndarray | None,
                   config: TrackMotionConfig = TrackMotionConfig(), slope: float | None = None,
                   columns: FootingColumns | None = None) -> np.ndarray | None:
    """(N,) float32 pixels by which each track's parallax exceeds what the surface under it allows.

    For a track below the epipole, the tracks below it within ``footing_band`` of the tracks' horizontal extent
    are its column. Its footing is the ``footing_support``-th lowest inverse depth (signed / gain) of the
    column or, when lower and ``ground`` is given, the ground's inverse depth at the row the track's object
    stands on: the lower of the column's first road track (a ground ratio within ``footing_road_tol`` of 1) and
    the object's lowest track (``_footing_base``: the lowest track of the column at the track's own inverse
    depth, within ``footing_same_depth``, that is not a road track itself). The excess is
    ``signed - footing_allowance x footing x gain``. A static track's excess is negative; an oncoming car's
    is positive (it closes in faster than the camera drives and looks nearer than the road under it).

    Args:
        x1: (N, 2) positions in the pair's earlier frame.
        parallax: the pair's ``signed_parallax``.
        ground: (N,) the pair's ``ground_parallax_ratio`` or None; tracks below ``ground_ratio`` are no
            footing (a followed car looks farther than anything behind it).
        config: the footing settings (``ground_min_px``: where the footing's parallax is below it, the track
            is not decided).
        slope: the pair's ``ground_slope`` when the caller has it (computed here otherwise, when ``ground``
            is given).
        columns: the pair's ``footing_columns`` when the caller has them (found here otherwise).

    Returns:
        Excesses, NaN where not decided; None when the camera does not move forward.
    """
    if parallax.epipole_row is None:
        return None
    excess = np.full(len(x1), np.nan, dtype=np.float32)
    tested, index, under, depth = footing_columns(x1, parallax, ground, config) if columns is None else columns
    if not tested.size:
        return excess
    rows = x1[index, 1]
    k = config.footing_support
    support = np.full(len(tested), np.inf, dtype=np.float32)
    support_row = x1[tested, 1].astype(np.float64)
    if under.shape[1] >= k:
        candidates = np.where(under, depth[index], np.inf).astype(np.float32)
        kth = np.argpartition(candidates, k - 1, axis=1)[:, k - 1:k]
        support, support_row = (np.take_along_axis(candidates, kth, axis=1)[:, 0],
                                np.take_along_axis(rows, kth, axis=1)[:, 0])
    if ground is None or config.footing_road_tol <= 0:
        slope = None
    elif slope is None:
        slope = ground_slope(x1, parallax, config)
    road = (under & (np.abs(ground[index] - 1.0) <= config.footing_road_tol) if slope is not None
            else np.zeros_like(under))
    base = _footing_base(x1[tested, 1], rows, under & ~road, depth[index], depth[tested], config.footing_same_depth)
    if slope is not None:
        first_road = np.where(road, rows, np.inf).min(axis=1)
        found = np.isfinite(first_road)
        stands = np.maximum(first_road[found], base[found])
        road_support = slope * (stands - parallax.epipole_row)
        lower = road_support < support[found]
        on_road = np.flatnonzero(found)[lower]
        support[on_road], support_row[on_road] = road_support[lower], stands[lower]
    ahead = support * parallax.gain[tested]  # the parallax the footing's depth gives at the track
    # Where nothing of the column lies clearly below the object's lowest track, its ground contact is out of view
    # (a near parked van cut by the image's edge), and what the column holds lies beside the object, not under it.
    seen = (under & (rows > base[:, None] + config.footing_clearance * float(np.ptp(x1[:, 1])))).any(axis=1)
    decided = np.isfinite(ahead) & (ahead >= config.ground_min_px) & seen
    allowance = footing_allowance(support_row, parallax.epipole_row, parallax.focal, config)
    excess[tested[decided]] = (parallax.signed[tested] - allowance * ahead)[decided]
    return excess


def footing_allowance(rows: np.ndarray, epipole_row: float, focal: float,
                      config: TrackMotionConfig = TrackMotionConfig()) -> np.ndarray:
    """The factor over a footing's parallax that a static point's may reach, for footings at ``rows`` (any shape)
    of a pair whose epipole lies at ``epipole_row`` and whose K has the vertical ``focal`` length:
    ``1 + footing_margin + footing_overhang x (row - epipole_row) / focal``, the last term the overhang's share of
    the footing's inverse depth over a level road (``TrackMotionConfig.footing_overhang``)."""
    tangent = np.maximum(np.asarray(rows, dtype=np.float32) - np.float32(epipole_row), 0.0) / np.float32(focal)
    return 1.0 + config.footing_margin + config.footing_overhang * tangent


class FootingColumns(NamedTuple):
    """What lies under each track of a pair (``footing_columns``): the tracks below the epipole (``tested``, (T,)
    indices), the tracks under each in its column band (``index`` (T, run) and ``under`` (T, run) bool, as
    ``_band_below``; T = 0 when no band holds one) and every track's inverse depth (``depth`` (N,), signed /
    gain)."""

    tested: np.ndarray
    index: np.ndarray
    under: np.ndarray
    depth: np.ndarray


def footing_columns(x1: np.ndarray, parallax: Parallax, ground: np.ndarray | None,
                    config: TrackMotionConfig = TrackMotionConfig()) -> FootingColumns:
    """The column under each track below the epipole (``footing_band`` of the tracks' horizontal extent) and the
    tracks in it that may be a footing: in front of infinity and, with ``ground``, not below ``ground_ratio`` (a
    followed car looks farther than anything behind it). The footing and standing tests share them."""
    depth = parallax.signed / np.maximum(parallax.gain, 1e-12)
    below_horizon = x1[:, 1] > parallax.epipole_row
    footing = below_horizon & (parallax.gain > 0) & (depth > 0)
    if ground is not None:
        footing &= ~(ground < config.ground_ratio)
    tested = np.flatnonzero(below_horizon)
    column = _band_below(x1, np.flatnonzero(footing), tested, config.footing_band * float(np.ptp(x1[:, 0])))
    if column is None:
        return FootingColumns(tested[:0], np.zeros((0, 0), dtype=np.int64), np.zeros((0, 0), dtype=bool), depth)
    return FootingColumns(tested, *column, depth)


def _footing_base(row: np.ndarray, rows: np.ndarray, under: np.ndarray, depths: np.ndarray, depth: np.ndarray,
                  same_depth: float) -> np.ndarray:
    """(T,) the lowest row (largest y) of each tested track's object: its own row or that of the lowest track
    under it (``rows``, ``under``: (T, run) from ``_band_below``) whose inverse depth ``depths`` is within
    ``same_depth`` of its own ``depth``. A thin pole hides little of the road beside its trunk; the road seen
    there lies behind it, not under it."""
    same = under & (np.abs(depths / np.maximum(depth, 1e-12)[:, None] - 1.0) <= same_depth)
    return np.maximum(np.where(same, rows, -np.inf).max(axis=1), row)


def _band_below(x: np.ndarray, candidates: np.ndarray, tested: np.ndarray,
                band: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The candidates in each tested point's column: (T, run) indices into x and (T, run) bool, True where the
    candidate is within ``band`` of the tested point's column and lower in the image; None when no band holds
    one.

    The candidates are sorted by column, so each tested point compares only with the run of candidates in its
    band (a (tested, longest run) table instead of (tested, candidates))."""
    if len(candidates) == 0 or len(tested) == 0:
        return None
    order = candidates[np.argsort(x[candidates, 0], kind="stable")]
    cx = x[order, 0]
    first = np.searchsorted(cx, x[tested, 0] - band, side="right")
    stop = np.searchsorted(cx, x[tested, 0] + band, side="left")
    run = int((stop - first).max())
    if run < 1:
        return None
    index = first[:, None] + np.arange(run)
    inside = index < stop[:, None]
    index = order[np.minimum(index, len(order) - 1)]
    return index, inside & (x[index, 1] > x[tested, 1][:, None])


class PairEvidence(NamedTuple):
    """One frame pair's evidence per track: ``distance`` as ``pair_residual``; given a camera matrix and a
    non-degenerate F, ``signed`` (``signed_parallax``), ``ground`` (``decided_ratios``), ``footing``
    (``footing_excess``) and ``shortfall`` (``standing_shortfall``), each None when not decided."""

    distance: np.ndarray
    signed: np.ndarray | None = None
    ground: np.ndarray | None = None
    footing: np.ndarray | None = None
    shortfall: np.ndarray | None = None


def pair_evidence(x1: np.ndarray, x2: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                  K: np.ndarray | None = None, guarded: bool = False,
                  planar_check: bool = True) -> PairEvidence | None:
    """The evidence of one frame pair's tracks (``PairEvidence``); None when there is no model at all.

    Under F a track's distance is its Sampson distance beyond ``epipole_allowance`` times its displacement
    (``beyond_allowance``); under a homography or a still camera it is the whole transfer error or motion.

    ``guarded``: the rotation may be misjudged (the module's docstring): a track is behind infinity only by at
    least ``behind_share`` of the rotation's image motion at it, and pairs turning more than
    ``max_rotation_deg`` sign nothing else (``signed_parallax``).
    ``planar_check``: False skips the homography's test of F's degeneracy (a caller that knows the camera
    translates, from a pair of the same window; the homography fit is the costlier half)."""
    if len(x1) < config.min_tracks:
        return None
    x1, x2 = np.asarray(x1, dtype=np.float64), np.asarray(x2, dtype=np.float64)
    if np.median(np.linalg.norm(x2 - x1, axis=1)) < config.min_parallax_px:
        # The camera stands still: the dominant motion is the identity, any motion is the residual.
        return PairEvidence(np.linalg.norm(x2 - x1, axis=1).astype(np.float32))
    fundamental, f_inliers = fundamental_polished(x1, x2, config.inlier_px)
    if fundamental is None:
        return None
    homography, h_inliers = (homography_ransac(x1, x2, cv2.USAC_MAGSAC, config.ransac_px)
                             if planar_check and may_be_planar(x1, x2, f_inliers, config) else (None, None))
    f_squared = sampson_distance(fundamental[None], x1, x2)[0]
    # The pair's noise: the robust sigma of F's inliers' distances (pixels).
    noise = 1.4826 * float(np.median(np.sqrt(f_squared[f_inliers]))) if f_inliers.any() else np.inf
    planar = False
    if homography is not None:
        h_squared = 0.5 * homography_transfer_error(homography[None], x1, x2)[0]
        # F is degenerate when the homography explains about as many tracks, or when Torr's GRIC prefers it.
        planar = h_inliers.sum() >= config.homography_preference * f_inliers.sum()
        if not planar:
            planar = homography_preferred(f_squared, h_squared, max(noise, config.gric_min_sigma_px))
    if planar:
        # F is degenerate: no translation to take a sign from.
        return PairEvidence(np.sqrt(h_squared).astype(np.float32))
    # cv2's F satisfies x2^T F x1 = 0, the convention of geometry.sampson_distance(F, x1, x2).
    distance = beyond_allowance(np.sqrt(f_squared), x2 - x1, config.epipole_allowance)
    if K is None:
        return PairEvidence(distance)
    limit = config.max_rotation_deg if guarded else np.inf
    parallax = signed_parallax(x1, x2, fundamental, f_inliers, K, config, limit)
    if parallax is None:
        return PairEvidence(distance)
    slope = ground_slope(x1, parallax, config)  # once for the ground, shortfall and footing tests
    signed = guarded_signs(x1, parallax, config.behind_share) if guarded else parallax.signed
    if slope is None:
        return PairEvidence(distance, signed, None, footing_excess(x1, parallax, None, config, slope))
    floor = ground_floor(x1, parallax, config, slope)  # once for the ratios and which of them are decided
    ground = (parallax.signed / floor).astype(np.float32)  # as ground_parallax_ratio gives them
    columns = footing_columns(x1, parallax, ground, config)  # once for the footing and shortfall tests
    return PairEvidence(distance, signed, decided_ratios(ground, floor, config, noise),
                        footing_excess(x1, parallax, ground, config, slope, columns),
                        standing_shortfall(x1, parallax, ground, config, slope, columns))


def decided_ratios(ground: np.ndarray, floor: np.ndarray, config: TrackMotionConfig, noise: float) -> np.ndarray:
    """(N,) float32 the ``ground`` ratios (``ground_parallax_ratio``) that the ratio test decides on: NaN where the
    ``floor`` (``ground_floor``, pixels) is below ``ground_ratio_noise`` times the pair's ``noise`` (pixels; the
    footing and shortfall tests keep every ratio)."""
    return np.where(floor >= config.ground_ratio_noise * noise, ground, np.nan).astype(np.float32)


def beyond_allowance(distance: np.ndarray, displacement: np.ndarray, allowance: float) -> np.ndarray:
    """(...) float32 epipolar ``distance`` (any shape) of correspondences less ``allowance`` times the length of
    each one's ``displacement`` (that shape plus a last axis of 2: x2 - x1, or a dense flow), at least 0
    (``TrackMotionConfig.epipole_allowance``; the front-end's ``dense_allowance`` for a dense flow)."""
    if allowance <= 0:
        return np.asarray(distance, dtype=np.float32)
    return np.maximum(distance - allowance * np.hypot(displacement[..., 0], displacement[..., 1]),
                      0.0).astype(np.float32)


def may_be_planar(x1: np.ndarray, x2: np.ndarray, f_inliers: np.ndarray,
                  config: TrackMotionConfig = TrackMotionConfig()) -> bool:
    """Whether a homography might explain about as many of the (N, 2) correspondences ``x1`` -> ``x2`` as F
    does (its (N,) bool ``f_inliers``): a quick RANSAC homography on every ``screen_stride``-th one explains at
    least ``homography_screen`` of F's inliers among them. False tells the caller to skip the full fit."""
    if config.homography_screen <= 0:
        return True
    step = max(1, config.screen_stride)
    model, inliers = homography_ransac(x1[::step], x2[::step], cv2.RANSAC, config.ransac_px,
                                       config.screen_iterations, 0.99)
    # No quick model decides nothing: the full fit does.
    return model is None or bool(inliers.sum() >= config.homography_screen * f_inliers[::step].sum())


def pair_residual(x1: np.ndarray, x2: np.ndarray,
                  config: TrackMotionConfig = TrackMotionConfig()) -> np.ndarray | None:
    """Distance of N correspondences from the dominant motion fitted to them by RANSAC.

    Sampson distance under F (beyond ``epipole_allowance``, see ``pair_evidence``), or the symmetric transfer
    error under a homography when one explains at least ``homography_preference`` as many correspondences as F
    (F is then degenerate).

    Args:
        x1: (N, 2) positions in the earlier frame.
        x2: (N, 2) the same points in the later frame.
        config: RANSAC threshold, smallest usable number of tracks and parallax.

    Returns:
        (N,) float32 distances in pixels, or None when there are too few points, too little parallax (the
        geometry is not determined) or RANSAC finds no model.
    """
    evidence = pair_evidence(x1, x2, config)
    return None if evidence is None else evidence.distance


def pair_residuals(tracks: np.ndarray, visible: np.ndarray,
                   config: TrackMotionConfig = TrackMotionConfig()) -> np.ndarray:
    """Sampson distance of every track under the dominant F of every frame pair (m, m + gap) of a window.

    Args:
        tracks: (N, F, 2) positions (x, y), NaN where not visible.
        visible: (N, F) bool.
        config: the gap and the settings of ``pair_residual``.

    Returns:
        (N, P) float32 distances in pixels, P = F - gap pairs, NaN where the track is not in both frames or
        the pair has no model.
    """
    pairs = max(visible.shape[1] - config.gap, 0)
    residuals = np.full((visible.shape[0], pairs), np.nan, dtype=np.float32)
    for m in range(pairs):
        both = visible[:, m] & visible[:, m + config.gap]
        distance = pair_residual(tracks[both, m], tracks[both, m + config.gap], config)
        if distance is not None:
            residuals[both, m] = distance
    return residuals


def moving_tracks(residuals: np.ndarray, config: TrackMotionConfig = TrackMotionConfig(),
                  signed: np.ndarray | None = None, ground: np.ndarray | None = None,
                  footing: np.ndarray | None = None, shortfall: np.ndarray | None = None,
                  dense: np.ndarray | None = None, measurable: np.ndarray | None = None,
                  depth: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: tracks whose median distance over their pairs exceeds max(factor x median, floor) (where the
    ``dense`` residual, when given, reaches ``corroboration`` times that distance, or the distance exceeds
    ``evident_factor`` times the threshold), whose median signed parallax is below -cheir_px, whose median
    ground ratio is below ground_ratio, whose median footing excess is above footing_px, or that fall short of
    the ground where they stand in most pairs (``short_of_ground``, where ``measurable``).

    Args:
        residuals: (N, P) distances from ``pair_residuals`` (NaN = not measured).
        config: the factor and floor.
        signed: optional (N, P) signed parallax (NaN = not measured or pair undecided).
        ground: optional (N, P) ratios of ``ground_parallax_ratio`` (NaN = undecided).
        footing: optional (N, P) excesses of ``footing_excess`` (NaN = undecided).
        shortfall: optional (N, P) margins of ``standing_shortfall`` (NaN = undecided).
        dense: optional (N,) the dense flow's epipolar residual near each track, in the units of its distance
            (NaN: not known there, no corroboration asked).
        measurable: optional (N,) bool, the tracks whose image can show their parallax (``aperture_share``);
            the shortfall test takes only those (default: every track).
        depth: optional (N,) bool, the depth tests' part (``depth_moving`` of the same arguments) when the caller
            has it already; then ``signed`` to ``measurable`` are not read.
    """
    per_track = row_medians(residuals)
    measured = ~np.isnan(per_track)
    moving = np.zeros(residuals.shape[0], dtype=bool)
    if not measured.any():
        return moving
    threshold = max(config.factor * float(np.median(per_track[measured])), config.floor_px)
    moving[measured] = per_track[measured] > threshold
    if dense is not None and config.corroboration > 0:
        doubted = dense < config.corroboration * per_track  # NaN compares False
        moving &= ~doubted | (per_track > config.evident_factor * threshold)
    if depth is None:
        depth = depth_moving(residuals.shape[0], config, signed, ground, footing, shortfall, measurable)
    return moving | depth


def depth_moving(n: int, config: TrackMotionConfig = TrackMotionConfig(), signed: np.ndarray | None = None,
                 ground: np.ndarray | None = None, footing: np.ndarray | None = None,
                 shortfall: np.ndarray | None = None, measurable: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: the part of ``moving_tracks`` that the depth tests flag (cheirality, the ground's ratio and
    shortfall, the footing): tracks whose motion lies along their epipolar lines, which no epipolar distance
    and no model of an object's own motion shows (a car driving along the camera's axis images as a static copy
    of it: docs/experiments.md). The arguments are ``moving_tracks``' (N: the number of tracks)."""
    moving = np.zeros(n, dtype=bool)
    if signed is not None:
        moving |= _median_below(signed, -config.cheir_px)
    if ground is not None:
        moving |= _median_below(ground, config.ground_ratio)
    if footing is not None:
        moving |= _median_below(-footing, -config.footing_px)
    if shortfall is not None:
        short = short_of_ground(shortfall)
        moving |= short if measurable is None else short & measurable
    return moving


def short_of_ground(shortfall: np.ndarray) -> np.ndarray:
    """(N,) bool: tracks short of the ground where they stand (a positive margin of ``standing_shortfall``,
    (N, P)) in more than half of the pairs that measured them (``moving_tracks``' ground shortfall test before
    its ``measurable`` check). A majority rather than the median: the median of an even count averages a pair
    far short with one that is not."""
    return np.count_nonzero(shortfall > 0, axis=1) > 0.5 * np.count_nonzero(~np.isnan(shortfall), axis=1)


def aperture_share(gray: np.ndarray, points: np.ndarray, centre: np.ndarray, window: int) -> np.ndarray:
    """(N,) the share of the image-gradient energy around each point that lies along the line from ``centre``
    through it: how well a patch tracker measures the point's motion along that line (0 on an edge running
    along it, the aperture problem; 1 on an edge across it, about 0.5 on a corner).

    d^T G d / trace(G), with G the structure tensor (summed products of Sobel 3x3 gradients) over a ``window`` x
    ``window`` patch and d the unit direction from ``centre`` to the point. Computed on each point's patch
    alone (the border pixel repeated outside the image): the test asks it of a few tracks a frame.

    Args:
        gray: (H, W) image.
        points: (N, 2) positions (x, y) in it; outside ones take the nearest border pixel.
        centre: (2,) where the lines start (the epipole of a camera driving forward: its parallax runs from it).
        window: side of the patch, pixels (odd).
    """
    h, w = gray.shape
    x, y = np.clip(np.rint(points).astype(np.int64), 0, [w - 1, h - 1]).T
    reach = np.arange(-(window // 2) - 1, window // 2 + 2)
    rows, columns = np.clip(y[:, None] + reach, 0, h - 1), np.clip(x[:, None] + reach, 0, w - 1)
    patch = gray[rows[:, :, None], columns[:, None, :]].astype(np.float32)  # (N, window + 2, window + 2)
    smooth_y = patch[:, :-2] + 2.0 * patch[:, 1:-1] + patch[:, 2:]
    smooth_x = patch[:, :, :-2] + 2.0 * patch[:, :, 1:-1] + patch[:, :, 2:]
    gx, gy = smooth_y[:, :, 2:] - smooth_y[:, :, :-2], smooth_x[:, 2:] - smooth_x[:, :-2]
    xx, xy, yy = ((a * b).sum(axis=(1, 2)) for a, b in ((gx, gx), (gx, gy), (gy, gy)))
    d = points - np.asarray(centre, dtype=np.float64)
    d /= np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
    along = xx * d[:, 0] ** 2 + 2.0 * xy * d[:, 0] * d[:, 1] + yy * d[:, 1] ** 2
    return along / np.maximum(xx + yy, 1e-12)


def _median_below(values: np.ndarray, limit: float) -> np.ndarray:
    """(N,) bool: rows of (N, P) ``values`` with a measurement (not NaN) whose median is below ``limit``."""
    return row_medians(values) < limit  # NaN (no measurement) compares False


def row_medians(values: np.ndarray) -> np.ndarray:
    """(N,) the median of each row of (N, P) ``values``, NaN ignored (NaN for a row without a number).

    The same numbers as ``np.nanmedian(values, axis=1)`` (the mean of the two middle values of an even count),
    from one sort: for short rows NumPy's nanmedian goes through masked arrays, several times slower, and the
    refit takes about four of these a frame while holding the GIL the frame path needs.
    """
    if values.shape[1] == 0:
        return np.full(values.shape[0], np.nan)
    ordered = np.sort(values, axis=1)  # NaN sorts last
    count = values.shape[1] - np.isnan(values).sum(axis=1)
    rows = np.arange(values.shape[0])
    middle = 0.5 * (ordered[rows, np.maximum((count - 1) // 2, 0)] + ordered[rows, np.maximum(count // 2, 0)])
    return np.where(count > 0, middle, np.nan)
