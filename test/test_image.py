"""Tests of moseg_ros.io.image: every encoding round-trips, bad inputs raise, colour conversions are right."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from moseg_ros.io.image import (
    ImageDecodeError,
    array_to_image_fields,
    compressed_to_array,
    declared_size,
    image_from_array,
    image_to_array,
    to_gray,
    to_rgb,
)

RNG = np.random.default_rng(7)
H, W = 5, 6

ENCODINGS = {  # encoding -> (dtype, channels)
    "mono8": (np.uint8, 1), "mono16": (np.uint16, 1), "rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3),
    "rgba8": (np.uint8, 4), "bgra8": (np.uint8, 4), "rgb16": (np.uint16, 3), "8UC1": (np.uint8, 1),
    "8UC3": (np.uint8, 3), "16UC1": (np.uint16, 1), "16SC1": (np.int16, 1), "32SC1": (np.int32, 1),
    "32FC1": (np.float32, 1), "64FC1": (np.float64, 1), "32FC3": (np.float32, 3),
    "bayer_rggb8": (np.uint8, 1), "bayer_bggr8": (np.uint8, 1), "bayer_gbrg8": (np.uint8, 1),
    "bayer_grbg8": (np.uint8, 1), "bayer_rggb16": (np.uint16, 1), "yuv422": (np.uint8, 2),
    "yuv422_yuy2": (np.uint8, 2),
}


def random_image(encoding: str, height: int = H, width: int = W) -> np.ndarray:
    dtype, channels = ENCODINGS[encoding]
    shape = (height, width) if channels == 1 else (height, width, channels)
    if np.issubdtype(dtype, np.floating):
        return RNG.normal(size=shape).astype(dtype)
    info = np.iinfo(dtype)
    return RNG.integers(info.min, info.max, size=shape, endpoint=True).astype(dtype)


def as_msg(fields: dict, **overrides) -> SimpleNamespace:
    return SimpleNamespace(header=None, **{**fields, **overrides})


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_round_trip_every_encoding(encoding: str) -> None:
    image = random_image(encoding)
    fields = array_to_image_fields(image, encoding)
    assert fields["data"].dtype == np.uint8 and fields["is_bigendian"] == 0
    assert fields["step"] == W * image.itemsize * (1 if image.ndim == 2 else image.shape[2])
    decoded = image_to_array(as_msg(fields))
    assert decoded.dtype == image.dtype and decoded.shape == image.shape
    np.testing.assert_array_equal(decoded, image)


@pytest.mark.parametrize("encoding", ["mono8", "rgb8", "16UC1", "32FC1", "bgra8"])
def test_step_padding_is_dropped_without_copy(encoding: str) -> None:
    image = random_image(encoding)
    fields = array_to_image_fields(image, encoding)
    pad = 7
    rows = fields["data"].reshape(H, fields["step"])
    padded = np.concatenate([rows, np.full((H, pad), 0xAB, np.uint8)], axis=1)
    msg = as_msg(fields, step=fields["step"] + pad, data=padded.tobytes())
    decoded = image_to_array(msg)
    np.testing.assert_array_equal(decoded, image)
    assert np.shares_memory(decoded, np.frombuffer(msg.data, np.uint8))


@pytest.mark.parametrize("encoding", ["mono16", "16UC1", "32SC1", "32FC1", "rgb16"])
def test_big_endian_is_swapped(encoding: str) -> None:
    image = random_image(encoding)
    fields = array_to_image_fields(image, encoding)
    msg = as_msg(fields, is_bigendian=1, data=image.astype(image.dtype.newbyteorder(">")).tobytes())
    decoded = image_to_array(msg)
    assert decoded.dtype.isnative
    np.testing.assert_array_equal(decoded, image)
    # The same bytes read as little-endian are different numbers: the flag really matters.
    assert not np.array_equal(image_to_array(as_msg(fields, is_bigendian=0, data=msg.data)), image)


def test_rosbags_image_class_round_trip_through_cdr() -> None:
    typestore = get_typestore(Stores.ROS2_JAZZY)
    types = typestore.types
    header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=3, nanosec=4),
                                          frame_id="cam")
    image = random_image("mono16")
    msg = image_from_array(types["sensor_msgs/msg/Image"], image, "mono16", header)
    back = typestore.deserialize_cdr(typestore.serialize_cdr(msg, "sensor_msgs/msg/Image"), "sensor_msgs/msg/Image")
    np.testing.assert_array_equal(image_to_array(back), image)
    assert back.header.frame_id == "cam" and back.header.stamp.nanosec == 4


def test_rclpy_image_class_round_trip() -> None:
    sensor_msgs = pytest.importorskip("sensor_msgs.msg", reason="rclpy's sensor_msgs not importable")
    std_msgs = pytest.importorskip("std_msgs.msg", reason="rclpy's std_msgs not importable")
    header = std_msgs.Header(frame_id="camera")
    header.stamp.sec, header.stamp.nanosec = 1_700_000_000, 123
    image = random_image("rgb8", 37, 51)
    msg = image_from_array(sensor_msgs.Image, image, "rgb8", header)
    assert isinstance(msg, sensor_msgs.Image)
    assert (msg.height, msg.width, msg.step, msg.encoding) == (37, 51, 51 * 3, "rgb8")
    assert msg.header.stamp.nanosec == 123 and msg.header.frame_id == "camera"
    np.testing.assert_array_equal(image_to_array(msg), image)


@pytest.mark.parametrize("overrides, message", [
    ({"encoding": "xyz"}, "unsupported encoding 'xyz'"),
    ({"data": b""}, "empty data"),
    ({"step": W * 3 - 1}, "step 17 smaller than width"),
    ({"data": bytes(W * 3 * H - 1)}, r"data length 89 != step\*height = 18\*5 = 90"),
    ({"height": 0}, "zero size"),
    ({"width": 0, "step": 0}, "zero size"),
])
def test_bad_messages_raise_specific_errors(overrides: dict, message: str) -> None:
    fields = array_to_image_fields(random_image("rgb8"), "rgb8")
    with pytest.raises(ImageDecodeError, match=message):
        image_to_array(as_msg(fields, **overrides))


def test_odd_width_yuv_is_rejected() -> None:
    fields = array_to_image_fields(np.zeros((2, 3, 2), np.uint8), "yuv422")
    with pytest.raises(ImageDecodeError, match="even width"):
        image_to_array(as_msg(fields))


@pytest.mark.parametrize("array, encoding, message", [
    (np.zeros((4, 4), np.uint8), "rgb8", r"does not fit 'rgb8'"),
    (np.zeros((4, 4, 3), np.uint16), "rgb8", "dtype uint16 does not fit"),
    (np.zeros((4, 4), np.float64), "32FC1", "dtype float64 does not fit"),
    (np.zeros((4, 4, 2), np.uint8), "mono8", "does not fit 'mono8'"),
    (np.zeros((0, 4), np.uint8), "mono8", "zero size"),
    (np.zeros((4, 4), np.uint8), "bayer_xyzw8", "unsupported encoding"),
])
def test_array_to_fields_validates(array: np.ndarray, encoding: str, message: str) -> None:
    with pytest.raises(ImageDecodeError, match=message):
        array_to_image_fields(array, encoding)


def test_colour_conversions_agree_across_channel_orders() -> None:
    rgb = random_image("rgb8", 8, 10)
    bgr, rgba = rgb[:, :, ::-1].copy(), np.dstack([rgb, np.full(rgb.shape[:2], 9, np.uint8)])
    for array, encoding in [(rgb, "rgb8"), (bgr, "bgr8"), (rgba, "rgba8"), (rgba[:, :, [2, 1, 0, 3]], "bgra8"),
                            (bgr, "8UC3")]:
        np.testing.assert_array_equal(to_rgb(array, encoding), rgb)
        np.testing.assert_array_equal(to_gray(array, encoding), cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    grey = to_gray(rgb, "rgb8")
    expected = np.clip(np.rint(rgb @ np.array([0.299, 0.587, 0.114])), 0, 255)
    assert np.abs(grey.astype(float) - expected).max() <= 1


def test_sixteen_bit_keeps_high_byte() -> None:
    image = random_image("mono16")
    np.testing.assert_array_equal(to_gray(image, "mono16"), (image >> 8).astype(np.uint8))
    np.testing.assert_array_equal(to_rgb(image, "16UC1"), np.repeat((image >> 8).astype(np.uint8)[..., None], 3, 2))


def mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """Bayer raw image of ``rgb``: pattern (e.g. "rggb") gives the colour of each pixel of the 2x2 block row-wise."""
    channel = {"r": 0, "g": 1, "b": 2}
    raw = np.empty(rgb.shape[:2], rgb.dtype)
    for k, letter in enumerate(pattern):
        raw[k // 2::2, k % 2::2] = rgb[k // 2::2, k % 2::2, channel[letter]]
    return raw


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_demosaic_recovers_colour(pattern: str) -> None:
    colour = np.array([200, 90, 30], np.uint8)
    rgb = np.broadcast_to(colour, (12, 16, 3)).copy()
    out = to_rgb(mosaic(rgb, pattern), f"bayer_{pattern}8")
    np.testing.assert_array_equal(out[2:-2, 2:-2], rgb[2:-2, 2:-2])
    out16 = to_rgb(mosaic(rgb.astype(np.uint16) << 8, pattern), f"bayer_{pattern}16")
    np.testing.assert_array_equal(out16[2:-2, 2:-2], rgb[2:-2, 2:-2])
    assert abs(int(to_gray(mosaic(rgb, pattern), f"bayer_{pattern}8")[5, 5]) - 200 * .299 - 90 * .587 - 30 * .114) <= 1


@pytest.mark.parametrize("encoding, order", [("yuv422", "uyvy"), ("yuv422_yuy2", "yuyv")])
def test_yuv422_decodes_to_colour(encoding: str, order: str) -> None:
    colour = np.array([[[180, 120, 60]]], np.uint8)
    # ITU-R BT.601 limited range (Y in 16..235), the YCbCr that 4:2:2 camera formats carry.
    r, g, b = colour[0, 0].astype(float)
    y = round(16 + (65.481 * r + 128.553 * g + 24.966 * b) / 255)
    u = round(128 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255)
    v = round(128 + (112.0 * r - 93.786 * g - 18.214 * b) / 255)
    pair = {"uyvy": [u, y, v, y], "yuyv": [y, u, y, v]}[order]
    packed = np.tile(np.array(pair, np.uint8).reshape(1, 2, 2), (4, 3, 1))  # 4 x 6 pixels, 2 bytes each
    out = to_rgb(packed, encoding)
    assert out.shape == (4, 6, 3)
    assert np.abs(out.astype(int) - colour.astype(int)).max() <= 3


def test_non_light_images_are_not_converted() -> None:
    with pytest.raises(ImageDecodeError, match="cannot convert '32FC1' to grey"):
        to_gray(np.zeros((2, 2), np.float32), "32FC1")
    with pytest.raises(ImageDecodeError, match="cannot convert '32SC1' to RGB"):
        to_rgb(np.zeros((2, 2), np.int32), "32SC1")


def test_compressed_png_and_jpeg() -> None:
    rgb = cv2.GaussianBlur(random_image("rgb8", 32, 48), (7, 7), 3)
    ok, png = cv2.imencode(".png", rgb[:, :, ::-1])
    assert ok
    np.testing.assert_array_equal(compressed_to_array(SimpleNamespace(format="png", data=png.tobytes())), rgb)
    ok, jpeg = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
    decoded = compressed_to_array(SimpleNamespace(format="rgb8; jpeg compressed bgr8", data=jpeg))
    assert decoded.shape == rgb.shape and np.abs(decoded.astype(int) - rgb).mean() < 3
    grey = rgb[:, :, 1].copy()
    ok, grey_png = cv2.imencode(".png", grey)
    np.testing.assert_array_equal(compressed_to_array(SimpleNamespace(format="mono8; png compressed", data=grey_png)),
                                  grey)


def test_compressed_garbage_raises() -> None:
    with pytest.raises(ImageDecodeError, match="could not decode"):
        compressed_to_array(SimpleNamespace(format="jpeg", data=b"not a jpeg at all"))
    with pytest.raises(ImageDecodeError, match="empty data"):
        compressed_to_array(SimpleNamespace(format="png", data=b""))
    with pytest.raises(ImageDecodeError, match="unsupported CompressedImage format"):
        compressed_to_array(SimpleNamespace(format="h264", data=b"\x00\x01"))


def test_sixteen_bit_png_stays_sixteen_bit() -> None:
    depth = (np.arange(24 * 40, dtype=np.uint16).reshape(24, 40) * 61).astype(np.uint16)
    ok, png = cv2.imencode(".png", depth)
    decoded = compressed_to_array(SimpleNamespace(format="16UC1; png compressed", data=png.tobytes()))
    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, depth)


def test_damaged_streams_print_nothing(capfd: pytest.CaptureFixture) -> None:
    """libjpeg and libpng print recoverable defects straight to fd 2; a stream of such frames must not flood it."""
    rgb = cv2.GaussianBlur(random_image("rgb8", 64, 64), (5, 5), 2)
    jpeg = cv2.imencode(".jpg", rgb)[1].tobytes()
    png = cv2.imencode(".png", rgb)[1].tobytes()
    spliced = jpeg[:200] + bytes(300) + jpeg[500:]  # libjpeg: "Corrupt JPEG data: ... extraneous bytes"
    for _ in range(20):
        assert compressed_to_array(SimpleNamespace(format="jpeg", data=spliced)).shape == (64, 64, 3)
        for truncated in (jpeg[:len(jpeg) // 2], png[:len(png) // 2]):
            with pytest.raises(ImageDecodeError, match="could not decode"):
                compressed_to_array(SimpleNamespace(format="jpeg", data=truncated))
    captured = capfd.readouterr()
    assert captured.err == "" and captured.out == ""


def test_declared_size_reads_headers_without_decoding() -> None:
    ok, png = cv2.imencode(".png", np.zeros((37, 53), np.uint8))
    assert declared_size(SimpleNamespace(format="png", data=png.tobytes())) == (37, 53)
    assert declared_size(SimpleNamespace(height=4, width=9, encoding="mono8", data=b"")) == (4, 9)
    assert declared_size(SimpleNamespace(format="jpeg", data=b"not a jpeg at all")) is None
