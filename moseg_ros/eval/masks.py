"""Score published dynamic masks against ground-truth masks, frame by frame, paired by exact stamp."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from moseg_ros.io.bags import iter_messages, stamp_to_ns
from moseg_ros.io.image import image_to_array

GT_DYNAMIC_TOPIC = "/gt/dynamic_mask"


def mask_iou(predicted: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two boolean masks; 1.0 when both are empty (nothing to find, nothing found)."""
    if predicted.shape != truth.shape:
        raise ValueError(f"mask shapes differ: {predicted.shape} vs {truth.shape}")
    union = np.count_nonzero(predicted | truth)
    return 1.0 if union == 0 else np.count_nonzero(predicted & truth) / union


@dataclass
class MaskScore:
    """Per-frame agreement of predicted and true dynamic masks.

    Attributes:
        stamps: (N,) stamps (ns) scored, in time order.
        iou: (N,) IoU per frame (frames where both masks are empty count as 1.0).
        recall: (N,) share of true moving pixels flagged (NaN where nothing moves).
        false_positive_rate: (N,) share of truly static pixels flagged.
        unmatched: ground-truth stamps with no predicted mask.
    """

    stamps: np.ndarray
    iou: np.ndarray
    recall: np.ndarray
    false_positive_rate: np.ndarray
    unmatched: list[int]

    def summary(self) -> dict[str, float | int]:
        """Means over the scored frames (IoU and recall over frames where something truly moves)."""
        moving = ~np.isnan(self.recall)
        return {
            "frames_scored": int(self.stamps.size),
            "iou_mean": float(np.mean(self.iou[moving])) if moving.any() else float("nan"),
            "iou_mean_all_frames": float(np.mean(self.iou)) if self.iou.size else float("nan"),
            "recall_mean": float(np.nanmean(self.recall)) if moving.any() else float("nan"),
            "false_positive_rate_mean": float(np.mean(self.false_positive_rate)) if self.iou.size else float("nan"),
            "frames_unmatched": len(self.unmatched),
        }


def masks_by_stamp(bag: str | Path, topic: str) -> dict[int, np.ndarray]:
    """Every mask on ``topic`` of ``bag`` as (H, W) bool (non-zero = set), keyed by header stamp (ns)."""
    return {stamp_to_ns(msg.header.stamp): image_to_array(msg) > 0 for _, _, msg in iter_messages(bag, [topic])}


def score_bags(truth_bag: str | Path, predicted_bag: str | Path, predicted_topic: str,
               truth_topic: str = GT_DYNAMIC_TOPIC) -> MaskScore:
    """Pair ground-truth and predicted masks by header stamp and score every pair.

    Args:
        truth_bag: bag holding ``truth_topic`` (mono8, non-zero = moving).
        predicted_bag: bag holding ``predicted_topic`` (mono8, 255 = moving).
    """
    truth = masks_by_stamp(truth_bag, truth_topic)
    predicted = masks_by_stamp(predicted_bag, predicted_topic)
    stamps = sorted(s for s in truth if s in predicted)
    iou, recall, fpr = [], [], []
    for stamp in stamps:
        t, p = truth[stamp], predicted[stamp]
        iou.append(mask_iou(p, t))
        recall.append(np.count_nonzero(p & t) / np.count_nonzero(t) if t.any() else np.nan)
        fpr.append(np.count_nonzero(p & ~t) / max(np.count_nonzero(~t), 1))
    return MaskScore(np.array(stamps, dtype=np.int64), np.array(iou), np.array(recall), np.array(fpr),
                     sorted(s for s in truth if s not in predicted))
