"""Reading and writing ROS bags with rosbags and mcap (``ros2 bag`` and rosbag2_py are not on PyPI).

Writing: :class:`BagWriter` makes a rosbag2 folder (metadata.yaml + one .mcap or .db3 file) with CDR
messages and ros2msg schemas of ROS 2 Jazzy, so the bag opens in rosbags, the mcap library, Foxglove
and ``ros2 bag``. MCAP output is chunk-compressed with zstd (chunks of about 1 MiB, written as they fill),
so a run that is killed leaves every complete chunk readable.

Reading: a rosbag2 folder (.mcap or .db3), a bare .mcap file, or a ROS 1 .bag. An MCAP file that is
unfinished (a killed writer: no summary, no metadata.yaml) or damaged is read record by record up to the
first unreadable byte; every reader ends a damaged bag with :class:`BagDamagedError`, which says how many
messages came out before the damage.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from contextlib import closing
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation

from moseg_ros.io.frames import camera_matrix
from moseg_ros.io.image import (
    array_to_image_fields,
    compressed_to_array,
    image_to_array,
    to_gray,
    to_rgb,
)

__all__ = [
    "BagDamagedError",
    "BagWriter",
    "BagImage",
    "IMAGE_TYPE",
    "COMPRESSED_TYPE",
    "CAMERA_INFO_TYPE",
    "Calibration",
    "camera_info_topic",
    "image_camera",
    "stamp_to_ns",
    "ns_to_stamp_fields",
    "list_topics",
    "pick_image_topic",
    "iter_messages",
    "read_images",
]

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
DEFAULT_IMAGE_TOPIC = "/camera/image_raw"
GROUND_TRUTH_PREFIX = "/gt/"
_STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
_NS = 1_000_000_000
_COMPRESSIONS = (None, "zstd")


class BagDamagedError(ValueError):
    """A bag readable only in part: ``messages_read`` messages came out before ``reason`` stopped the reading."""

    def __init__(self, path: str | Path, messages_read: int, reason: str) -> None:
        self.path = Path(path)
        self.messages_read = messages_read
        self.reason = reason
        super().__init__(f"bag {path} is damaged: {reason} (after {messages_read} readable messages)")


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds of a builtin_interfaces/Time (``sec``, ``nanosec``; ROS 1's ``secs``, ``nsecs`` too)."""
    if hasattr(stamp, "nanosec"):
        return int(stamp.sec) * _NS + int(stamp.nanosec)
    return int(stamp.secs) * _NS + int(stamp.nsecs)


def ns_to_stamp_fields(ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a time in nanoseconds; nanosec in [0, 1e9) also for negative times."""
    sec, nanosec = divmod(int(ns), _NS)
    return int(sec), int(nanosec)


def _rotation_quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a 3x3 rotation; ValueError if it is not a rotation."""
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-5) or np.linalg.det(rotation) < 0:
        raise ValueError(f"pose rotation is not a proper rotation matrix:\n{rotation}")
    return Rotation.from_matrix(rotation).as_quat()


