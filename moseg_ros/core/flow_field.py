"""Dense flow fields as arrays: the size they are computed at, the pixel grid they are defined on, their
round-trip (forward-backward) error and where they land.

Pure numpy/OpenCV, shared by the per-pixel tests in core/ and the front-end that computes the flows.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np


# Smallest working side, in pixels. cv2.DISOpticalFlow.calc segfaults on heights of about 8-31 px at widths of
# 48 px and more (OpenCV 5.0.0); KLT and resize raise on 1-15 px frames. Probed: 32 is safe at widths 31-4096.
MIN_WORKING_SIDE = 32


def shrink_scale(height: int, width: int, max_width: int, max_pixels: int = 0, min_side: int = 0) -> float:
    """Scale (at most 1) that shrinks a frame to a width and pixel budget without a side below ``min_side``.

    s = min(1, max(min(max_width / W, sqrt(max_pixels / (H W))), min_side / H, min_side / W))

    A pixel budget as well as a width, since a width alone lets a frame's cost grow with its height (a 4:3
    frame holds 2.5 times the pixels of a 10:3 one of the same width).

    Args:
        height, width: frame size H, W in pixels.
        max_width: largest width after scaling.
        max_pixels: largest H W after scaling (to the rounding of the sides); 0 = no budget.
        min_side: no side that is at least this long is shrunk below it.

    Returns:
        The scale s.
    """
    scale = max_width / width
    if max_pixels > 0:
        scale = min(scale, float(np.sqrt(max_pixels / (height * width))))
    return min(1.0, max(scale, min_side / height, min_side / width))


@lru_cache(maxsize=8)
def pixel_grid(height: int, width: int, step: int = 1) -> np.ndarray:
    """Pixel centres of a regular grid: (H/step, W/step, 2) float32 (x, y). Cached and read-only."""
    ys, xs = np.mgrid[0:height:step, 0:width:step].astype(np.float32)
    grid = np.stack([xs, ys], axis=-1)
    grid.flags.writeable = False
    return grid


def forward_backward_error(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """Round-trip error |f(x) + b(x + f(x))| per pixel, the usual occlusion / mismatch test.

    Args:
        forward: (H, W, 2) flow source -> target.
        backward: (H, W, 2) flow target -> source.

    Returns:
        (H, W) float32 error in pixels (large where the flow is unreliable or occluded).
    """
    h, w = forward.shape[:2]
    grid = pixel_grid(h, w)
    landing = grid + forward
    # The (H, W, 2) map whole: its channels apart are strided views that OpenCV would copy first.
    back_at_landing = cv2.remap(backward, landing, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                borderValue=(1e3, 1e3))
    round_trip = forward + back_at_landing
    return np.hypot(round_trip[..., 0], round_trip[..., 1])


def lands_inside(flow: np.ndarray, margin: float) -> np.ndarray:
    """Pixels whose flow lands at least ``margin`` pixels inside the image.

    Near the target's border a dense flow's patches are clipped and its coarse levels extrapolate, so the
    matches that land there are guesses (and content entering the view has no match at all).

    Args:
        flow: (H, W, 2) flow.
        margin: pixels.

    Returns:
        (H, W) bool.
    """
    return away_from_border(pixel_grid(*flow.shape[:2]) + flow, flow.shape[:2], margin)


def away_from_border(points: np.ndarray, shape: tuple[int, int], margin: float) -> np.ndarray:
    """Which points lie at least ``margin`` pixels inside an image: margin <= x <= W − 1 − margin, same for y.

    Args:
        points: (..., 2) points (x, y).
        shape: (H, W) of the image.
        margin: pixels.

    Returns:
        (...) bool.
    """
    x, y = points[..., 0], points[..., 1]
    return (x >= margin) & (x <= shape[1] - 1 - margin) & (y >= margin) & (y <= shape[0] - 1 - margin)


def pulled_forward(image: np.ndarray, flow: np.ndarray, border: int) -> np.ndarray:
    """An image of the frame before, carried to this frame along the backward flow: out(x) = image(x + flow(x)).

    Args:
        image: (h, w) image of the frame before.
        flow: (h, w, 2) backward flow, this frame -> the one before.
        border: value where the flow lands outside the image.

    Returns:
        (h, w) image, same dtype, nearest-neighbour sampled.
    """
    landing = pixel_grid(*flow.shape[:2]) + flow
    # One (h, w, 2) map: its two channels passed apart are strided views that OpenCV copies first (twice the time).
    return cv2.remap(image, landing, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=border)
