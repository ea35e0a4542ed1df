"""The `segmenter` node: a thin rclpy adapter around moseg_ros.pipeline.Pipeline.

Subscribes ``image`` (sensor_msgs/Image or CompressedImage via ``image_transport_compressed``), optionally
``instances``; publishes ``~/dynamic_mask``, ``~/static_mask``, ``~/instance_labels``, ``~/debug_image`` (each
only while subscribed) and ``/diagnostics``. Every output carries the input image's header unchanged.

The subscription callback only enqueues; one worker thread decodes and segments, so a slow frame never
blocks the executor. The queue is bounded and the newest frames win: on overflow the oldest frame leaves the
queue unprocessed, and with ``overflow`` "carry" (the default) it gets the newest masks under its own header
at once, so every frame still gets masks when the camera is faster than the method ("drop": it gets none).
Both are counted in the diagnostics. A carried mask is published when its frame leaves the queue, so it can
come before the mask of an older frame still being processed: pair images and masks by stamp.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
import sys
import threading
import time
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data, ReliabilityPolicy, HistoryPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from moseg_ros.io.frames import camera_matrix, decode_frame, decode_instances
from moseg_ros.io.image import declared_size, image_from_array
from moseg_ros.diagnostics import NodeStatistics
from moseg_ros.config import all_settings, bare_names, config_from_values, nested_values, pipeline_settings
from moseg_ros.params import Setting
from moseg_ros.pipeline import FrameResult, Pipeline
from moseg_ros.render import Masks, debug_overlay


def _describe(entry: Setting) -> ParameterDescriptor:
    """A read-only parameter descriptor with the setting's range, or its choices in the constraints text."""
    descriptor = ParameterDescriptor(description=entry.description, read_only=True)
    if entry.choices:
        descriptor.additional_constraints = "one of: " + ", ".join(entry.choices)
    if entry.low is not None:
        if isinstance(entry.default, int):
            descriptor.integer_range = [IntegerRange(from_value=int(entry.low), to_value=int(entry.high), step=1)]
        else:
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(entry.low),
                                                                  to_value=float(entry.high))]
    return descriptor


# name -> (default, descriptor), derived from the one schema (moseg_ros/params.py). rclpy enforces the ranges
# at declaration; choices are checked by the schema at start (descriptors cannot express them).
SCHEMA = {entry.name: entry for entry in all_settings()}
PARAMETERS: dict[str, tuple[Any, ParameterDescriptor]] = {
    name: (entry.default, _describe(entry)) for name, entry in SCHEMA.items()}
PIPELINE_NAMES = tuple(entry.name for entry in pipeline_settings())
# The method settings' bare names, read for one release after they were nested by method (``moving_objects.*``).
DEPRECATED = {name: ParameterDescriptor(description=f"deprecated: name it {' / '.join(nested)}", read_only=True,
                                        dynamic_typing=True)
              for name, nested in bare_names().items()}


def checked_settings(settings: dict[str, Any]) -> dict[str, Any]:
    """``settings`` (the node's parameters by name), each checked by the schema; ValueError names a bad one."""
    for name, value in settings.items():
        SCHEMA[name].check(value)
    if settings["method"] == "object_level" and not settings["use_instances"] and not settings["instance_model"]:
        raise ValueError("method object_level segments instances: set use_instances:=true and remap "
                         "`instances`, or give an instance_model")
    return settings


def declared_settings(node: Node) -> dict[str, Any]:
    """Declare every parameter on ``node`` and return their values by name, checked (``checked_settings``); a
    method setting given by its deprecated bare name is taken for every method that has it, with a warning."""
    for name, (default, descriptor) in PARAMETERS.items():
        node.declare_parameter(name, default, descriptor)
    for name, descriptor in DEPRECATED.items():
        node.declare_parameter(name, None, descriptor)
    values = {name: node.get_parameter(name).value for name in PARAMETERS}
    bare = {name: node.get_parameter(name).value for name in DEPRECATED}
    values.update(nested_values({name: value for name, value in bare.items() if value is not None},
                                node.get_logger().warning))
    return checked_settings(values)


