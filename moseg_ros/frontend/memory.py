"""The motion front-end's memory: moving evidence carried from frame to frame while it drops out.

Evidence flickers (a mover's residual around its threshold, a looming car's tracks dying of its growth, a small
fast car's flow smoothed into the background's). ``carried`` moves a mask along the dense backward flows since its
frame; ``remembered`` keeps each pixel's evidence for a few frames along the flow unless static tracks veto it;
``coasted`` moves a lasting region's evidence as a tracker coasts an object whose detections dropped out.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core.flow_field import pulled_forward


def carried(mask: np.ndarray, index: int, backward: tuple[tuple[int, np.ndarray], ...]) -> np.ndarray:
    """A mask of frame ``index`` carried along the backward flows to the last frame of ``backward``.

    Each flow of a later frame pulls the mask forward one frame (nearest-neighbour, 0 where it lands outside).

    Args:
        mask: (h, w) bool mask, or uint8 labels.
        index: the mask's frame.
        backward: (frame, (h, w, 2) backward flow to the frame before) pairs, oldest first.

    Returns:
        (h, w) mask where it lies in the last frame of ``backward``, of the same dtype.
    """
    labels = mask.astype(np.uint8, copy=False)
    for frame, flow in backward:
        if frame <= index:
            continue
        labels = pulled_forward(labels, flow, 0)
    return labels if mask.dtype == np.uint8 else labels > 0


# The age ``remembered`` gives a pixel that holds no evidence.
NO_EVIDENCE = np.uint8(255)


def remembered(fresh: np.ndarray, before: np.ndarray | None, flow: np.ndarray | None, settled: np.ndarray,
               frames: int, veto: int) -> np.ndarray:
    """Age of each pixel's moving evidence, in frames, carried along the flow.

    age = 0 where fresh; k <= frames where the carried age of the frame before is k − 1; NO_EVIDENCE elsewhere,
    and over each carried region that is not fresh now and holds ``veto`` or more ``settled`` points.

    Args:
        fresh: (h, w) bool evidence of this frame.
        before: (h, w) uint8 ages of the frame before, or None (no such frame).
        flow: (h, w, 2) flow, this frame -> the one before, or None.
        settled: (S, 2) points (x, y) of static evidence.
        frames: most frames a pixel's evidence is remembered.
        veto: settled points that veto a carried region (0: no veto).

    Returns:
        (h, w) uint8 ages.
    """
    age = np.where(fresh, 0, NO_EVIDENCE).astype(np.uint8)
    if frames <= 0 or before is None or flow is None or before.shape != fresh.shape:
        return age
    carried = pulled_forward(before, flow, int(NO_EVIDENCE))
    kept = (carried < frames) & ~fresh
    if veto > 0 and len(settled) and kept.any():
        count, labels = cv2.connectedComponents(kept.astype(np.uint8), connectivity=8)
        xy = np.clip(np.rint(settled).astype(np.int64), 0, [fresh.shape[1] - 1, fresh.shape[0] - 1])
        vetoed = np.bincount(labels[xy[:, 1], xy[:, 0]], minlength=count) >= veto
        vetoed[0] = False
        kept &= ~vetoed[labels]
    age[kept] = carried[kept] + 1
    return age


@dataclass(frozen=True)
class Coast:
    """A lasting region's coasting.

    Attributes:
        frames: the frames in a row it was drawn without its evidence.
        motion: (2, 3) similarity it last moved by (its tracks' from the frame before); None before one was fitted.
        shape: while it coasts, (h, w) bool evidence of its last frame with evidence, moved to the frame before.
    """

    frames: int = 0
    motion: np.ndarray | None = None
    shape: np.ndarray | None = None


def coasted(moving: np.ndarray, labels: np.ndarray, evidence: np.ndarray, lasting: dict[int, Coast],
            before: np.ndarray, now: np.ndarray, settled: np.ndarray, frames: int, min_tracks: int, cover: float,
            veto: int, flow: np.ndarray | None = None) -> tuple[np.ndarray, dict[int, Coast]]:
    """Lasting regions of the frame before carried where this frame's evidence lost them.

    x_now = motion · (x, y, 1)ᵀ, motion the (2, 3) similarity of the region's tracks (or the last one).

    A looming car's tracks die of its growth and its dense flow fails its check as it passes the camera, a small
    fast car's flow is smoothed into the background's: the evidence drops out for a frame or three while the
    object is still in view. A tracker of objects coasts a track whose detections drop out on its motion model;
    this does the same with a region's evidence: the evidence of each lasting region moves by the similarity of
    the tracks on it from the frame before to this one (cv2.estimateAffinePartial2D, RANSAC), or, with too few of
    them (they die with the evidence), both by the similarity it moved by last and along the dense ``flow``: a
    passing car's side is no similarity and its growth speeds up, so the last similarity alone slides the evidence
    off the car (or the image), while the dense flow alone lags behind a looming car, smoothed into the road's;
    where less than ``cover`` of it, moved, is evidence now, it is drawn. What coasts is a region's evidence, not
    its drawn area, and a coasting region goes on from where its evidence went: a drawn area grows with each
    coasted frame (and with the memory), and the background's tracks it takes in would move it with the
    background.

    Args:
        moving: (h, w) bool evidence of this frame.
        labels: (h, w) int region ids published for the frame before.
        evidence: (h, w) bool evidence of the frame before (its ``moving`` before its coasting).
        lasting: {id: Coast} of the regions that may coast (published for long enough).
        before: (N, 2) positions (x, y, at this size) in the frame before of the tracks seen in both frames.
        now: (N, 2) their positions in this frame.
        settled: (S, 2) tracks that lived through the window unflagged (static evidence).
        frames: most frames in a row a region coasts.
        min_tracks: fewest tracks of a region's evidence that fix its similarity.
        cover: the share of a region's moved evidence that this frame's evidence must cover for it not to coast.
        veto: a region's moved evidence holding this many ``settled`` points is not drawn (0: no veto).
        flow: (h, w, 2) dense flow from this frame back to the frame before, or None (the last similarity alone).

    Returns:
        ``moving`` with the moved evidence of each lasting region whose evidence dropped and that has coasted
        fewer than ``frames`` frames in a row; and {id: Coast} of the lasting regions.
    """
    out, coasts = moving.copy(), {}
    h, w = labels.shape
    xy = np.clip(np.rint(before).astype(np.int64), 0, [w - 1, h - 1])
    owner = np.where(evidence[xy[:, 1], xy[:, 0]], labels[xy[:, 1], xy[:, 0]], 0)
    for region, coast in lasting.items():
        mine = owner == region
        fitted = None
        if np.count_nonzero(mine) >= min_tracks:
            fitted, _ = cv2.estimateAffinePartial2D(before[mine], now[mine], method=cv2.RANSAC,
                                                    ransacReprojThreshold=2.0)
        motion = fitted if fitted is not None else coast.motion
        if motion is None:
            coasts[region] = coast
            continue
        shape = (coast.shape if coast.shape is not None else evidence & (labels == region)).astype(np.uint8)
        there = cv2.warpAffine(shape, motion, (w, h), flags=cv2.INTER_NEAREST) > 0
        if fitted is None and flow is not None and flow.shape[:2] == shape.shape:
            there |= pulled_forward(shape, flow, 0) > 0
        covered = np.count_nonzero(moving & there) >= cover * np.count_nonzero(there)
        if not there.any() or covered or (veto > 0 and _points_inside(settled, there) >= veto):
            coasts[region] = Coast(0, motion)
            continue
        if coast.frames >= frames:
            coasts[region] = Coast(frames, motion, there)
            continue
        out |= there
        coasts[region] = Coast(coast.frames + 1, motion, there)
    return out, coasts


def _points_inside(points: np.ndarray, mask: np.ndarray) -> int:
    """How many of the (N, 2) ``points`` (x, y) lie in the (h, w) bool ``mask``."""
    h, w = mask.shape
    xy = np.rint(points).astype(np.int64)
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < w) & (xy[:, 1] >= 0) & (xy[:, 1] < h)
    return int(np.count_nonzero(mask[xy[inside, 1], xy[inside, 0]]))
