"""Replay a bag's images to a running segmenter over DDS and record everything it publishes.

The images go out at the bag's own rate (or ``--rate`` times it) with their recorded headers; every output
of the node is written to an MCAP bag together with the images sent. Each input frame is accounted for:
a frame whose mask never came back is listed by stamp, never silently dropped.
"""

from __future__ import annotations

import argparse
import importlib
import json
import shutil
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from moseg_ros.io.bag_images import camera_info_topic, pick_image_topic
from moseg_ros.io.bag_writer import BagWriter
from moseg_ros.io.bags import CAMERA_INFO_TYPE, BagDamagedError, iter_messages, list_topics
from moseg_ros.timing import sleep_until
from moseg_ros.tools.dds import use_loopback

OUTPUTS = {
    "dynamic_mask": "sensor_msgs/msg/Image",
    "static_mask": "sensor_msgs/msg/Image",
    "instance_labels": "sensor_msgs/msg/Image",
}
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"


@dataclass
class ReplayReport:
    """What came back for each frame sent.

    Attributes:
        frames_in: image messages published to the node.
        masks_out: distinct input stamps for which a dynamic mask came back.
        missing_stamps: stamps (ns) of frames that got no dynamic mask.
        header_mismatches: masks whose frame_id differs from their input's.
        latency_ms: per returned mask, wall time from publishing the image to receiving its mask.
        outputs: messages recorded per output topic.
        diagnostics: the key/values of the node's last /diagnostics status.
        input_damage: None, or why the reading of a damaged input bag stopped (what came before was replayed).
    """

    frames_in: int = 0
    masks_out: int = 0
    missing_stamps: list[int] = field(default_factory=list)
    header_mismatches: int = 0
    latency_ms: list[float] = field(default_factory=list)
    outputs: dict[str, int] = field(default_factory=dict)
    diagnostics: dict[str, str] = field(default_factory=dict)
    input_damage: str | None = None

    def summary(self) -> dict[str, Any]:
        """The report as JSON-ready numbers (latency percentiles instead of the raw list)."""
        latency = np.array(self.latency_ms) if self.latency_ms else np.full(1, np.nan)
        return {
            "frames_in": self.frames_in, "masks_out": self.masks_out,
            "frames_without_mask": len(self.missing_stamps), "missing_stamps": self.missing_stamps,
            "header_mismatches": self.header_mismatches,
            "latency_ms_p50": float(np.percentile(latency, 50)),
            "latency_ms_p95": float(np.percentile(latency, 95)),
            "outputs": self.outputs, "node_diagnostics": self.diagnostics, "input_damage": self.input_damage,
        }


def rclpy_messages(bag: Path, topics: dict[str, str]) -> Iterator[tuple[str, int, Any]]:
    """The bag's messages on ``topics`` as rclpy messages (CDR round trip keeps every field, header included)."""
    from rclpy.serialization import deserialize_message
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    classes = {msgtype: get_message(msgtype) for msgtype in set(topics.values())}
    for topic, log_time, msg in iter_messages(bag, list(topics)):
        msgtype = topics[topic]
        yield topic, log_time, deserialize_message(bytes(typestore.serialize_cdr(msg, msgtype)), classes[msgtype])


def camera_topics(available: dict[str, str], image_topic: str | None = None) -> tuple[str, dict[str, str]]:
    """(the image topic, {topic: type} of it and of its camera_info beside it when the bag has one)."""
    topic = pick_image_topic(available, image_topic)
    topics = {topic: available[topic]}
    info_topic = camera_info_topic(available, topic)
    if info_topic is not None:
        topics[info_topic] = CAMERA_INFO_TYPE
    return topic, topics


def get_message(msgtype: str) -> type:
    """The rclpy message class of a type name like "sensor_msgs/msg/Image" (rosidl_runtime_py is not on PyPI)."""
    package, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


