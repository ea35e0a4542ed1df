"""Cheirality: which tracks lie behind infinity, from their parallax signed against the infinite homography.

With K (camera_info's, or ``guessed_camera_matrix``), E = Kᵀ F K gives R and t; the infinite homography
H∞ = K R K⁻¹ maps x1 to where a point at infinite depth lands, and a static point's image moves away from there
as its inverse depth grows (Hartley & Zisserman 9.6.3). A track whose signed parallax is negative lies behind
infinity: a car pulling away ahead. The sign of t is voted by F's inliers. ``dense_parallax`` gives the same
quantity for every pixel of a dense flow. docs/method.md has the derivation and the guards against a misjudged R.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from moseg_ros.core.flow_field import pixel_grid
from moseg_ros.core.geometry import sampson_distance
from moseg_ros.core.track_tests.settings import TrackMotionConfig


def guessed_camera_matrix(image_size: tuple[int, int], focal_fraction: float = 0.9) -> np.ndarray:
    """Camera matrix of an uncalibrated camera: focal ``focal_fraction`` x width, principal point at the centre.

    K = [[f, 0, w/2], [0, f, h/2], [0, 0, 1]],  f = focal_fraction · w

    Args:
        image_size: (h, w) in pixels (height first).
        focal_fraction: focal length over the width.

    Returns:
        (3, 3) float64 K.
    """
    h, w = image_size
    f = focal_fraction * w
    return np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])


def rotation_degrees(R: np.ndarray) -> float:
    """The angle of a (3, 3) rotation matrix in degrees: θ = arccos((tr R − 1) / 2)."""
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
        Parallax of the N tracks; None when the pair does not decide the sign (too few votes, no consensus, or
        too much rotation with an infinite ``behind_share``). The translation's sign is the one the votes
        choose, for ``signed`` and ``epipole_row`` alike.
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
    """Points whose parallax lies behind infinity by at least ``share`` of the image motion the rotation alone
    gives them: −signed >= share · |K R K⁻¹ x1 − x1|.

    The rotation recovered from F is off by a share of its own image motion (most with a guessed K, and in a
    turn with any), and static points come out behind infinity by about that much; an object the panning camera
    follows stays still in the image, so it lies behind infinity by all of it.

    Args:
        x1: (N, 2) points in the earlier image.
        signed: (N,) their signed parallax (``oriented_parallax``, oriented by the vote).
        rotation: (3, 3) the infinite homography K R K^-1.
        share: the least share of the rotation's motion.

    Returns:
        (N,) bool.
    """
    rotated = x1 @ rotation[:, :2].T + rotation[:, 2]
    motion = np.hypot(rotated[:, 0] / rotated[:, 2] - x1[:, 0], rotated[:, 1] / rotated[:, 2] - x1[:, 1])
    return -signed >= share * motion


def guarded_signs(x1: np.ndarray, parallax: Parallax, share: float) -> np.ndarray:
    """The signed parallax the cheirality test takes from a guarded pair (``pair_evidence``).

    A point ``far_behind`` infinity (by ``share`` of the rotation's image motion) keeps its value; one less far
    behind counts as at infinity (0), and in a ``turned`` pair every other point is undecided (NaN). The ground
    and footing tests keep ``parallax.signed``: a followed car's small negative parallax is theirs.

    Args:
        x1: (N, 2) points in the earlier image.
        parallax: the pair's ``signed_parallax``.
        share: the least share of the rotation's motion.

    Returns:
        (N,) signed parallax in pixels, 0 or NaN as above.
    """
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
    """The cheirality of ``signed_parallax`` for every pixel of a dense flow.

    The translation's sign is voted by every ``step``-th reliable pixel within ``inlier_px`` of its epipolar
    line, then each pixel's parallax against the plane at infinity is taken (``oriented_parallax``).
    ``behind_infinity`` and ``nearer_than_road`` read it.

    Args:
        to_previous: (H, W, 2) flow from the current frame to the previous one.
        valid: (H, W) bool pixels whose flow is reliable (forward-backward).
        fundamental: (3, 3) F with x_prev^T F x_cur = 0 (core/baseline.epipolar_residual's).
        K: (3, 3) camera matrix at the flow's size.
        config: the sign's vote (``cheir_consensus`` and friends) and ``ground_min_forward``.
        step, inlier_px: which pixels vote.
        max_rotation_deg: as in ``signed_parallax``.

    Returns:
        DenseParallax with (H, W) fields; None when the vote does not decide the translation's sign.
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
    """Reliable pixels whose signed parallax is below −``threshold_px``: the cheirality test for every pixel.

    It finds the body of an object the camera follows, or of a car pulling away, where tracks are few.

    Args:
        parallax: the flow's ``dense_parallax``.
        valid: (H, W) bool pixels whose flow is reliable.
        config: ``behind_share``.
        threshold_px: parallax below minus this moves.
        guarded: the rotation may be misjudged (a guessed K, a turn): a pixel is behind infinity only by at
            least ``config.behind_share`` of the rotation's image motion there (``far_behind``).

    Returns:
        (H, W) bool.
    """
    h, w = valid.shape
    behind = (parallax.signed < -threshold_px).ravel()
    if guarded:  # tested where behind only: a few pixels of the frame
        where = np.flatnonzero(behind)
        behind[where] = far_behind(pixel_grid(h, w).reshape(-1, 2)[where].astype(np.float64),
                                   parallax.signed.ravel()[where], parallax.vote.rotation, config.behind_share)
    return behind.reshape(h, w) & valid