class BagWriter:
    """Write a rosbag2 folder; connections are created on the first write to each topic.

    Use as a context manager (or call :meth:`close`): metadata.yaml is written on close, also when the
    ``with`` body raised, so whatever was written stays readable. ``typestore`` (ROS 2 Jazzy) builds
    messages for :meth:`write`; ``counts`` holds messages written per topic.
    """

    def __init__(self, path: str | Path, *, storage: str = "mcap", compression: str | None = "zstd") -> None:
        path = Path(path)
        if storage not in _STORAGES:
            raise ValueError(f"unknown bag storage {storage!r}; use one of {sorted(_STORAGES)}")
        if compression not in _COMPRESSIONS:
            raise ValueError(f"unknown bag compression {compression!r}; use one of {_COMPRESSIONS}")
        if path.exists():
            raise FileExistsError(f"output bag already exists (not overwriting): {path}")
        if not path.parent.is_dir():
            raise FileNotFoundError(f"parent folder of the output bag does not exist: {path.parent}")
        self.path = path
        self.storage = storage
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self.counts: dict[str, int] = {}
        self._connections: dict[str, Any] = {}
        # Metadata version 9 is what Jazzy's rosbag2 writes.
        self._writer = Writer(path, version=9, storage_plugin=_STORAGES[storage])
        if compression is not None and storage == "mcap":
            # Storage-level compression is MCAP's own chunk compression (as ros2 bag's mcap plugin writes it):
            # each chunk stands alone, unlike file compression, which a killed run leaves unreadable.
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Finish the bag (summary, metadata.yaml); further writes raise."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def _connection(self, topic: str, msgtype: str) -> Any:
        if self._writer is None:
            raise ValueError(f"bag {self.path} is closed")
        connection = self._connections.get(topic)
        if connection is None:
            if msgtype not in self.typestore.types:
                raise ValueError(f"unknown message type {msgtype!r} for topic {topic!r} (not in ROS 2 Jazzy)")
            connection = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
            self._connections[topic] = connection
            self.counts[topic] = 0
        elif connection.msgtype != msgtype:
            raise ValueError(f"topic {topic!r} already holds {connection.msgtype}, cannot write {msgtype}")
        return connection

    def write_serialized(self, topic: str, msgtype: str, data: bytes | memoryview, log_time_ns: int) -> None:
        """Write an already CDR-serialized message (e.g. from rclpy's serialize_message or a raw subscription)."""
        self._writer.write(self._connection(topic, msgtype), int(log_time_ns), data)
        self.counts[topic] += 1

    def write(self, topic: str, msgtype: str, msg: Any, log_time_ns: int) -> None:
        """Serialize a typestore message ``msg`` of type ``msgtype`` (e.g. "std_msgs/msg/String") and write it."""
        connection = self._connection(topic, msgtype)
        self._writer.write(connection, int(log_time_ns), self.typestore.serialize_cdr(msg, msgtype))
        self.counts[topic] += 1

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        """A std_msgs/Header of this typestore."""
        sec, nanosec = ns_to_stamp_fields(stamp_ns)
        types = self.typestore.types
        return types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id)

    def write_image(self, topic: str, stamp_ns: int, frame_id: str, array: np.ndarray, encoding: str, *,
                    log_time_ns: int | None = None) -> None:
        """Write a sensor_msgs/Image of ``array`` (H, W) or (H, W, C), which must fit ``encoding``.

        The log time defaults to the stamp (as for every write_* helper).
        """
        msg = self.typestore.types[IMAGE_TYPE](header=self.header(stamp_ns, frame_id),
                                               **array_to_image_fields(array, encoding))
        self.write(topic, IMAGE_TYPE, msg, stamp_ns if log_time_ns is None else log_time_ns)

    def write_camera_info(self, topic: str, stamp_ns: int, frame_id: str, K: np.ndarray, width: int, height: int,
                          *, D: np.ndarray | None = None, P: np.ndarray | None = None,
                          log_time_ns: int | None = None) -> None:
        """Write a sensor_msgs/CameraInfo: K (3, 3), D (plumb_bob, 5 zeros by default), P (3, 4), default [K | 0]."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"K must be 3x3, got shape {K.shape}")
        P = np.hstack([K, np.zeros((3, 1))]) if P is None else np.asarray(P, dtype=np.float64)
        if P.shape != (3, 4):
            raise ValueError(f"P must be 3x4, got shape {P.shape}")
        D = np.zeros(5) if D is None else np.asarray(D, dtype=np.float64).reshape(-1)
        if width <= 0 or height <= 0:
            raise ValueError(f"camera_info size must be positive, got {width}x{height}")
        types = self.typestore.types
        msg = types["sensor_msgs/msg/CameraInfo"](
            header=self.header(stamp_ns, frame_id), height=int(height), width=int(width),
            distortion_model="plumb_bob" if D.size in (5, 0) else "rational_polynomial",
            d=D, k=K.reshape(-1), r=np.eye(3).reshape(-1), p=P.reshape(-1), binning_x=0, binning_y=0,
            roi=types["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
        self.write(topic, "sensor_msgs/msg/CameraInfo", msg, stamp_ns if log_time_ns is None else log_time_ns)

    def write_pose(self, topic: str, stamp_ns: int, frame_id: str, T: np.ndarray, *,
                   log_time_ns: int | None = None) -> None:
        """Write a geometry_msgs/PoseStamped of a 4x4 camera-to-world transform T (frame_id = the world frame)."""
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"pose must be a 4x4 matrix, got shape {T.shape}")
        x, y, z, w = _rotation_quaternion_xyzw(T[:3, :3])
        types = self.typestore.types
        pose = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            orientation=types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w)))
        msg = types["geometry_msgs/msg/PoseStamped"](header=self.header(stamp_ns, frame_id), pose=pose)
        self.write(topic, "geometry_msgs/msg/PoseStamped", msg, stamp_ns if log_time_ns is None else log_time_ns)


def _bag_kind(path: str | Path) -> tuple[str, Path]:
    """Classify a bag path: ("rosbag2", folder), ("mcap", file) or ("ros1", file)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"bag not found: {path}")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "rosbag2", path
        mcaps = sorted(path.glob("*.mcap"))
        if len(mcaps) == 1:
            return "mcap", mcaps[0]
        raise ValueError(f"{path} is a folder without metadata.yaml and with {len(mcaps)} .mcap files; "
                         "expected a rosbag2 folder, a .mcap file or a ROS 1 .bag")
    if path.suffix == ".mcap":
        return "mcap", path
    if path.suffix == ".bag":
        return "ros1", path
    if (path.suffix == ".db3" or path.name == "metadata.yaml") and (path.parent / "metadata.yaml").is_file():
        return "rosbag2", path.parent
    raise ValueError(f"unknown bag format: {path} (expected a rosbag2 folder, a .mcap file or a ROS 1 .bag)")


