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
from scipy.sparse.csgraph import connected_components

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
    """An id map renumbered 0..R (the InstanceTracker's input form).

    Args:
        ids: (H, W) int ids, 0 or below = none.

    Returns:
        values (R + 1,) the ids in order, the first 0 (none); compact (H, W) int32 each pixel's number,
        values[compact] = max(ids, 0).
    """
    ids = np.maximum(ids, 0)
    if ids.max(initial=0) <= DENSE_IDS:  # a table of the ids present: NumPy's unique sorts every pixel, much slower
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

    IoU_ij = |P_i ∩ C_j| / |P_i ∪ C_j|

    Args:
        previous: (H, W) int labels 0..n_prev.
        current: (H, W) int labels 0..n_cur.
        n_prev, n_cur: the largest label of each.

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


def kept_apart(regions: np.ndarray, previous: np.ndarray, eligible: np.ndarray, share: float,
               flow: np.ndarray | None = None, motion_ratio: float = 0.0) -> np.ndarray:
    """Regions that took in two or more eligible regions of the frame before that move apart, split between them.

    Each pixel of such a region goes to the nearest pixel of those regions inside it
    (cv2.distanceTransformWithLabels).

    Two movers whose regions touch come out of the evidence as one connected region; the frame before still had
    them apart, and each of them lies mostly inside the joined one. Two parts of one mover (a car's front and
    back, flagged apart for a while) also do, but they move alike (``same_motion``): they are joined.

    Args:
        regions: (H, W) int32, 0 = none and 1..R each present.
        previous: (H, W) int, the frame before's regions (0 = none, 1..P) at this frame (moved along the flow).
        eligible: (P + 1,) bool, which of ``previous``'s regions may be kept apart (the first, none, is ignored).
        share: the least share of an eligible region's pixels inside one region of ``regions`` that takes it in.
        flow: optional (H, W, 2) flow at this frame (to the frame before): regions taken in whose median flows
            are alike (``same_motion`` with ``motion_ratio``) count as one; None: each is a mover of its own.
        motion_ratio: see ``same_motion``.

    Returns:
        (H, W) int32: the regions, the parts of a split one numbered R + 1 on (its first part keeps its number).
    """
    n_cur = int(regions.max(initial=0))
    n_prev = eligible.size - 1
    if n_cur == 0 or n_prev < 2:
        return regions
    joint = np.bincount(previous.ravel().astype(np.int64) * (n_cur + 1) + regions.ravel(),
                        minlength=(n_prev + 1) * (n_cur + 1)).reshape(n_prev + 1, n_cur + 1)
    host = joint[:, 1:].argmax(axis=1) + 1
    taken = eligible & (joint[np.arange(n_prev + 1), host] >= share * np.maximum(joint.sum(axis=1), 1))
    taken[0] = False
    out = regions.copy()
    next_label = n_cur + 1
    for region in np.flatnonzero(np.bincount(host[taken], minlength=n_cur + 1) >= 2):
        ys, xs = np.nonzero(regions == region)
        window = np.s_[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
        inside = regions[window] == region
        members = np.flatnonzero(taken & (host == region))
        here = previous[window]
        mover = np.zeros(n_prev + 1, dtype=np.int64)
        mover[members] = members
        if flow is not None:
            medians = np.array([np.median(flow[window][inside & (here == m)], axis=0) for m in members])
            mover[members] = members[same_motion(medians, motion_ratio)]
        if np.unique(mover[members]).size < 2:
            continue
        nearest = nearest_seed(np.where(inside, mover[here], 0))
        parts = np.unique(nearest[inside])
        numbers = np.zeros(int(parts.max()) + 1, dtype=np.int32)
        numbers[parts] = np.concatenate([[region], np.arange(next_label, next_label + parts.size - 1)])
        next_label += parts.size - 1
        out[window][inside] = numbers[nearest[inside]]
    return out


# Two regions' median flows closer than this (pixels a frame) move alike whatever their speed (``same_motion``):
# DIS's error on a smooth body and a slow mover's parts.
SAME_MOTION_FLOOR_PX = 1.0


def same_motion(flows: np.ndarray, ratio: float) -> np.ndarray:
    """Groups of regions that move alike, from their median flows.

    Regions i and j move alike when |f_i − f_j| <= max(SAME_MOTION_FLOOR_PX, ratio · max(|f_i|, |f_j|)) (a rigid
    body's parts differ by its rotation and looming; two movers by their own motions); groups are the connected
    components of that relation (scipy.sparse.csgraph).

    Args:
        flows: (K, 2) median flow of each region (pixels a frame).
        ratio: share of the faster flow two alike regions may differ by.

    Returns:
        (K,) int index of the first region of the group each one moves with.
    """
    speed = np.linalg.norm(flows, axis=1)
    apart = np.linalg.norm(flows[:, None] - flows[None], axis=2)
    alike = apart <= np.maximum(SAME_MOTION_FLOOR_PX, ratio * np.maximum(speed[:, None], speed[None]))
    _, group = connected_components(alike, directed=False)
    first = np.full(group.max() + 1, len(flows))
    np.minimum.at(first, group, np.arange(len(flows)))
    return first[group]


def nearest_seed(seeds: np.ndarray) -> np.ndarray:
    """Each pixel's nearest non-zero seed value, by Euclidean distance (cv2.distanceTransformWithLabels).

    Args:
        seeds: (h, w) int, at least one non-zero.

    Returns:
        (h, w) values of ``seeds``' dtype.
    """
    _, pixel = cv2.distanceTransformWithLabels((seeds == 0).astype(np.uint8), cv2.DIST_L2, 5,
                                               labelType=cv2.DIST_LABEL_PIXEL)
    value = np.zeros(int(pixel.max()) + 1, dtype=seeds.dtype)
    value[pixel[seeds != 0]] = seeds[seeds != 0]
    return value[pixel]


class InstanceTracker:
    """Gives regions ids that persist across frames (IoU matching with the previous frame).

    ``ages`` counts, per id, the consecutive frames it has been seen, so callers can ignore one-frame
    flickers (flow failures) and keep only regions that persist. With ``keep_apart_after`` > 0, ``update`` keeps
    two regions seen that many frames apart when they join while they move apart (``kept_apart``, with the flow):
    each keeps its id.
    """

    def __init__(self, min_iou: float = 0.2, keep_apart_after: int = 0, keep_apart_share: float = 0.5,
                 keep_apart_motion: float = 0.3) -> None:
        self.min_iou = min_iou
        self.keep_apart_after = keep_apart_after
        self.keep_apart_share = keep_apart_share
        self.keep_apart_motion = keep_apart_motion
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
        """Relabel regions with persistent ids.

        With ``keep_apart_after``, a region that took in two or more of the frame before's regions, each seen
        that many frames, is split between them first.

        Args:
            regions: (H, W) int32, 0 = none and 1..R each present.
            flow: optional (H, W, 2) dense flow back to the frame before (see ``assign``).

        Returns:
            (H, W) int32 persistent ids (0 = none).
        """
        previous = self._moved_previous(regions.shape, flow)
        if self.keep_apart_after > 0 and previous is not None:
            old_ids = np.concatenate([[0], self._previous[1]])
            eligible = np.array([self.ages.get(int(i), 0) >= self.keep_apart_after for i in old_ids])
            moved = flow if flow is not None and flow.shape[:2] == regions.shape else None
            regions = kept_apart(regions, previous, eligible, self.keep_apart_share, moved, self.keep_apart_motion)
        return np.take(self._matched(regions, previous), regions)

    def assign(self, regions: np.ndarray, flow: np.ndarray | None = None) -> np.ndarray:
        """The persistent id of each region; the tracker moves on to this frame as ``update`` does.

        Args:
            regions: (H, W) int32, 0 = none and 1..R each present.
            flow: optional (H, W, 2) dense flow from this frame back to the one before, which moves the previous
                regions to this frame before they are matched (a looming or fast object overlaps too little of
                where it was to keep its id otherwise); None: matched where they were.

        Returns:
            (R + 1,) int32 table of ids, 0 for none.
        """
        return self._matched(regions, self._moved_previous(regions.shape, flow))

    def _moved_previous(self, shape: tuple[int, int], flow: np.ndarray | None) -> np.ndarray | None:
        """The previous frame's regions (0..P) at this frame: moved along ``flow`` when it fits; None when there
        are none of this ``shape``."""
        if self._previous is None or self._previous[0].shape != shape:
            return None
        previous, previous_ids = self._previous
        if flow is not None and flow.shape[:2] == shape and previous_ids.size < 2**16:
            return pulled_forward(previous.astype(np.uint16), flow, 0).astype(np.int32)
        return previous

    def _matched(self, regions: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
        """``assign``'s table, given the previous regions at this frame (``_moved_previous``)."""
        n_cur = int(regions.max(initial=0))
        ids = np.zeros(n_cur + 1, dtype=np.int32)
        if previous is not None and n_cur:
            previous_ids = self._previous[1]
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
