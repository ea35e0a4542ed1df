"""One decoded camera frame from any supported image message: the pipeline's input format."""

from __future__ import annotations

from typing import Any

import numpy as np

from moseg_ros.io.image import ImageDecodeError, compressed_to_array, image_to_array, to_gray, to_rgb

GREY_ENCODINGS = frozenset({"mono8", "mono16", "8UC1", "16UC1"})


def decode_frame(msg: Any, max_pixels: int | None = None) -> np.ndarray:
    """Decode a sensor_msgs/Image or CompressedImage into the pipeline's frame.

    Grey encodings give (H, W) uint8; colour, Bayer and YUV give (H, W, 3) uint8 RGB. Raises
    ImageDecodeError (a ValueError) with the reason for anything that is not a usable camera image, and for
    an image whose declared size (raw: height x width; compressed: the header's) exceeds ``max_pixels``.
    """
    if hasattr(msg, "format"):
        return eight_bit(compressed_to_array(msg, max_pixels))
    pixels = image_to_array(msg, max_pixels)
    if msg.encoding in GREY_ENCODINGS:
        return to_gray(pixels, msg.encoding)
    return to_rgb(pixels, msg.encoding)


def eight_bit(pixels: np.ndarray) -> np.ndarray:
    """A decoded image (``compressed_to_array``'s) as the pipeline's frame: 16-bit grey keeps its high byte."""
    return (pixels >> 8).astype(np.uint8) if pixels.dtype == np.uint16 else pixels


def decode_instances(msg: Any) -> np.ndarray:
    """Decode an instance-id image (32SC1 or 16UC1, 0 = no object) into (H, W) int32 ids."""
    if msg.encoding not in ("32SC1", "16UC1", "mono16", "8UC1", "mono8"):
        raise ImageDecodeError(f"instance images must be 32SC1 or 16UC1 ids, got {msg.encoding!r}")
    ids = image_to_array(msg)
    if ids.ndim != 2:
        raise ImageDecodeError(f"instance images must have one channel, got shape {ids.shape}")
    return ids.astype(np.int32)


def camera_matrix(k: Any) -> np.ndarray | None:
    """(3, 3) float64 K from a CameraInfo's nine ``k`` values, or None when they are no camera (a zero or
    non-finite focal length: an uncalibrated driver's placeholder)."""
    K = np.asarray(k, dtype=np.float64).reshape(3, 3)
    return K if K[0, 0] > 0 and K[1, 1] > 0 and bool(np.isfinite(K).all()) else None
