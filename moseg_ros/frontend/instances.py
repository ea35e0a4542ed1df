"""Weight-free instance proposals and a tracker that keeps instance ids stable over time.

Without an upstream instance topic the baseline proposes regions from its own motion evidence: connected
components of a cleaned binary map. The tracker matches each frame's regions to the previous frame's by
mask IoU with the Hungarian method (scipy.optimize.linear_sum_assignment), so an object keeps its id; given the
dense flow, the previous regions are first moved along it to this frame.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from moseg_ros.core.baseline import DENSE_IDS
from moseg_ros.core.flow_field import pulled_forward


def propose_regions(evidence: np.ndarray, min_area: int, close_px: int = 5) -> np.ndarray:
    """Connected components of a binary evidence map after a morphological close and open.

    Args:
        evidence: (H, W) bool, pixels that look independently moving.
        min_area: components smaller than this many pixels are dropped as noise.
        close_px: structuring-element size that bridges gaps inside one object.

    Returns:
        (H, W) int32 labels, 0 = no region, 1..R the regions (unordered, not stable over time).
    """
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_px, close_px))
    mask = cv2.morphologyEx(evidence.astype(np.uint8), cv2.MORPH_CLOSE, kernel)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
    # The areas from a histogram of the labels: OpenCV's labelling with statistics costs several times as much.
    count, labels = cv2.connectedComponents(mask, connectivity=8)
    keep = np.zeros(count, dtype=np.int32)
    large = np.flatnonzero(np.bincount(labels.ravel(), minlength=count)[1:] >= min_area) + 1
    keep[large] = np.arange(1, large.size + 1, dtype=np.int32)
    return np.take(keep, labels)


def compact_ids(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An id map ((H, W) ints, 0 or below = none) renumbered 0..R: returns the (R + 1,) ids in order, the first
    0 (none), and the (H, W) int32 map of each pixel's number (the InstanceTracker's input form)."""
    ids = np.maximum(ids, 0)
    if ids.max(initial=0) <= DENSE_IDS:  # a table of the ids present: NumPy's unique sorts every pixel, 7x slower
        present = np.flatnonzero(np.bincount(ids.ravel()))
        values = present if present.size and present[0] == 0 else np.concatenate([[0], present])
        table = np.zeros(int(values[-1]) + 1, dtype=np.int32)
        table[values] = np.arange(values.size, dtype=np.int32)
        return values, np.take(table, ids)
    values, inverse = np.unique(ids, return_inverse=True)
    compact = inverse.reshape(ids.shape).astype(np.int32)
    if values[0] == 0:
        return values, compact
    return np.concatenate([[0], values]), compact + 1


def mask_iou_matrix(previous: np.ndarray, current: np.ndarray, n_prev: int, n_cur: int) -> np.ndarray:
    """IoU between every labelled region of two label maps, from one joint histogram.

    Args:
        previous: (H, W) int labels 0..n_prev.
        current: (H, W) int labels 0..n_cur.

    Returns:
        (n_prev, n_cur) float IoU of region i+1 of ``previous`` with region j+1 of ``current``.
    """
    # Only the pixels of some region count (the joint histogram's [0, 0], the shared background, is never used):
    # regions cover a few per cent of a frame.
    labelled = np.flatnonzero((previous.ravel() > 0) | (current.ravel() > 0))
    joint = np.bincount(previous.ravel()[labelled].astype(np.int64) * (n_cur + 1) + current.ravel()[labelled],
                        minlength=(n_prev + 1) * (n_cur + 1)).reshape(n_prev + 1, n_cur + 1)
    inter = joint[1:, 1:].astype(np.float64)
    union = joint[1:, :].sum(1)[:, None] + joint[:, 1:].sum(0)[None, :] - inter
    return inter / np.maximum(union, 1.0)


class InstanceTracker:
    """Gives regions ids that persist across frames (IoU matching with the previous frame).

    ``ages`` counts, per id, the consecutive frames it has been seen, so callers can ignore one-frame
    flickers (flow failures) and keep only regions that persist.
    """

    def __init__(self, min_iou: float = 0.2) -> None:
        self.min_iou = min_iou
        # The previous frame's regions as given (0..R) and the id each got: matching against them needs no
        # renumbering of the previous ids' map.
        self._previous: tuple[np.ndarray, np.ndarray] | None = None
        self._next_id = 1
        self.ages: dict[int, int] = {}

    def reset(self) -> None:
        """Forget all tracks (after a size change or a jump back in time)."""
        self._previous = None
        self._next_id = 1
        self.ages = {}

    def update(self, regions: np.ndarray, flow: np.ndarray | None = None) -> np.ndarray:
        """Relabel ``regions`` ((H, W) int32, 0 = none and 1..R each present) with persistent ids; returns
        (H, W) int32. ``flow``: see ``assign``."""
        return np.take(self.assign(regions, flow), regions)

    def assign(self, regions: np.ndarray, flow: np.ndarray | None = None) -> np.ndarray:
        """The persistent id of each region of ``regions`` (``update``'s input) as a (R + 1,) int32 table, 0 for
        none; the tracker moves on to this frame as ``update`` does. ``flow``: the (H, W, 2) dense flow from this
        frame back to the one before, which moves the previous regions to this frame before they are matched (a
        looming or fast object overlaps too little of where it was to keep its id otherwise); None: matched
        where they were."""
        n_cur = int(regions.max(initial=0))
        ids = np.zeros(n_cur + 1, dtype=np.int32)
        if self._previous is not None and self._previous[0].shape == regions.shape and n_cur:
            previous, previous_ids = self._previous
            if flow is not None and flow.shape[:2] == regions.shape and previous_ids.size < 2**16:
                previous = pulled_forward(previous.astype(np.uint16), flow, 0).astype(np.int32)
            if previous_ids.size:
                iou = mask_iou_matrix(previous, regions, previous_ids.size, n_cur)
                rows, cols = linear_sum_assignment(-iou)
                good = iou[rows, cols] >= self.min_iou
                ids[cols[good] + 1] = previous_ids[rows[good]]
        fresh = np.flatnonzero(ids[1:] == 0) + 1
        ids[fresh] = np.arange(self._next_id, self._next_id + fresh.size, dtype=np.int32)
        self._next_id += fresh.size
        self._previous = (regions, ids[1:])
        self.ages = {int(i): self.ages.get(int(i), 0) + 1 for i in ids[1:]}
        return ids