def input_qos(settings: dict[str, Any]) -> QoSProfile:
    """The QoS of the input subscriptions: ``image_qos`` with ``qos_depth``."""
    depth = settings["qos_depth"]
    if settings["image_qos"] == "sensor_data":
        return QoSProfile(depth=depth, reliability=qos_profile_sensor_data.reliability,
                          durability=qos_profile_sensor_data.durability, history=HistoryPolicy.KEEP_LAST)
    reliability = ReliabilityPolicy.RELIABLE if settings["image_qos"] == "reliable" else ReliabilityPolicy.BEST_EFFORT
    return QoSProfile(depth=depth, reliability=reliability, history=HistoryPolicy.KEEP_LAST)


class InstancesByStamp:
    """Upstream instance images kept by stamp (the newest ``capacity``) until the worker pairs one with its image."""

    def __init__(self, wake: threading.Condition, capacity: int = 50) -> None:
        self._wake = wake  # the node's: the worker waits on it for frames and instances alike
        self._capacity = capacity
        self._by_stamp: collections.OrderedDict[tuple[int, int], Any] = collections.OrderedDict()

    def add(self, msg: Any) -> None:
        """Keep an instance image (the subscription's callback)."""
        with self._wake:
            self._by_stamp[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = msg
            while len(self._by_stamp) > self._capacity:
                self._by_stamp.popitem(last=False)
            self._wake.notify()

    def take(self, image: Any, timeout: float, stopping: Callable[[], bool]) -> Any | None:
        """The instance image with ``image``'s exact stamp, waiting up to ``timeout`` seconds (or until
        ``stopping``); None when none came."""
        key = (image.header.stamp.sec, image.header.stamp.nanosec)
        with self._wake:
            self._wake.wait_for(lambda: key in self._by_stamp or stopping(), timeout=timeout)
            return self._by_stamp.pop(key, None)


class SegmenterNode(Node):
    """Publishes per-instance dynamic masks for every image it receives."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("segmenter", **kwargs)
        self.settings = declared_settings(self)
        self.pipeline = Pipeline(config_from_values({name: self.settings[name] for name in PIPELINE_NAMES}),
                                 live=True)

        self.statistics = NodeStatistics()
        self.counters = self.statistics.counters
        self._queue: collections.deque[tuple[Any, float]] = collections.deque()
        self._wake = threading.Condition()
        self._instances = InstancesByStamp(self._wake)
        self._running = True
        self.camera_matrix: np.ndarray | None = None
        self._camera_size: tuple[int, int] = (0, 0)
        self._last_warning: dict[str, float] = {}
        self._newest_masks: Masks | None = None  # what a carried frame gets
        self._free_since = -np.inf  # when the worker was done with its last frame (how long a queued one waited)
        self._publishing = threading.Lock()  # the worker and the executor (carried frames) both publish

        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
        self.pub_dynamic = self.create_publisher(Image, "~/dynamic_mask", reliable)
        self.pub_static = self.create_publisher(Image, "~/static_mask", reliable)
        self.pub_labels = self.create_publisher(Image, "~/instance_labels", reliable)
        self.pub_debug = self.create_publisher(Image, "~/debug_image", reliable)
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)

        image_type = CompressedImage if self.settings["compressed_input"] else Image
        qos = input_qos(self.settings)
        self.create_subscription(image_type, "image", self._on_image, qos)
        self.create_subscription(CameraInfo, "camera_info", self._on_camera_info, qos)
        if self.settings["use_instances"]:
            self.create_subscription(Image, "instances", self._instances.add, qos)
        self.create_timer(self.settings["diagnostics_period_s"], self._publish_diagnostics)
        self._worker = threading.Thread(target=self._work, name="segmenter-worker", daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"segmenter ready: method={self.settings['method']} image_qos={self.settings['image_qos']} "
            f"input={image_type.__name__} use_instances={self.settings['use_instances']}")

    def _warn(self, kind: str, text: str) -> None:
        # Throttled per kind: rclpy's own throttle is per call site, which would let one kind hide another.
        now = time.monotonic()
        if now - self._last_warning.get(kind, -np.inf) >= self.settings["warn_throttle_s"]:
            self._last_warning[kind] = now
            self.get_logger().warning(text)

    # Callbacks: the executor thread only enqueues.
    def _on_image(self, msg: Any) -> None:
        now = time.monotonic()
        evicted = None
        with self._wake:
            self.statistics.arrived(now)
            if len(self._queue) >= self.settings["queue_size"]:
                evicted = self._queue.popleft()[0]
            self._queue.append((msg, now))
            self._wake.notify()
        if evicted is not None:  # published outside the queue's lock, so the worker never waits for it
            self._overflow(evicted)

    def _overflow(self, msg: Any) -> None:
        """The oldest queued frame leaves the queue unprocessed: carry the newest masks to it, or drop it."""
        masks = self._newest_masks
        if self.settings["overflow"] == "carry" and _fits(msg, masks):
            self._publish_masks(msg.header, masks)
            self.counters.carried += 1
            self._warn("carried", "worker is behind: the oldest queued frame got the newest masks")
            return
        self.counters.dropped += 1
        self._warn("dropped", "worker is behind: dropped the oldest queued frame")

    def _stale(self, msg: Any, arrived: float) -> bool:
        """Whether a frame waited for the busy worker longer than ``max_wait_ms`` (from its arrival to the moment the
        worker was done with the frame before) and may leave the queue unprocessed (``_overflow``): carried when
        the newest masks fit it, dropped with ``overflow`` drop; with nothing to carry it is processed (every
        decodable frame gets masks). A frame that came while the worker was free never waited, however late the
        worker thread wakes."""
        if (self._free_since - arrived) * 1e3 <= self.settings["max_wait_ms"]:
            return False
        return self.settings["overflow"] == "drop" or _fits(msg, self._newest_masks)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        # moving_objects uses K for its cheirality test; without it (or for another image size) K is guessed.
        self.camera_matrix = camera_matrix(msg.k)
        self._camera_size = (msg.height, msg.width)

    def _camera_matrix_for(self, frame: np.ndarray) -> np.ndarray | None:
        """camera_info's K when its image size is the frame's (a K for another size would mislead)."""
        if self.camera_matrix is None or self._camera_size != frame.shape[:2]:
            return None
        return self.camera_matrix

    # Worker thread.
    def _work(self) -> None:
        while True:
            with self._wake:
                self._wake.wait_for(lambda: self._queue or not self._running)
                if not self._running:
                    return
                msg, arrived = self._queue.popleft()
            if self._stale(msg, arrived):
                self._overflow(msg)
                continue
            try:
                self._handle(msg, arrived)
            except Exception as error:  # the node must outlive any single bad frame
                self.counters.failures += 1
                self.get_logger().error(f"frame at {_stamp_text(msg)} failed: {error!r}",
                                        throttle_duration_sec=self.settings["warn_throttle_s"])
            self._free_since = time.monotonic()

    def _take_instances(self, msg: Any) -> np.ndarray | None:
        if not self.settings["use_instances"]:
            return None
        found = self._instances.take(msg, self.settings["instances_timeout_s"], lambda: not self._running)
        if found is None:
            self.counters.no_instances += 1
            self._warn("no_instances", f"no instance image with stamp {_stamp_text(msg)}: segmenting without it")
            return None
        return decode_instances(found)

    def _next_frame_at(self) -> float | None:
        """When the camera's next frame is expected (``timing.next_arrival``), the time this frame may spend on
        its refit (``refit_wait_ms`` -1); now when a frame already waits in the queue (there is no time)."""
        with self._wake:
            return time.monotonic() if self._queue else self.statistics.next_arrival()

    def _handle(self, msg: Any, arrived: float) -> None:
        try:
            frame = decode_frame(msg, self.settings["max_pixels"])
            instances = self._take_instances(msg)
        except ValueError as error:
            self.counters.bad_input += 1
            self._warn("bad_input", f"skipped frame {_stamp_text(msg)}: {error}")
            return
        if instances is not None and instances.shape != frame.shape[:2]:
            self.counters.bad_input += 1
            self._warn("bad_instances",
                       f"instance image {instances.shape} does not match frame {frame.shape[:2]}; ignored")
            instances = None
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        try:
            result = self.pipeline.process(frame, stamp_ns, instances, self._camera_matrix_for(frame),
                                           self._next_frame_at())
        except Exception as error:  # a decodable frame gets masks whatever goes wrong: empty, with its status
            self.counters.failures += 1
            result = self.pipeline.failed(stamp_ns, frame.shape[:2], error)
        kind = result.status.split(":")[0]
        self.statistics.processed(result.status, result.telemetry)
        if kind == "reset":
            self.counters.resets += 1
            self._warn("reset", f"window reset at {_stamp_text(msg)}: {result.status[7:]}")
        elif kind in ("too_small", "failed"):
            self._warn(kind, f"frame {_stamp_text(msg)} {frame.shape[:2]} got an empty mask: {result.status}")
        self._publish(msg.header, frame, result)
        self.statistics.published(arrived, time.monotonic())

    def _publish(self, header: Any, frame: np.ndarray, result: FrameResult) -> None:
        masks = result.masks
        self._publish_masks(header, masks)
        self._newest_masks = masks
        if self.pub_debug.get_subscription_count() > 0:
            rgb = frame if frame.ndim == 3 else np.repeat(frame[..., None], 3, axis=2)
            self.pub_debug.publish(image_from_array(Image, debug_overlay(rgb, masks), "rgb8", header))

    def _publish_masks(self, header: Any, masks: Masks) -> None:
        # A mask nobody subscribes to is not built: the labels alone are 4 bytes a pixel, and the worker holds
        # the GIL while it copies them into a message (about 2 ms a KITTI frame for the three).
        outputs = ((self.pub_dynamic, masks.dynamic, "mono8"), (self.pub_static, masks.static, "mono8"),
                   (self.pub_labels, masks.instance_labels, "32SC1"))
        with self._publishing:
            for publisher, array, encoding in outputs:
                if publisher.get_subscription_count() > 0:
                    publisher.publish(image_from_array(Image, array, encoding, header))

    def _publish_diagnostics(self) -> None:
        problems = self.counters.problems
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
            name=f"{self.get_name()}: motion segmentation",
            message="dropped, carried, skipped or failed frames" if problems else "ok",
            hardware_id=self.get_fully_qualified_name())
        values = {**self.statistics.values(), "queued": len(self._queue), "calibrated": self.camera_matrix is not None}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.pub_diagnostics.publish(array)

    def stop(self) -> None:
        """Stop the worker thread after the frame it is on, then the pipeline's refit worker."""
        with self._wake:
            self._running = False
            self._wake.notify_all()
        self._worker.join(timeout=5.0)
        self.pipeline.close()


def _fits(msg: Any, masks: Masks | None) -> bool:
    """Whether ``masks`` can be carried to the frame of ``msg``: there are some, of its declared size."""
    return masks is not None and declared_size(msg) == masks.dynamic.shape


def _stamp_text(msg: Any) -> str:
    return f"{msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}"


def main(args: list[str] | None = None) -> int:
    """Run the segmenter until SIGINT or SIGTERM; exit code 2 for invalid parameters."""
    rclpy.init(args=args)
    node = None
    try:
        node = SegmenterNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # rclpy's signal handler can shut the context down while the executor builds its wait set
        # (ros2/rclpy#402); the executor then raises RCLError instead of ExternalShutdownException.
        if rclpy.ok():
            raise
    except (ValueError, ParameterException) as error:
        print(f"segmenter: invalid parameters: {error}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.stop()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
