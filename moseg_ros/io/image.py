"""sensor_msgs/Image and CompressedImage <-> numpy, without cv_bridge and without rclpy.

Everything here works on any object carrying the sensor_msgs/Image fields (``header, height, width,
encoding, is_bigendian, step, data``): rclpy messages, rosbags messages, or a plain namespace. Decoding
returns a view of ``msg.data`` whenever the layout allows it (no row padding to drop, native byte order),
so the returned array may be read-only; copy it before writing into it.
"""

from __future__ import annotations

import array as pyarray
import dataclasses
import io
import re
from typing import Any

import cv2
import numpy as np
import PIL.Image

__all__ = [
    "ImageDecodeError",
    "encoding_layout",
    "image_to_array",
    "to_gray",
    "to_rgb",
    "compressed_to_array",
    "decode_image_bytes",
    "array_to_image_fields",
    "image_from_array",
]


class ImageDecodeError(ValueError):
    """An image message (or array) that cannot be turned into pixels: unsupported or inconsistent layout."""


# encoding -> (numpy dtype of one channel, channels), as in sensor_msgs/image_encodings.hpp.
_NAMED: dict[str, tuple[str, int]] = {
    "mono8": ("u1", 1), "mono16": ("u2", 1),
    "rgb8": ("u1", 3), "bgr8": ("u1", 3), "rgba8": ("u1", 4), "bgra8": ("u1", 4),
    "rgb16": ("u2", 3), "bgr16": ("u2", 3), "rgba16": ("u2", 4), "bgra16": ("u2", 4),
    "bayer_rggb8": ("u1", 1), "bayer_bggr8": ("u1", 1), "bayer_gbrg8": ("u1", 1), "bayer_grbg8": ("u1", 1),
    "bayer_rggb16": ("u2", 1), "bayer_bggr16": ("u2", 1), "bayer_gbrg16": ("u2", 1), "bayer_grbg16": ("u2", 1),
    # Packed 4:2:2, two bytes per pixel. ROS "yuv422" is UYVY byte order, "yuv422_yuy2" is YUYV.
    "yuv422": ("u1", 2), "uyvy": ("u1", 2), "yuv422_yuy2": ("u1", 2), "yuyv": ("u1", 2),
}
_CV_DEPTH = {"8U": "u1", "8S": "i1", "16U": "u2", "16S": "i2", "32S": "i4", "32F": "f4", "64F": "f8"}
_CV_PATTERN = re.compile(r"^(8U|8S|16U|16S|32S|32F|64F)C([1-4])$")

# ROS names a Bayer pattern by its top-left 2x2 block read row-wise; OpenCV names it by the block that
# starts at pixel (1, 1), hence the apparent swap (the same mapping image_proc uses).
_BAYER_TO_RGB = {
    "rggb": cv2.COLOR_BayerBG2RGB, "bggr": cv2.COLOR_BayerRG2RGB,
    "gbrg": cv2.COLOR_BayerGR2RGB, "grbg": cv2.COLOR_BayerGB2RGB,
}
_YUV_TO_RGB = {
    "yuv422": cv2.COLOR_YUV2RGB_UYVY, "uyvy": cv2.COLOR_YUV2RGB_UYVY,
    "yuv422_yuy2": cv2.COLOR_YUV2RGB_YUY2, "yuyv": cv2.COLOR_YUV2RGB_YUY2,
}


def encoding_layout(encoding: str) -> tuple[np.dtype, int]:
    """Return (little-endian channel dtype, channels) of a sensor_msgs encoding; ImageDecodeError if unknown."""
    if encoding in _NAMED:
        code, channels = _NAMED[encoding]
    elif match := _CV_PATTERN.match(encoding):
        code, channels = _CV_DEPTH[match.group(1)], int(match.group(2))
    else:
        supported = ", ".join(sorted(_NAMED)) + ", and <8U|8S|16U|16S|32S|32F|64F>C<1-4>"
        raise ImageDecodeError(f"unsupported encoding {encoding!r} (supported: {supported})")
    return np.dtype(code).newbyteorder("<"), channels


