"""Upstream instances as the objects: which of them move, judged by the regions the method finds without them.

An instance moves when ``min_fraction`` of its pixels lie in the regions the method would publish alone (its
regions grown by the published margin, ``published_regions``) and, once flagged, while ``hold_fraction`` of them
still do (``InstanceDecisions``: a hysteresis per instance, followed by its overlap from frame to frame).
``with_unknown_regions`` publishes the method's own regions that lie mostly outside every instance beside them.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core.baseline import MIN_INSTANCE_PIXELS, instance_shares
from moseg_ros.frontend.instances import InstanceTracker, compact_ids
from moseg_ros.params import setting


@dataclass(frozen=True)
class InstanceSettings:
    """How upstream instances are judged by the method's regions."""

    instance_min_fraction: float = setting(0.4, "with instances: share of an instance's pixels in the regions the "
                                           "method would publish without instances (margin included) that flags "
                                           "it", low=0.01, high=1.0)
    instance_hold_fraction: float = setting(0.1, "with instances: a flagged instance stays flagged while this share "
                                            "of it lies in those regions (each instance followed by its overlap; at "
                                            "or above instance_min_fraction: no hold)", low=0.0, high=1.0)
    instance_unknown_regions: bool = setting(True, "with instances: also publish the method's own regions that lie "
                                             "mostly outside every instance (movers the instance source does not "
                                             "know), with ids from 2**30 up")


def published_regions(labels: np.ndarray, shape: tuple[int, int], margin_px: int) -> np.ndarray:
    """(H, W) bool: the pixels of ``labels`` > 0 ((h, w) regions) at ``shape``, grown by ``margin_px`` (an
    ellipse, as the published masks are grown): what the method publishes without instances."""
    regions = (labels > 0).astype(np.uint8)
    if regions.shape != shape:
        regions = cv2.resize(regions, shape[::-1], interpolation=cv2.INTER_NEAREST)
    if margin_px > 0:
        regions = cv2.dilate(regions, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2))
    return regions > 0


# The ids of the method's own regions published beside upstream instances start here, far above a segmenter's
# numbering (with_unknown_regions), so that a region keeps the id its tracker gave it from frame to frame.
OWN_REGION_BASE = 2 ** 30


def with_unknown_regions(instances: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (H, W) ``instances`` with the method's own regions (``labels`` (h, w) > 0, its tracked region ids at its
    own size) that lie mostly outside every instance painted where no instance is, as ``OWN_REGION_BASE`` + their
    id (above the frame's largest instance id when a segmenter's ids reach that far; the smallest ids no instance
    has when they reach the top of int32); returns the map (int32) and the (R,) int32 ids painted. These are
    movers the instance source does not know (a class its model never learned, an object it missed); a region
    that lies mostly on instances is theirs to decide."""
    if labels.shape != instances.shape:
        labels = cv2.resize(labels, instances.shape[::-1], interpolation=cv2.INTER_NEAREST)
    count = int(labels.max(initial=0)) + 1
    on_instances = np.bincount(labels[instances > 0], minlength=count)
    area = np.bincount(labels.ravel(), minlength=count)
    outside = (area > 0) & (2 * on_instances < area)
    outside[0] = False
    if not outside.any():
        return instances, np.zeros(0, dtype=np.int32)
    own_ids = max(OWN_REGION_BASE, int(instances.max(initial=0)) + 1) + np.arange(count, dtype=np.int64)
    if own_ids[-1] > np.iinfo(np.int32).max:  # a segmenter's ids reach the top of int32: the smallest free ones
        taken = np.unique(instances)
        own_ids = np.zeros(count, dtype=np.int64)
        own_ids[outside] = np.setdiff1d(np.arange(1, taken.size + count + 1), taken)[:int(outside.sum())]
    painted = outside[labels] & (instances <= 0)
    combined = instances.astype(np.int32, copy=True)
    combined[painted] = own_ids[labels[painted]]
    shown = np.bincount(labels[painted], minlength=count) > 0
    return combined, own_ids[shown].astype(np.int32)


def held_instances(instances: np.ndarray, regions: np.ndarray, held: np.ndarray, min_fraction: float,
                   hold_fraction: float) -> np.ndarray:
    """(D,) int32 sorted ids of the (H, W) ``instances`` with ``min_fraction`` of their pixels in ``regions``
    ((H, W) bool), and of the ``held`` ids (flagged the frame before) with ``hold_fraction`` of them there: a
    hysteresis per id, as Canny's on edges (0: a held id stays while it is seen, ``MIN_INSTANCE_PIXELS`` or more)."""
    ids, share, pixels = instance_shares(instances, regions, np.ones(instances.shape, dtype=bool))
    seen = pixels >= MIN_INSTANCE_PIXELS
    return ids[seen & ((share >= min_fraction) | ((share >= hold_fraction) & np.isin(ids, held)))]


class InstanceDecisions:
    """Which upstream instances move, frame after frame: ``min_fraction`` of an instance in the method's regions
    flags it, and a flagged instance stays flagged while ``hold_fraction`` of it remains there (``held_instances``).
    The hold follows each instance by its overlap with the frame before (InstanceTracker), not by its id: a
    segmenter that numbers its instances afresh every frame would hand a held id to another object."""

    def __init__(self, min_fraction: float, hold_fraction: float) -> None:
        self.min_fraction = min_fraction
        self.hold_fraction = hold_fraction
        self._identities = InstanceTracker()
        self.reset()

    def reset(self) -> None:
        """Forget every instance and its flag (a new stream)."""
        self._identities.reset()
        self._held = np.zeros(0, dtype=np.int32)  # the identities flagged the frame before

    def update(self, instances: np.ndarray, regions: np.ndarray) -> np.ndarray:
        """(D,) int32 sorted ids of the (H, W) ``instances`` (0 or below: none) that move, given the frame's
        (H, W) bool ``regions``."""
        ids, compact = compact_ids(instances)
        identity = self._identities.assign(compact)  # of each number of ``compact``
        held = np.flatnonzero(np.isin(identity, self._held))
        moving = held_instances(compact, regions, held, self.min_fraction, self.hold_fraction)
        self._held = identity[moving]
        return ids[moving].astype(np.int32)
