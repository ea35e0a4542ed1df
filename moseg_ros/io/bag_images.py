"""A bag's camera: its image topic, its camera_info by time (``Calibration``) and its images (``read_images``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from moseg_ros.io.frames import camera_matrix
from moseg_ros.io.image import (
    compressed_to_array,
    image_to_array,
    to_gray,
    to_rgb,
)
from moseg_ros.io.bags import BagDamagedError, CAMERA_INFO_TYPE, iter_messages, list_topics, stamp_to_ns


DEFAULT_IMAGE_TOPIC = "/camera/image_raw"
GROUND_TRUTH_PREFIX = "/gt/"


def _is_image_type(msgtype: str) -> bool:
    return msgtype.replace("/msg/", "/") in ("sensor_msgs/Image", "sensor_msgs/CompressedImage")


def camera_info_topic(topics: dict[str, str], image_topic: str) -> str | None:
    """The camera_info beside ``image_topic`` in ``topics`` (topic -> msgtype): ``<its namespace>/camera_info``,
    as a camera driver publishes them; None when the bag has no such CameraInfo topic."""
    topic = image_topic.rsplit("/", 1)[0] + "/camera_info"
    return topic if topics.get(topic) == CAMERA_INFO_TYPE else None


class Calibration:
    """A bag's camera_info over time, read once: the K that a frame logged at a given time had, as the node
    keeps the newest camera_info it got.

    Args:
        path: the bag.
        topic: its CameraInfo topic (``camera_info_topic``), or None (no calibration: ``at`` gives None).
    """

    def __init__(self, path: str | Path, topic: str | None) -> None:
        self.topic = topic
        self._times: list[int] = []
        self._cameras: list[tuple[np.ndarray | None, tuple[int, int]]] = []
        try:
            for _, log_time, msg in iter_messages(path, [topic]) if topic else ():
                self._times.append(int(log_time))
                self._cameras.append((camera_matrix(msg.k), (int(msg.height), int(msg.width))))
        except BagDamagedError:
            pass  # what was read before the damage holds; the images' reading reports the damage

    def at(self, log_time_ns: int, shape: tuple[int, ...]) -> np.ndarray | None:
        """(3, 3) K of the newest camera_info logged at or before ``log_time_ns``, when it is valid and for an
        image of ``shape`` ((H, W, ...): a K for another size would mislead); else None."""
        index = int(np.searchsorted(self._times, log_time_ns, side="right")) - 1
        if index < 0:
            return None
        k, size = self._cameras[index]
        return k if size == tuple(shape[:2]) else None


def pick_image_topic(topics: dict[str, str], requested: str | None = None) -> str:
    """The image topic to read from ``topics`` (topic -> msgtype).

    ``requested`` if given (it must exist and be an Image or CompressedImage topic); otherwise the one
    image topic not under /gt/ (ground truth), else /camera/image_raw; ValueError naming the candidates.
    """
    images = {topic for topic, msgtype in topics.items() if _is_image_type(msgtype)}
    if requested is not None:
        if requested not in topics:
            raise ValueError(f"image topic {requested!r} not in the bag; available: {sorted(topics)}")
        if requested not in images:
            raise ValueError(f"topic {requested!r} is {topics[requested]}, not sensor_msgs/Image or CompressedImage")
        return requested
    candidates = sorted(t for t in images if not t.startswith(GROUND_TRUTH_PREFIX))
    if len(candidates) == 1:
        return candidates[0]
    if DEFAULT_IMAGE_TOPIC in images:
        return DEFAULT_IMAGE_TOPIC
    if not candidates:
        raise ValueError(f"no image topic (sensor_msgs/Image or CompressedImage) outside {GROUND_TRUTH_PREFIX}; "
                         f"topics: {sorted(topics)}")
    raise ValueError(f"several image topics, choose one: {candidates}")


def image_camera(path: str | Path, requested: str | None = None) -> tuple[str, Calibration]:
    """The bag's image topic (``pick_image_topic`` of ``requested``) and the Calibration of the camera_info beside
    it (``camera_info_topic``; one without a topic when there is none), as the node would pair them."""
    topics = list_topics(path)
    topic = pick_image_topic(topics, requested)
    return topic, Calibration(path, camera_info_topic(topics, topic))


@dataclasses.dataclass(frozen=True)
class BagImage:
    """One image message read from a bag; ``msg`` is the deserialized Image or CompressedImage."""

    topic: str
    log_time_ns: int
    stamp_ns: int
    frame_id: str
    msg: Any

    @property
    def compressed(self) -> bool:
        """True for a sensor_msgs/CompressedImage."""
        return hasattr(self.msg, "format")

    @cached_property
    def decoded(self) -> tuple[np.ndarray, str]:
        """(pixels, encoding): as image_to_array gives them when raw; "rgb8" or "mono8"/"mono16" when compressed."""
        if not self.compressed:
            return image_to_array(self.msg), self.msg.encoding
        pixels = compressed_to_array(self.msg)
        if pixels.ndim == 3:
            return pixels, "rgb8"
        return pixels, "mono16" if pixels.dtype == np.uint16 else "mono8"

    def rgb(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB."""
        return to_rgb(*self.decoded)

    def gray(self) -> np.ndarray:
        """(H, W) uint8 grey."""
        return to_gray(*self.decoded)


def read_images(path: str | Path, topic: str | None = None) -> Iterator[BagImage]:
    """Image messages of ``topic`` (picked by :func:`pick_image_topic` when None), in log-time order.

    Decoding is lazy (``BagImage.decoded``), so a frame with a bad encoding raises ImageDecodeError only
    when its pixels are asked for and the caller can count and skip it.
    """
    topic = pick_image_topic(list_topics(path), topic)
    for name, log_time, msg in iter_messages(path, [topic]):
        yield BagImage(name, int(log_time), stamp_to_ns(msg.header.stamp), str(msg.header.frame_id), msg)