class _Recorder:
    """Subscribes to the node's outputs and writes every message to the output bag."""

    def __init__(self, node: Any, writer: BagWriter, segmenter: str) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Image

        self.writer = writer
        self.lock = threading.Lock()
        self.received: dict[int, float] = {}
        self.frame_ids: dict[int, str] = {}
        self.stamps: dict[str, set[int]] = {}
        self.diagnostics: dict[str, str] = {}
        self.topics = {f"{segmenter}/{name}": msgtype for name, msgtype in OUTPUTS.items()}
        self.stamps = {topic: set() for topic in self.topics}
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
        for topic in self.topics:
            node.create_subscription(Image, topic, lambda msg, t=topic: self._on_output(t, msg), reliable,
                                     raw=True)
        self.mask_topic = f"{segmenter}/dynamic_mask"
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    def _on_output(self, topic: str, raw: bytes) -> None:
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import Image

        now = time.monotonic()
        header = deserialize_message(raw, Image).header
        stamp = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
        with self.lock:
            self.writer.write_serialized(topic, self.topics[topic], raw, time.time_ns())
            self.stamps[topic].add(stamp)
            if topic == self.mask_topic:
                self.received.setdefault(stamp, now)
                self.frame_ids[stamp] = header.frame_id

    def has_all_outputs(self, stamps: Iterable[int]) -> bool:
        """Every output topic has a message for each of ``stamps`` (the node publishes them one by one)."""
        with self.lock:
            return all(set(stamps) <= seen for seen in self.stamps.values())

    def _on_diagnostics(self, msg: Any) -> None:
        from rclpy.serialization import serialize_message

        with self.lock:
            self.writer.write_serialized("/diagnostics", DIAGNOSTICS_TYPE, serialize_message(msg), time.time_ns())
            for status in msg.status:
                if status.name.startswith(("segmenter", "/segmenter")) or "motion segmentation" in status.name:
                    self.diagnostics = {kv.key: kv.value for kv in status.values}