def _mcap_typestore(schemas: Iterable[Any]) -> Any:
    """A typestore holding every message definition embedded in these MCAP schema records."""
    types: dict[str, Any] = {}
    for schema in schemas:
        text = schema.data.decode()
        if schema.encoding == "ros2msg":
            types.update(get_types_from_msg(text, schema.name))
        elif schema.encoding == "ros2idl":
            for part in text.split("=" * 80 + "\n"):
                idl = part.split("\n", 1)[1] if part.startswith("IDL: ") else part
                if idl.strip():
                    types.update(get_types_from_idl(idl))
    typestore = get_typestore(Stores.EMPTY)
    typestore.register(types)
    return typestore


def _damage(error: BaseException) -> str:
    """What stopped the reading of a damaged bag, in one line."""
    if type(error).__name__ == "EndOfFile":
        return "the file ends inside a record (truncated, or its writer was killed)"
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


def _mcap_summary(path: Path) -> Any | None:
    """The summary of an MCAP file, or None when it has none or it cannot be read (unfinished or damaged)."""
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        try:
            return make_reader(stream).get_summary()
        except Exception:  # any failure means "no usable index": the file is then streamed
            return None


def _until_damage(items: Iterator[Any], path: Path, counter: list[int]) -> Iterator[Any]:
    """Yield from ``items``, counting in ``counter[0]``; an error while reading the next one ends the readable
    part with :class:`BagDamagedError`."""
    while True:
        try:
            item = next(items)
        except StopIteration:
            return
        except Exception as error:  # whatever the damage (length, CRC, codec, sqlite, ROS 1), the readable part ends
            raise BagDamagedError(path, counter[0], _damage(error)) from None
        counter[0] += 1
        yield item


