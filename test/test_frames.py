"""decode_frame's size limit: raw images by their declared size, compressed ones by their header, undecoded."""

from __future__ import annotations

import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from moseg_ros.io.frames import camera_matrix, decode_frame
from moseg_ros.io.image import ImageDecodeError, compressed_size


def _png(height: int, width: int) -> bytes:
    return cv2.imencode(".png", np.zeros((height, width), np.uint8))[1].tobytes()


class TestCompressedSize:
    @pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".webp"])
    def test_reads_width_and_height_from_the_header(self, ext):
        data = cv2.imencode(ext, np.zeros((37, 53, 3), np.uint8))[1]
        assert compressed_size(data) == (53, 37)

    def test_garbage_has_no_header(self):
        with pytest.raises(ImageDecodeError, match="cannot read the image header"):
            compressed_size(np.frombuffer(b"not an image", np.uint8))


class TestDecodeFrameLimit:
    def test_a_decompression_bomb_is_refused_before_decoding(self):
        bomb = SimpleNamespace(format="png", data=_png(8192, 8192))  # ~65 KB declaring 67 M pixels
        assert len(bomb.data) < 300_000
        start = time.perf_counter()
        with pytest.raises(ImageDecodeError, match="8192x8192 = 67108864 pixels, over the limit of 16777216"):
            decode_frame(bomb, max_pixels=16_777_216)
        assert time.perf_counter() - start < 0.5  # the header only; decoding would allocate 64 MB

    def test_a_raw_image_is_refused_by_its_declared_size(self):
        huge = SimpleNamespace(encoding="mono8", height=100_000, width=100_000, step=100_000, is_bigendian=0,
                               data=b"\0" * 16)
        with pytest.raises(ImageDecodeError, match="over the limit"):
            decode_frame(huge, max_pixels=1_000_000)

    def test_images_within_the_limit_decode(self):
        small = SimpleNamespace(format="png", data=_png(40, 60))
        assert decode_frame(small, max_pixels=2400).shape == (40, 60)
        raw = SimpleNamespace(encoding="mono8", height=2, width=3, step=3, is_bigendian=0, data=bytes(6))
        assert decode_frame(raw, max_pixels=6).shape == (2, 3)


class TestCameraMatrix:
    def test_nine_values_make_k(self):
        K = camera_matrix([707.0, 0, 601.9, 0, 707.0, 183.1, 0, 0, 1])
        assert K.shape == (3, 3) and K.dtype == np.float64 and K[0, 0] == 707.0 and K[1, 2] == 183.1

    @pytest.mark.parametrize("k", [[0.0] * 9, [np.nan, 0, 1, 0, 500, 1, 0, 0, 1], [500, 0, 1, 0, -500, 1, 0, 0, 1]])
    def test_placeholders_are_no_camera(self, k):
        assert camera_matrix(k) is None