def wait_until(condition: Any, timeout: float, what: str) -> None:
    """Poll ``condition`` every 50 ms; TimeoutError naming ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.05)


def replay(bag: str | Path, output: str | Path, *, image_topic: str | None = None, segmenter: str = "/segmenter",
           rate: float = 1.0, discovery_timeout: float = 30.0, drain_timeout: float = 10.0,
           domain_id: int | None = None, instances_topic: str | None = None) -> ReplayReport:
    """Publish ``bag``'s images (and camera_info) to a running segmenter and record its outputs.

    Args:
        bag: input bag (rosbag2 folder, .mcap or ROS 1 .bag).
        output: rosbag2 MCAP folder to create with the images sent and every output received.
        image_topic: the image topic to replay (default: picked as in :func:`pick_image_topic`).
        segmenter: the node's fully qualified name; outputs are ``<segmenter>/dynamic_mask`` etc.
        rate: playback speed factor (1.0 = the bag's own timing).
        discovery_timeout: seconds to wait for the node to appear.
        drain_timeout: seconds to wait for outstanding masks after the last frame.
        domain_id: ROS domain; when given, the loopback DDS profile is applied to this process first.
        instances_topic: a bag topic of instance-id images to publish as ``instances`` (for a node run with
            use_instances:=true), e.g. the synthetic bags' /gt/instances.

    Returns:
        The per-frame account of what came back.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    if rate <= 0:
        raise ValueError(f"rate must be > 0, got {rate}")
    available = list_topics(bag)
    topic, topics = camera_topics(available, image_topic)
    if instances_topic is not None:
        if instances_topic not in available:
            raise ValueError(f"{bag} has no topic {instances_topic}; topics: {', '.join(sorted(available))}")
        topics[instances_topic] = available[instances_topic]
    if domain_id is not None:
        use_loopback(domain_id)

    report = ReplayReport()
    sent: dict[int, tuple[float, str]] = {}
    writer = BagWriter(output)  # before any DDS set-up: an unusable output path fails fast and leaks nothing
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("moseg_replay", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    with writer:
        recorder = _Recorder(node, writer, segmenter)
        try:
            reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
            publishers = {name: node.create_publisher(get_message(msgtype),
                                                      "instances" if name == instances_topic else name, reliable)
                          for name, msgtype in topics.items()}
            spinner.start()
            wait_until(lambda: publishers[topic].get_subscription_count() > 0
                  and node.count_publishers(recorder.mask_topic) > 0, discovery_timeout,
                  f"a segmenter subscribed to {topic} and publishing {recorder.mask_topic}")
            time.sleep(0.5)  # let the remaining endpoints of both participants match
            try:
                _publish_all(rclpy_messages(Path(bag), topics), publishers, topic, topics, writer, recorder, rate,
                             sent, report)
            except BagDamagedError as error:
                report.input_damage = str(error)
            wait_until(lambda: recorder.has_all_outputs(list(sent)), drain_timeout, "the last masks") if sent else None
        except TimeoutError as error:
            if not sent:
                # The bag holds nothing; left in place, it would block a rerun once the node is up.
                writer.close()
                shutil.rmtree(output, ignore_errors=True)
                raise
            print(f"replay: {error}; reporting what came back")
        finally:
            executor.shutdown(timeout_sec=1.0)
            node.destroy_node()
            rclpy.try_shutdown(context=context)
            spinner.join(timeout=2.0)
        with recorder.lock:
            _account(report, sent, recorder)
            report.outputs = {name: writer.counts.get(name, 0) for name in recorder.topics}
    return report


def _publish_all(messages: Iterator[tuple[str, int, Any]], publishers: dict[str, Any], image_topic: str,
                 topics: dict[str, str], writer: BagWriter, recorder: _Recorder, rate: float,
                 sent: dict[int, tuple[float, str]], report: ReplayReport) -> None:
    from rclpy.serialization import serialize_message

    first_log: int | None = None
    start = time.monotonic()
    for name, log_time, msg in messages:
        first_log = log_time if first_log is None else first_log
        sleep_until(start + (log_time - first_log) / 1e9 / rate)
        publishers[name].publish(msg)
        with recorder.lock:
            writer.write_serialized(name, topics[name], serialize_message(msg), time.time_ns())
        if name == image_topic:
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            sent[stamp] = (time.monotonic(), msg.header.frame_id)
            report.frames_in += 1


def _account(report: ReplayReport, sent: dict[int, tuple[float, str]], recorder: _Recorder) -> None:
    for stamp, (published, frame_id) in sent.items():
        if stamp not in recorder.received:
            report.missing_stamps.append(stamp)
            continue
        report.masks_out += 1
        report.latency_ms.append((recorder.received[stamp] - published) * 1e3)
        report.header_mismatches += recorder.frame_ids[stamp] != frame_id
    report.diagnostics = dict(recorder.diagnostics)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg replay`."""
    parser.add_argument("bag", type=Path, help="input bag: rosbag2 folder, .mcap file or ROS 1 .bag")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output rosbag2 MCAP folder")
    parser.add_argument("--topic", help="image topic to replay (default: the bag's one camera image topic)")
    parser.add_argument("--instances", metavar="TOPIC",
                        help="also publish this bag topic of instance-id images as `instances`")
    parser.add_argument("--segmenter", default="/segmenter", help="fully qualified name of the running node")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1.0)")
    parser.add_argument("--domain", type=int, default=None,
                        help="ROS domain id; applies the loopback DDS profile (default: the environment's)")
    parser.add_argument("--discovery-timeout", type=float, default=30.0)
    parser.add_argument("--drain-timeout", type=float, default=10.0)


def run(args: argparse.Namespace) -> int:
    """Replay and print the account; exit 1 when any frame got no mask or the input is damaged, 2 when replay
    could not start."""
    try:
        report = replay(args.bag, args.output, image_topic=args.topic, segmenter=args.segmenter, rate=args.rate,
                        discovery_timeout=args.discovery_timeout, drain_timeout=args.drain_timeout,
                        domain_id=args.domain, instances_topic=args.instances)
    except (TimeoutError, FileNotFoundError, FileExistsError, ValueError) as error:
        print(f"moseg replay: error: {error}", file=sys.stderr)
        return 2
    summary = report.summary()
    print(json.dumps({k: v for k, v in summary.items() if k != "missing_stamps"}, indent=2))
    if report.missing_stamps:
        print(f"{len(report.missing_stamps)} frames got no mask: first stamps {report.missing_stamps[:10]}")
    if report.input_damage:
        print(f"moseg replay: warning: {report.input_damage}; replayed the {report.frames_in} frames before it",
              file=sys.stderr)
    return 0 if not report.missing_stamps and not report.input_damage else 1
