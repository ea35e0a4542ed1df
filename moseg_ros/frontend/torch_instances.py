"""A user's TorchScript instance-segmentation model as the instance source (torch is imported only here).

Conventions (what the model must accept and return):

- input: one float32 tensor (1, 3, H, W), RGB, values in [0, 1], on the model's device (CUDA when available,
  else CPU), at the frame's size;
- output: either (H, W) or (1, H, W) integer instance ids (0 = no object), or (N, H, W) / (1, N, H, W) float
  per-instance masks or probabilities (a pixel belongs to the instance of highest value above 0.5). Another
  output size is resized to the frame's (nearest neighbour).

The ids a model gives are not stable over time, so its maps pass through the same InstanceTracker as the
built-in regions before the method sees them.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from moseg_ros.frontend.instances import InstanceTracker, compact_ids


def masks_to_ids(output: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """(H, W) int32 ids from a model's output: an id map as is, per-instance masks by their arg-max.

    Args:
        output: (H, W) ids, or (N, H, W) per-instance scores (leading 1-sized dimensions are dropped).
        threshold: a pixel whose best score is not above it belongs to no instance.
    """
    output = np.asarray(output)
    if output.ndim == 4 and output.shape[0] == 1:  # (1, N, H, W): a batch of one
        output = output[0]
    if np.issubdtype(output.dtype, np.integer) or output.dtype == bool:
        if output.ndim == 3 and output.shape[0] == 1:
            output = output[0]
        if output.ndim == 2:
            return output.astype(np.int32)
    if output.ndim != 3:
        raise ValueError(f"instance model output must be (H, W) ids or (N, H, W) masks, got {output.shape}")
    if output.shape[0] == 0:
        return np.zeros(output.shape[1:], dtype=np.int32)
    best = output.argmax(axis=0)
    return np.where(output.max(axis=0) > threshold, best + 1, 0).astype(np.int32)


class TorchScriptInstances:
    """Runs a TorchScript model on each frame and gives its instances ids that persist over time."""

    def __init__(self, path: str | Path) -> None:
        import torch  # only for users who give a model

        if not Path(path).is_file():
            raise ValueError(f"instance_model {str(path)!r} is not a file")
        self._torch = torch
        self.device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
        self._model = torch.jit.load(str(path), map_location=self.device).eval()
        self._tracker = InstanceTracker()

    def reset(self) -> None:
        """Forget the instance ids (a new stream)."""
        self._tracker.reset()

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        """(H, W) int32 persistent instance ids of one (H, W, 3) uint8 RGB frame (grey frames are repeated)."""
        if rgb.ndim == 2:
            rgb = np.repeat(rgb[..., None], 3, axis=2)
        tensor = self._torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1))).to(self.device)
        with self._torch.inference_mode():
            output = self._model(tensor[None].float() / 255.0)
        ids = masks_to_ids(output.detach().cpu().numpy())
        if ids.shape != rgb.shape[:2]:
            ids = cv2.resize(ids, rgb.shape[1::-1], interpolation=cv2.INTER_NEAREST)
        return self._tracker.update(compact_ids(ids)[1])
