"""Soak the real node: a bag's frames looped at a camera rate for a while, over loopback DDS.

Starts ``segmenter`` as its own process (loopback profile, a domain of its own), publishes the bag's images
(the first ``--frames`` of them, looped) at ``--rate`` Hz with stamps that keep increasing, and camera_info
when the bag has it, then reports: masks / frames, latency p50 / p95 (publish -> dynamic mask, matched by
header stamp; carried masks, which the node publishes for frames it skips, come at once and count too), the
drops and carried frames the node reports, the share of frames it processed and its own p95 latency over them
(queue arrival -> masks published), the node's resident memory at start and end and its slope after
the first minute (MB/min; after the first fifth of shorter runs) and at each whole minute (does it level
off?), and its CPU use (100 % = one core).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from moseg_ros.io.bags import list_topics
from moseg_ros.config import all_settings
from moseg_ros.timing import sleep_until
from moseg_ros.tools.demo import start_segmenter, stop_segmenter
from moseg_ros.tools.dds import use_loopback
from moseg_ros.tools.replay import camera_topics, rclpy_messages, wait_until

_TICKS = os.sysconf("SC_CLK_TCK")


def process_sample(pid: int) -> tuple[float, float]:
    """(resident MB, CPU seconds so far) of a process, from /proc."""
    status = Path(f"/proc/{pid}/status").read_text()
    rss_kb = next(int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:"))
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return rss_kb / 1024.0, (int(fields[11]) + int(fields[12])) / _TICKS


def memory_slope(samples: list[tuple[float, float, float]], settle_s: float) -> float:
    """MB per minute of a least-squares line through the (time, MB, cpu) samples after ``settle_s``."""
    times = np.array([t for t, _, _ in samples])
    later = times >= times[0] + settle_s
    if later.sum() < 2:
        return float("nan")
    slope = np.polyfit(times[later], np.array([mb for _, mb, _ in samples])[later], 1)[0]
    return float(slope * 60.0)


def memory_by_minute(samples: list[tuple[float, float, float]]) -> list[float]:
    """Resident MB at the start and at each whole minute after it (whether the memory levels off)."""
    times = np.array([t for t, _, _ in samples]) - samples[0][0]
    minutes = np.arange(int(times[-1] // 60.0) + 1) * 60.0
    first_after = np.searchsorted(times, minutes)
    return [round(samples[i][1], 1) for i in first_after]


def _load(bag: Path, frames: int) -> tuple[str, list[Any], Any | None]:
    """(image topic, its first ``frames`` rclpy messages, one camera_info or None)."""
    topic, topics = camera_topics(list_topics(bag))
    images, info = [], None
    for name, _, msg in rclpy_messages(bag, topics):
        if name == topic:
            images.append(msg)
        elif info is None:
            info = msg
        if len(images) >= frames:
            break
    if not images:
        raise ValueError(f"{bag} has no frames on {topic}")
    return topic, images, info


class _Listener:
    """Receives the node's masks (arrival time per stamp) and its diagnostics."""

    def __init__(self, node: Any) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Image

        self.lock = threading.Lock()
        self.arrived: dict[int, float] = {}
        self.diagnostics: dict[str, str] = {}
        reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
        node.create_subscription(Image, "/segmenter/dynamic_mask", self._on_mask, reliable)
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    def _on_mask(self, msg: Any) -> None:
        now = time.monotonic()
        with self.lock:
            self.arrived[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = now

    def _on_diagnostics(self, msg: Any) -> None:
        with self.lock:
            for status in msg.status:
                if status.hardware_id.endswith("segmenter"):
                    self.diagnostics = {kv.key: kv.value for kv in status.values}


def soak(bag: Path, rate: float, seconds: float, *, frames: int = 100, domain_id: int = 77,
         params: list[str] = (), log_path: Path | None = None) -> dict[str, Any]:
    """Run the soak and return its report (see the module docstring); ``params`` are node ``name:=value``."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    if rate <= 0 or seconds <= 0:
        raise ValueError(f"rate and seconds must be > 0, got {rate} Hz for {seconds} s")
    topic, images, info = _load(Path(bag), frames)
    log_path = log_path or Path(tempfile.mkstemp(prefix="moseg-soak-", suffix=".log")[1])
    process = start_segmenter(domain_id, log_path, list(params))
    use_loopback(domain_id)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("moseg_soak", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    listener = _Listener(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    sent: dict[int, float] = {}
    samples: list[tuple[float, float, float]] = []
    try:
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
        publisher = node.create_publisher(type(images[0]), topic, reliable)
        info_publisher = node.create_publisher(type(info), topic.rsplit("/", 1)[0] + "/camera_info",
                                               reliable) if info is not None else None
        spinner.start()
        wait_until(lambda: publisher.get_subscription_count() > 0
              and node.count_publishers("/segmenter/dynamic_mask") > 0, 60.0, "the segmenter")
        time.sleep(0.5)
        samples.append((time.monotonic(), *process_sample(process.pid)))
        _publish_loop(images, info, publisher, info_publisher, rate, seconds, sent, samples, process.pid)
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and len(listener.arrived) < len(sent):
            time.sleep(0.05)
        time.sleep(1.5)  # one more diagnostics period
    finally:
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        spinner.join(timeout=2.0)
        exit_code = stop_segmenter(process)
    return _report(sent, listener, samples, rate, seconds, exit_code, str(log_path))


def _publish_loop(images: list[Any], info: Any | None, publisher: Any, info_publisher: Any | None, rate: float,
                  seconds: float, sent: dict[int, float], samples: list[tuple[float, float, float]],
                  pid: int) -> None:
    period = 1.0 / rate
    start = time.monotonic()
    stamp0 = time.time_ns()
    next_sample = start + 1.0
    for k in range(max(1, round(rate * seconds))):
        sleep_until(start + k * period)
        msg = images[k % len(images)]
        stamp = stamp0 + round(k * period * 1e9)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        if info_publisher is not None and k % max(1, round(rate)) == 0:
            info.header.stamp = msg.header.stamp
            info_publisher.publish(info)
        sent[stamp] = time.monotonic()
        publisher.publish(msg)
        if time.monotonic() >= next_sample:
            samples.append((time.monotonic(), *process_sample(pid)))
            next_sample += 1.0
    samples.append((time.monotonic(), *process_sample(pid)))


def _report(sent: dict[int, float], listener: _Listener, samples: list[tuple[float, float, float]], rate: float,
            seconds: float, exit_code: int, log: str) -> dict[str, Any]:
    with listener.lock:
        latency = np.array([(listener.arrived[s] - t) * 1e3 for s, t in sent.items() if s in listener.arrived])
        diagnostics = dict(listener.diagnostics)
    wall = samples[-1][0] - samples[0][0]
    cpu = (samples[-1][2] - samples[0][2]) / wall * 100 if wall > 0 else float("nan")
    return {
        "rate_hz": rate, "seconds": seconds, "frames": len(sent), "masks": int(latency.size),
        "masked_fraction": latency.size / max(len(sent), 1),
        "latency_ms_p50": float(np.percentile(latency, 50)) if latency.size else None,
        "latency_ms_p95": float(np.percentile(latency, 95)) if latency.size else None,
        "node_dropped": int(diagnostics.get("dropped", -1)),
        "node_carried": int(diagnostics.get("carried", -1)),
        "processed_fraction": int(diagnostics.get("frames_out", 0)) / max(len(sent), 1),
        "node_latency_ms_p95": float(diagnostics.get("latency_ms_p95", "nan")),
        "node_refit_age_mean": float(diagnostics.get("refit_age_mean", "nan")),
        "node_fusion_age_mean": float(diagnostics.get("fusion_age_mean", "nan")),
        "rss_mb_start": samples[0][1], "rss_mb_end": samples[-1][1],
        "rss_slope_mb_per_min": memory_slope(samples, 60.0 if seconds >= 120 else seconds / 5),
        "rss_mb_by_minute": memory_by_minute(samples),
        "cpu_percent": cpu, "node_exit_code": exit_code, "node_log": log,
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg bench soak`."""
    parser.add_argument("bag", type=Path, help="bag whose frames are looped (e.g. from `moseg kitti2bag`)")
    parser.add_argument("--rate", type=float, default=30.0, help="frames per second (default 30)")
    parser.add_argument("--seconds", type=float, default=60.0, help="how long to publish (default 60)")
    parser.add_argument("--frames", type=int, default=100, help="first N frames of the bag, looped (default 100)")
    parser.add_argument("--domain", type=int, default=77, help="ROS domain of the soak (default 77)")
    parser.add_argument("--set", dest="node_params", action="append", default=[], metavar="NAME=VALUE",
                        help="a node parameter (repeatable), e.g. --set queue_size=1")
    parser.add_argument("--json", type=Path, metavar="PATH", help="also write the report here")


def _node_params(assignments: list[str]) -> list[str]:
    """``name:=value`` for the node from ``--set`` NAME=VALUE, each value parsed and checked in its setting's
    type and written as ROS reads that type back (``100`` for a float setting is ``100.0``: ROS would read an
    integer, and the node refuses an integer for a double parameter)."""
    settings = {entry.name: entry for entry in all_settings()}
    params = []
    for assignment in assignments:
        name, sep, text = assignment.partition("=")
        if not sep or name not in settings:
            raise ValueError(f"--set {assignment!r}: expected NAME=VALUE with NAME one of the node's parameters "
                             f"({', '.join(sorted(settings))})")
        value = settings[name].parse(text)
        settings[name].check(value)
        params.append(f"{name}:={ros_text(value)}")
    return params


def ros_text(value: bool | int | float | str) -> str:
    """``value`` as a ROS ``-p name:=value`` argument reads it back in the same type."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return repr(value)
    return str(value)


def run(args: argparse.Namespace) -> int:
    """Print the report as JSON; exit 1 when the node did not exit cleanly."""
    try:
        report = soak(args.bag, args.rate, args.seconds, frames=args.frames, domain_id=args.domain,
                      params=_node_params(args.node_params))
    except (FileNotFoundError, ValueError, TimeoutError) as error:
        print(f"moseg bench soak: error: {error}")
        return 2
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0 if report["node_exit_code"] == 0 else 1

