"""Reading ROS bags with rosbags and mcap (``ros2 bag`` and rosbag2_py are not on PyPI); writing: io/bag_writer.py.

Reading: a rosbag2 folder (.mcap or .db3), a bare .mcap file, or a ROS 1 .bag. An MCAP file that is
unfinished (a killed writer: no summary, no metadata.yaml) or damaged is read record by record up to the
first unreadable byte; every reader ends a damaged bag with :class:`BagDamagedError`, which says how many
messages came out before the damage.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import closing
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore



IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
_NS = 1_000_000_000


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


def is_bag(path: Path) -> bool:
    """A rosbag2 folder (with metadata.yaml), a .mcap file or a ROS 1 .bag."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.is_file() and path.suffix in (".mcap", ".bag")