def _buffer(data: Any) -> np.ndarray:
    """Flat uint8 view of a message's ``data`` (bytes, array.array, memoryview, ndarray or list)."""
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    if isinstance(data, (list, tuple)):
        return np.asarray(data, dtype=np.uint8)
    return np.frombuffer(data, dtype=np.uint8)


def check_pixel_count(width: int, height: int, max_pixels: int | None, what: str) -> None:
    """Raise ImageDecodeError when a declared size exceeds ``max_pixels`` (None: no limit)."""
    if max_pixels is not None and width * height > max_pixels:
        raise ImageDecodeError(f"{what} declares {width}x{height} = {width * height} pixels, over the limit of "
                               f"{max_pixels} (parameter max_pixels)")


def image_to_array(msg: Any, max_pixels: int | None = None) -> np.ndarray:
    """Pixels of a sensor_msgs/Image in their own encoding.

    Returns an (H, W) array for one-channel encodings (mono, bayer, xxC1) and (H, W, C) otherwise (the
    4:2:2 YUV encodings give (H, W, 2) raw bytes), in the encoding's dtype and native byte order. Row
    padding (``step`` > W * bytes per pixel) is dropped by a strided view; a copy happens only to swap a
    big-endian buffer. A declared size over ``max_pixels`` is refused before the data is looked at.
    """
    dtype, channels = encoding_layout(msg.encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise ImageDecodeError(f"zero size image: {width}x{height} ({msg.encoding})")
    check_pixel_count(width, height, max_pixels, f"a {msg.encoding} image")
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes:
        raise ImageDecodeError(
            f"step {step} smaller than width*bytes_per_pixel = {width}*{channels * dtype.itemsize} = {row_bytes}"
            f" ({msg.encoding})")
    buf = _buffer(msg.data)
    if buf.size == 0:
        raise ImageDecodeError(f"empty data for a {width}x{height} {msg.encoding} image")
    if buf.size != step * height:
        raise ImageDecodeError(
            f"data length {buf.size} != step*height = {step}*{height} = {step * height} ({msg.encoding})")
    if msg.encoding in _YUV_TO_RGB and width % 2:
        raise ImageDecodeError(f"{msg.encoding} needs an even width, got {width}")
    rows = buf.reshape(height, step)[:, :row_bytes]
    wire = dtype.newbyteorder(">") if msg.is_bigendian else dtype
    pixels = rows.view(wire)
    if not pixels.dtype.isnative:
        pixels = pixels.astype(pixels.dtype.newbyteorder("="))
    shape = (height, width) if channels == 1 else (height, width, channels)
    return pixels.reshape(shape)


def _check_shape(array: np.ndarray, encoding: str) -> tuple[np.dtype, int]:
    dtype, channels = encoding_layout(encoding)
    if array.ndim == 2 and channels == 1:
        pass
    elif array.ndim == 3 and array.shape[2] == channels:
        pass
    else:
        raise ImageDecodeError(
            f"array of shape {array.shape} does not fit {encoding!r}: expected "
            f"{'(H, W) or ' if channels == 1 else ''}(H, W, {channels})")
    if array.dtype.kind != dtype.kind or array.dtype.itemsize != dtype.itemsize:
        raise ImageDecodeError(f"array dtype {array.dtype} does not fit {encoding!r} (needs {dtype.name})")
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise ImageDecodeError(f"zero size image: shape {array.shape}")
    return dtype, channels


def to_gray(array: np.ndarray, encoding: str) -> np.ndarray:
    """Convert pixels decoded by image_to_array to an (H, W) uint8 grey image.

    Colour uses OpenCV's BT.601 weights; Bayer is demosaiced first; 16-bit data keeps its high byte
    (value >> 8). Float and signed one-channel encodings are not images of light and are rejected.
    """
    _check_shape(array, encoding)
    if encoding in ("mono8", "8UC1"):
        return np.asarray(array)
    if encoding in ("mono16", "16UC1"):
        return (array >> 8).astype(np.uint8)
    if encoding == "8UC3":
        encoding = "bgr8"  # OpenCV's own convention for an untyped 3-channel image
    if encoding in ("rgb8", "bgr8", "rgba8", "bgra8"):
        code = {"rgb8": cv2.COLOR_RGB2GRAY, "bgr8": cv2.COLOR_BGR2GRAY,
                "rgba8": cv2.COLOR_RGBA2GRAY, "bgra8": cv2.COLOR_BGRA2GRAY}[encoding]
        return cv2.cvtColor(np.ascontiguousarray(array), code)
    if encoding.startswith("bayer_") or encoding in _YUV_TO_RGB or encoding in ("rgb16", "bgr16", "rgba16", "bgra16"):
        return cv2.cvtColor(to_rgb(array, encoding), cv2.COLOR_RGB2GRAY)
    raise ImageDecodeError(f"cannot convert {encoding!r} to grey (not an intensity image)")


def to_rgb(array: np.ndarray, encoding: str) -> np.ndarray:
    """Convert pixels decoded by image_to_array to an (H, W, 3) uint8 RGB image (see to_gray for the rules)."""
    _check_shape(array, encoding)
    if encoding in ("rgb16", "bgr16", "rgba16", "bgra16"):
        array, encoding = (array >> 8).astype(np.uint8), encoding[:-2] + "8"
    if encoding == "8UC3":
        encoding = "bgr8"
    if encoding == "rgb8":
        return np.asarray(array)
    if encoding in ("bgr8", "rgba8", "bgra8"):
        code = {"bgr8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB, "bgra8": cv2.COLOR_BGRA2RGB}[encoding]
        return cv2.cvtColor(np.ascontiguousarray(array), code)
    if encoding.startswith("bayer_"):
        raw = np.ascontiguousarray(array)
        if raw.dtype != np.uint8:
            raw = (raw >> 8).astype(np.uint8)
        return cv2.cvtColor(raw, _BAYER_TO_RGB[encoding[6:10]])
    if encoding in _YUV_TO_RGB:
        return cv2.cvtColor(np.ascontiguousarray(array), _YUV_TO_RGB[encoding])
    if encoding in ("mono8", "8UC1", "mono16", "16UC1"):
        return cv2.cvtColor(to_gray(array, encoding), cv2.COLOR_GRAY2RGB)
    raise ImageDecodeError(f"cannot convert {encoding!r} to RGB (not a colour or intensity image)")


_HEADER_ERRORS = (PIL.UnidentifiedImageError, OSError, ValueError, PIL.Image.DecompressionBombError)


def compressed_size(buf: np.ndarray) -> tuple[int, int]:
    """(width, height) from a compressed image's header, without decoding its pixels.

    Pillow reads only the header on open (its decoding is lazy), so a decompression bomb costs nothing here.
    """
    try:
        with PIL.Image.open(io.BytesIO(buf.tobytes())) as header:
            return header.size
    except _HEADER_ERRORS as error:
        raise ImageDecodeError(f"cannot read the image header: {error}") from None


def declared_size(msg: Any) -> tuple[int, int] | None:
    """(H, W) an Image or CompressedImage message declares (a compressed one's header, pixels not decoded);
    None when a compressed header cannot be read."""
    if not hasattr(msg, "format"):
        return (msg.height, msg.width)
    try:
        width, height = compressed_size(_buffer(msg.data))
    except ImageDecodeError:
        return None
    return (height, width)


def _pillow_pixels(image: PIL.Image.Image) -> np.ndarray:
    """Pixels of a loaded Pillow image: (H, W) uint8 or uint16 for grey modes, (H, W, 3) uint8 RGB otherwise."""
    if image.mode in ("I", "I;16", "I;16B", "I;16L", "I;16N"):
        return np.clip(np.asarray(image), 0, 65535).astype(np.uint16)
    if image.mode == "F":
        raise ImageDecodeError("floating-point compressed images are not supported")
    if image.mode in ("1", "L", "LA"):
        return np.asarray(image.convert("L"))
    return np.asarray(image.convert("RGB"))


def compressed_to_array(msg: Any, max_pixels: int | None = None) -> np.ndarray:
    """Decode a sensor_msgs/CompressedImage to (H, W, 3) uint8 RGB, or (H, W) uint8 for a grey image.

    The ``format`` string ("jpeg", "png", "rgb8; jpeg compressed bgr8", ...) is only checked for a known
    codec; the codec itself is read from the bytes. 16-bit grey PNGs are returned as uint16. With
    ``max_pixels``, the size in the header is checked first and a larger image is refused undecoded.
    Pillow decodes (not cv2.imdecode) because libjpeg and libpng print every recoverable defect of a
    damaged stream straight to stderr from inside OpenCV, which a stream of bad frames turns into a flood;
    Pillow reports a truncated stream as an error, here an :class:`ImageDecodeError`.
    """
    fmt = str(msg.format).lower()
    if fmt and not any(codec in fmt for codec in ("jpeg", "jpg", "png", "tiff", "bmp", "webp")):
        raise ImageDecodeError(f"unsupported CompressedImage format {msg.format!r}")
    buf = _buffer(msg.data)
    if buf.size == 0:
        raise ImageDecodeError(f"empty data in a CompressedImage ({msg.format!r})")
    return decode_image_bytes(buf.tobytes(), f"a {msg.format!r} CompressedImage", max_pixels)


def decode_image_bytes(data: bytes, what: str, max_pixels: int | None = None) -> np.ndarray:
    """Decode an encoded image (JPEG, PNG, ...: the codec is read from the bytes) as ``compressed_to_array``
    does; ``what`` names it in the errors (ImageDecodeError, a truncated stream among them)."""
    try:
        with PIL.Image.open(io.BytesIO(data)) as image:
            if max_pixels is not None:
                check_pixel_count(*image.size, max_pixels, what)
            image.load()
            return _pillow_pixels(image)
    except ImageDecodeError:
        raise
    except Exception as error:  # Pillow's codec plug-ins raise OSError, EOFError, SyntaxError... on bad streams
        raise ImageDecodeError(f"could not decode {len(data)} bytes of {what}: {error}") from None


def array_to_image_fields(array: np.ndarray, encoding: str) -> dict[str, Any]:
    """sensor_msgs/Image fields for an array: height, width, encoding, is_bigendian (0), step, data.

    ``array`` must be (H, W) or (H, W, C) with the encoding's channel count and a dtype of the encoding's
    kind and size; ``data`` is a flat little-endian np.uint8 array (a view when already contiguous).
    """
    array = np.asarray(array)
    dtype, channels = _check_shape(array, encoding)
    little = np.ascontiguousarray(array, dtype=dtype)
    height, width = array.shape[:2]
    return {
        "height": int(height), "width": int(width), "encoding": encoding, "is_bigendian": 0,
        "step": int(width * channels * dtype.itemsize), "data": little.reshape(-1).view(np.uint8),
    }


def image_from_array(msg_cls: type, array: np.ndarray, encoding: str, header: Any) -> Any:
    """Build a ``msg_cls`` (rclpy's or rosbags' sensor_msgs/Image class) holding ``array``.

    rosbags message classes (dataclasses) take the np.uint8 data as is; rclpy messages get an
    array.array('B') filled from the buffer in one copy, which rclpy's setter accepts without its
    per-element check.
    """
    fields = array_to_image_fields(array, encoding)
    if dataclasses.is_dataclass(msg_cls):
        return msg_cls(header=header, **fields)
    data = pyarray.array("B")
    data.frombytes(fields.pop("data"))
    msg = msg_cls(header=header, **fields)
    msg.data = data
    return msg
