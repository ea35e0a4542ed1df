"""How the published instances follow the true moving objects, frame after frame.

In each scored frame a true object's instance is the published instance holding most of its samples (pixels, or
labelled points), if that holds at least ``INSTANCE_SHARE`` of them. Its instance changing id from one frame to the
next where it has one is an id switch (MOT's identity switch, without the gaps: an object that loses its instance
for a frame and gets the same id back has not switched); a frame in which its instance is also another true
object's is shared (two movers published as one instance); a frame in which two or more instances each hold
``INSTANCE_SHARE`` of it is split (one mover published as two).
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from moseg_ros.frontend.instances import compact_ids

# A true object's instance holds at least this share of its samples: a sliver of a neighbour's margin is not it.
INSTANCE_SHARE = 0.2


def instance_holdings(published: np.ndarray, truth: np.ndarray, objects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of the (K,) ``objects`` (ids of ``truth``): the id of ``published`` (same shape as ``truth``; 0 or
    below none) that holds most of its samples, 0 where none holds ``INSTANCE_SHARE`` of them, and how many
    instances hold that share of it; two (K,) int64 arrays."""
    if objects.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    ids, compact = compact_ids(published)
    row = np.searchsorted(objects, truth.ravel())
    mine = (row < objects.size) & (objects[np.minimum(row, objects.size - 1)] == truth.ravel())
    counts = np.zeros((objects.size, ids.size), dtype=np.int64)
    np.add.at(counts, (row[mine], compact.ravel()[mine]), 1)
    strong = counts[:, 1:] >= INSTANCE_SHARE * np.maximum(counts.sum(axis=1, keepdims=True), 1)
    if ids.size == 1:
        return np.zeros(objects.size, dtype=np.int64), np.zeros(objects.size, dtype=np.int64)
    best = counts[:, 1:].argmax(axis=1)
    held = np.where(strong[np.arange(objects.size), best], ids[best + 1], 0)
    return held.astype(np.int64), strong.sum(axis=1).astype(np.int64)


class InstanceFollow:
    """Counts, per true object, the id switches, the shared frames and the split frames of its published instance
    (the module's docstring), one frame at a time; ``switches``, ``shared`` and ``split`` are Counters by object
    id."""

    def __init__(self) -> None:
        self.switches: Counter[int] = Counter()
        self.shared: Counter[int] = Counter()
        self.split: Counter[int] = Counter()
        self._last: dict[int, int] = {}

    def add(self, published: np.ndarray, truth: np.ndarray, objects: np.ndarray) -> None:
        """One scored frame: ``published`` instance ids and ``truth`` object ids of the same samples (any equal
        shapes), and the (K,) sorted ids of the true objects to follow (the moving ones seen enough)."""
        held, parts = instance_holdings(published, truth, objects)
        holders = Counter(held[held > 0].tolist())
        for obj, instance, count in zip(objects.tolist(), held.tolist(), parts.tolist()):
            self.split[obj] += int(count >= 2)
            if instance == 0:
                continue
            self.switches[obj] += int(self._last.get(obj, instance) != instance)
            self.shared[obj] += int(holders[instance] > 1)
            self._last[obj] = instance
