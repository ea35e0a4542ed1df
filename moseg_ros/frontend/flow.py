"""Dense optical flow between two grey frames (OpenCV DIS)."""

from __future__ import annotations

import cv2
import numpy as np

# name: (OpenCV's preset, variational refinement iterations per scale instead of the preset's, or None).
# balanced is medium's resolution with 2 refinement iterations instead of 5: less time, and the evaluations
# close to medium's (docs/experiments.md, ``flow_preset``).
DIS_PRESETS = {
    "ultrafast": (cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, None),
    "fast": (cv2.DISOPTICAL_FLOW_PRESET_FAST, None),
    "balanced": (cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, 2),
    "medium": (cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, None),
}


class DenseFlow:
    """Dense inverse search flow (Kroeger et al. 2016) with a named speed/quality preset.

    The presets trade time for detail: fast stops at a quarter of the image's size, balanced and medium at
    half, balanced with fewer rounds of variational refinement (their costs are in docs/experiments.md).
    """

    def __init__(self, preset: str = "fast") -> None:
        if preset not in DIS_PRESETS:
            raise ValueError(f"unknown flow preset {preset!r}; choose one of {sorted(DIS_PRESETS)}")
        self.preset = preset
        base, refinement = DIS_PRESETS[preset]
        self._dis = cv2.DISOpticalFlow_create(base)
        if refinement is not None:
            self._dis.setVariationalRefinementIterations(refinement)

    def __call__(self, source: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Flow from ``source`` to ``target``: pixel x of source moves to x + flow[y, x] in target.

        Args:
            source: (H, W) uint8 grey frame.
            target: (H, W) uint8 grey frame of the same size.

        Returns:
            (H, W, 2) float32 flow (u, v) in pixels.
        """
        if source.shape != target.shape or source.ndim != 2:
            raise ValueError(f"flow needs two grey frames of one size, got {source.shape} and {target.shape}")
        return self._dis.calc(source, target, None)
