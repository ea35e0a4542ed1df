"""Decisions -> masks: the three published masks and the debug overlay."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from moseg_ros.core.baseline import DENSE_IDS


@dataclass
class Masks:
    """The masks published for one frame, all (H, W) at the input image's size.

    Attributes:
        dynamic: uint8, 255 = independently moving (ignore), 0 = usable (OpenVINS / Isaac ROS polarity).
        static: uint8, 255 = usable, 0 = moving (OpenCV / stella_vslam / VINS feature-mask polarity).
        instance_labels: int32, 0 = static or background, j > 0 = id of a moving instance.
    """

    dynamic: np.ndarray
    static: np.ndarray
    instance_labels: np.ndarray


def render_masks(instances: np.ndarray, dynamic_ids: np.ndarray, size: tuple[int, int],
                 margin_px: int = 0) -> Masks:
    """Paint the dynamic instances, grow them by a safety margin and scale to the image size.

    Args:
        instances: (h, w) int32 instance ids at the working resolution.
        dynamic_ids: (D,) ids of the instances judged to move by themselves.
        size: (H, W) of the input image.
        margin_px: dilation in output pixels, so features on an object's rim are dropped too; where two ids
            grow into the same pixel the larger one wins.

    Returns:
        The masks at (H, W).
    """
    height, width = size
    ids = np.unique(dynamic_ids[(dynamic_ids > 0) & (dynamic_ids <= instances.max(initial=0))])
    # Each dynamic id becomes its rank (1..D, in the order of the ids) in the smallest type that holds D:
    # resizing and dilating uint8 is several times faster than int32 / float32 ids at the output size, and the
    # order kept makes the dilation's maximum the same id.
    ranked = _ranks(instances, ids, _rank_type(ids.size))
    if ranked.shape != (height, width):
        ranked = cv2.resize(ranked, (width, height), interpolation=cv2.INTER_NEAREST)
    if margin_px > 0 and ids.size:
        ranked = _grown(ranked, margin_px)
    # 255 where moving; against an array, not the scalar 0, which OpenCV misreads for 1xN images.
    dynamic = cv2.compare(ranked, np.zeros_like(ranked), cv2.CMP_GT)
    labels = _ids_of_ranks(ranked, np.concatenate([[0], ids]).astype(np.int32))
    return Masks(dynamic=dynamic, static=255 - dynamic, instance_labels=labels)


def _ranks(instances: np.ndarray, ids: np.ndarray, dtype: type) -> np.ndarray:
    """(h, w) each pixel's rank among the sorted positive ``ids`` (1..D) as ``dtype``, 0 where its id is none of
    them (ids <= 0 included). Ids up to ``DENSE_IDS`` index a table; larger ones (an upstream segmenter's
    hashes) are searched, rather than a table of every id up to them."""
    if ids.size == 0:
        return np.zeros(instances.shape, dtype=dtype)
    if ids[-1] <= DENSE_IDS:
        ranks = np.zeros(int(ids[-1]) + 2, dtype=dtype)  # the last entry stands for every id beyond the table
        ranks[ids] = np.arange(1, ids.size + 1)
        return np.take(ranks, instances, mode="clip")  # a negative id clips to entry 0: none
    position = np.searchsorted(ids, instances)
    found = ids[np.minimum(position, ids.size - 1)] == instances
    return np.where(found, position + 1, 0).astype(dtype)


def _rank_type(count: int) -> type:
    """The smallest type OpenCV resizes and dilates that holds ranks 0..count: uint8, uint16, else float32
    (exact below 2**24, more than the pixels of any working image)."""
    return np.uint8 if count < 2 ** 8 else np.uint16 if count < 2 ** 16 else np.float32


def _ids_of_ranks(ranked: np.ndarray, table: np.ndarray) -> np.ndarray:
    """(H, W) int32 ``table[ranked]``: OpenCV's lookup table for uint8 ranks (several times faster than NumPy's
    indexing at the output size), NumPy's indexing for wider ones."""
    if ranked.dtype == np.uint8:
        return cv2.LUT(ranked, np.pad(table, (0, 256 - table.size)))
    return np.take(table, ranked if ranked.dtype.kind == "u" else ranked.astype(np.int64))


def _grown(labels: np.ndarray, margin_px: int) -> np.ndarray:
    """``labels`` (ranks) with every label dilated by ``margin_px`` into the background around it.

    Only the bounding box of the labelled pixels, widened by the margin, can change, so only it is dilated
    (the masks of a frame are usually a small part of it)."""
    x, y, w, h = cv2.boundingRect((labels > 0).view(np.uint8))
    rows = slice(max(y - margin_px, 0), y + h + margin_px)
    cols = slice(max(x - margin_px, 0), x + w + margin_px)
    box = labels[rows, cols]
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
    labels = labels.copy()
    labels[rows, cols] = np.where(box > 0, box, cv2.dilate(box, kernel))
    return labels


def debug_overlay(rgb: np.ndarray, masks: Masks, alpha: float = 0.5) -> np.ndarray:
    """Tint moving instances on the image, one colour per id, with their outlines.

    Args:
        rgb: (H, W, 3) uint8 image.
        masks: the frame's masks.

    Returns:
        (H, W, 3) uint8 overlay.
    """
    labels = masks.instance_labels
    golden = (labels.astype(np.int64) * 47) % 180
    hsv = np.stack([golden, np.full_like(golden, 255), np.full_like(golden, 255)], axis=-1).astype(np.uint8)
    colours = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    moving = labels > 0
    out = rgb.copy()
    out[moving] = ((1 - alpha) * rgb[moving] + alpha * colours[moving]).astype(np.uint8)
    edges = cv2.morphologyEx(masks.dynamic, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    out[edges] = (255, 255, 0)
    return out