def _stream_mcap(path: Path, topics: set[str] | None) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time, message) of an MCAP file in file order, record by record.

    Needs no summary or index, so it reads what a killed writer left (wrap it in :func:`_until_damage`).
    """
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    typestores: dict[int, Any] = {}
    with path.open("rb") as stream:
        for record in StreamReader(stream, validate_crcs=True).records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels[record.channel_id]
                if topics is not None and channel.topic not in topics:
                    continue
                schema = schemas[channel.schema_id]
                if schema.id not in typestores:
                    typestores[schema.id] = _mcap_typestore([schema])
                yield channel.topic, record.log_time, typestores[schema.id].deserialize_cdr(record.data, schema.name)


def _scan_mcap_topics(path: Path) -> dict[str, str]:
    """Topics and types of an MCAP file without a usable summary, from the channel records that can be read."""
    from mcap.records import Channel, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    topics: dict[str, str] = {}
    with path.open("rb") as stream:
        try:
            for record in StreamReader(stream).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel) and record.schema_id in schemas:
                    topics[record.topic] = schemas[record.schema_id]
        except Exception as error:  # damage after the channels is reported when the messages are read
            if not topics:
                raise BagDamagedError(path, 0, _damage(error)) from None
    return topics


def _rosbag2_mcap_files(folder: Path) -> list[Path]:
    """The .mcap files of a rosbag2 folder in recording order (metadata.yaml's list, else by name)."""
    import yaml

    try:
        info = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        files = [folder / name for name in info.get("relative_file_paths", [])]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        files = []
    files = [f for f in files if f.suffix == ".mcap" and f.is_file()]
    return files or sorted(folder.glob("*.mcap"))


def _mcap_files(files: list[Path]) -> tuple[dict[Path, Any | None], dict[str, str]]:
    """Each MCAP file's summary (None when unfinished or damaged) and the topics of them all."""
    summaries = {file: _mcap_summary(file) for file in files}
    topics: dict[str, str] = {}
    for file, summary in summaries.items():
        if summary is None:
            topics.update(_scan_mcap_topics(file))
        else:
            topics.update({channel.topic: summary.schemas[channel.schema_id].name
                           for channel in summary.channels.values() if channel.schema_id in summary.schemas})
    return summaries, topics


def _open_any_reader(path: Path) -> Any | None:
    """An open rosbags AnyReader, or None when a rosbag2 folder of MCAP files cannot be opened (then streamed)."""
    reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
    try:
        reader.open()
    except Exception as error:  # rosbags raises several types for a truncated or corrupt file
        if path.is_dir() and _rosbag2_mcap_files(path):
            return None
        raise BagDamagedError(path, 0, _damage(error)) from None
    return reader


def list_topics(path: str | Path) -> dict[str, str]:
    """Topics of a bag and their message types ("sensor_msgs/msg/Image", ...)."""
    kind, path = _bag_kind(path)
    if kind == "mcap":
        return _mcap_files([path])[1]
    reader = _open_any_reader(path)
    if reader is None:
        return _mcap_files(_rosbag2_mcap_files(path))[1]
    with closing(reader):
        return {topic: info.msgtype for topic, info in reader.topics.items() if info.msgtype}


def _check_topics(topics: Iterable[str] | None, available: dict[str, str]) -> set[str]:
    wanted = set(available) if topics is None else set(topics)
    if missing := wanted - set(available):
        raise ValueError(f"topic(s) {sorted(missing)} not in the bag; available: {sorted(available)}")
    return wanted


def _indexed_mcap(path: Path, summary: Any, wanted: set[str], counter: list[int]) -> Iterator[tuple[str, int, Any]]:
    from mcap.reader import make_reader

    typestore = _mcap_typestore(summary.schemas.values())
    with path.open("rb") as stream:
        messages = make_reader(stream).iter_messages(topics=sorted(wanted), log_time_order=True)
        for schema, channel, message in _until_damage(messages, path, counter):
            if channel.message_encoding != "cdr":
                raise ValueError(f"{path}: topic {channel.topic} is {channel.message_encoding!r}, not cdr")
            yield channel.topic, message.log_time, typestore.deserialize_cdr(message.data, schema.name)


def _mcap_messages(files: list[Path], topics: Iterable[str] | None) -> Iterator[tuple[str, int, Any]]:
    """Messages of MCAP files: log-time order through the index when a file has one, file order otherwise."""
    summaries, available = _mcap_files(files)
    wanted = _check_topics(topics, available)
    counter = [0]
    for file, summary in summaries.items():
        if summary is None:
            yield from _until_damage(_stream_mcap(file, wanted), file, counter)
        else:
            yield from _indexed_mcap(file, summary, wanted, counter)


def iter_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, Any]]:
    """(topic, log time ns, deserialized message) of the given topics (all if None), in log-time order.

    An unfinished MCAP file (no summary) is read in file order, which is the order it was written in.
    A damaged bag yields what can be read and then raises :class:`BagDamagedError`.
    """
    kind, path = _bag_kind(path)
    if kind == "mcap":
        yield from _mcap_messages([path], topics)
        return
    reader = _open_any_reader(path)
    if reader is None:
        yield from _mcap_messages(_rosbag2_mcap_files(path), topics)
        return
    with closing(reader):
        wanted = _check_topics(topics, {c.topic: c.msgtype for c in reader.connections})
        connections = [c for c in reader.connections if c.topic in wanted]
        messages = ((c.topic, log_time, reader.deserialize(raw, c.msgtype))
                    for c, log_time, raw in reader.messages(connections=connections))
        yield from _until_damage(messages, path, [0])


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


def is_bag(path: Path) -> bool:
    """A rosbag2 folder (with metadata.yaml), a .mcap file or a ROS 1 .bag."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.is_file() and path.suffix in (".mcap", ".bag")
