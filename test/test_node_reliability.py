"""The node in its own process under a few thousand hostile messages: alive, every valid frame answered with its
own header, every bad message counted, a clean exit on SIGINT."""

from __future__ import annotations

import signal

import numpy as np
import pytest

from conftest import textured_frames
from moseg_ros.io.bags import stamp_to_ns
from moseg_ros.tools.demo import every_frame_params, start_segmenter

pytest.importorskip("rclpy", reason="rclpy (ROS 2 Jazzy from PyPI) is not installed")
from sensor_msgs.msg import CompressedImage, Image  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from test_node import _Probe  # noqa: E402

SECOND = 1_000_000_000
N_RAW, N_COMPRESSED = 2400, 1200
PARAMS = ["image_qos:=reliable", "qos_depth:=100", *every_frame_params(100), "warn_throttle_s:=1.0"]


def _header(stamp_ns: int, frame_id: str = "camera") -> Header:
    header = Header(frame_id=frame_id)
    header.stamp.sec, header.stamp.nanosec = divmod(stamp_ns, SECOND)
    return header


def _raw(stamp_ns: int, encoding: str, height: int, width: int, step: int, data: bytes, frame_id: str = "camera",
         bigendian: int = 0) -> Image:
    return Image(header=_header(stamp_ns, frame_id), height=height, width=width, encoding=encoding,
                 is_bigendian=bigendian, step=step, data=data)


def hostile_raw(rng: np.random.Generator, stamp_ns: int, kind: int) -> tuple[Image, bool]:
    """One hostile sensor_msgs/Image and whether it must get a mask (decodable) or be counted as bad."""
    small = rng.integers(0, 255, (8, 64), dtype=np.uint8).tobytes()
    cases = [
        (lambda: _raw(stamp_ns, "xyz99", 8, 8, 8, bytes(64)), False),               # unknown encoding
        (lambda: _raw(stamp_ns, "rgb8", 10, 10, 10, bytes(100)), False),            # step shorter than a row
        (lambda: _raw(stamp_ns, "mono8", 10, 10, 10, bytes(99)), False),            # data length != step x height
        (lambda: _raw(stamp_ns, "mono8", 0, 10, 10, b""), False),                   # zero size
        (lambda: _raw(stamp_ns, "mono8", 100_000, 100_000, 100_000, bytes(16)), False),  # huge declared size
        (lambda: _raw(stamp_ns, "32FC1", 4, 4, 16, np.full(16, np.nan, np.float32).tobytes()), False),  # NaN
        (lambda: _raw(stamp_ns, "yuv422", 4, 3, 6, bytes(24)), False),              # odd-width 4:2:2
        (lambda: _raw(stamp_ns, "mono8", 4, 4, 4, b""), False),                     # empty data
        (lambda: _raw(stamp_ns, "mono8", 8, 64, 64, small), True),                  # too small: empty mask
        (lambda: _raw(stamp_ns, "mono16", 8, 8, 16, bytes(128), bigendian=1), True),  # tiny big-endian grey
        (lambda: _raw(stamp_ns, "mono8", 1, 640, 640, bytes(640), frame_id="ñ/odd id ✓"), True),  # 1 row
    ]
    make, expect = cases[kind % len(cases)]
    return make(), expect


def hostile_compressed(rng: np.random.Generator, stamp_ns: int, kind: int, bomb: bytes,
                       jpeg: bytes) -> tuple[CompressedImage, bool]:
    """One hostile sensor_msgs/CompressedImage and whether it must get a mask."""
    cases = [
        ("jpeg", rng.integers(0, 255, 200, dtype=np.uint8).tobytes(), False),  # garbage
        ("jpeg", jpeg[: len(jpeg) // 3], False),   # truncated: cv2.imdecode gives nothing
        ("png", bomb, False),                       # 8192x8192 declared: refused from its header
        ("jpeg", b"", False),                        # empty
        ("gif89", jpeg, False),                     # unsupported format string
        ("png", cv2_png(rng.integers(0, 255, (8, 64), dtype=np.uint8)), True),  # decodable but too small
    ]
    fmt, data, expect = cases[kind % len(cases)]
    return CompressedImage(header=_header(stamp_ns), format=fmt, data=data), expect


def cv2_png(array: np.ndarray) -> bytes:
    import cv2

    return cv2.imencode(".png", array)[1].tobytes()


def _run(probe: _Probe, messages: list[tuple[object, bool]], valid_every: int, valid: list[object]) -> list[int]:
    """Publish the hostile messages in bursts, each burst followed by a valid frame waited for; returns the
    stamps that must be answered, in order."""
    expected: list[int] = []
    for start in range(0, len(messages), valid_every):
        for msg, expect in messages[start:start + valid_every]:
            probe.publisher.publish(msg)
            if expect:
                expected.append(stamp_to_ns(msg.header.stamp))
        frame = valid[(start // valid_every) % len(valid)]
        expected.append(stamp_to_ns(frame.header.stamp))
        probe.send_and_wait(frame, expect_mask=True, timeout=20.0)
        probe.spin_until(lambda: len(probe.masks) >= len(expected), 20.0)
    return expected


def _check_run(probe: _Probe, process, log, expected: list[int], sent: int, bad: int) -> None:
    assert probe.spin_until(lambda: len(probe.masks) >= len(expected), 30), (len(probe.masks), len(expected))
    assert probe.spin_until(lambda: probe.diagnostics.get("frames_in") == str(sent)
                            and probe.diagnostics.get("queued") == "0", 15), probe.diagnostics
    probe.spin_until(lambda: False, 1.5)  # one more diagnostics period
    d = probe.diagnostics
    assert int(d["bad_input"]) == bad and int(d["dropped"]) == 0 and int(d["failures"]) == 0, d
    assert int(d["frames_out"]) == len(expected), d
    assert [stamp_to_ns(m.header.stamp) for m in probe.masks] == expected  # every valid frame, its own header
    assert process.poll() is None, log.read_text()[-2000:]
    process.send_signal(signal.SIGINT)
    assert process.wait(timeout=15) == 0
    assert "Traceback" not in log.read_text()


def _survive(ros_domain: int, tmp_path, monkeypatch, params: list[str], message_type: type,
             messages: list[tuple[object, bool]], valid: list[object]) -> None:
    """Start the node, send the hostile messages between valid frames, check every count, stop it by SIGINT."""
    log = tmp_path / "log"
    process = start_segmenter(ros_domain, log, params=PARAMS + params)
    probe = _Probe(ros_domain, monkeypatch, message_type)
    try:
        assert probe.wait_for_node(), log.read_text()
        expected = _run(probe, messages, 40, valid)
        decodable = sum(expect for _, expect in messages)
        _check_run(probe, process, log, expected, sent=len(messages) + len(expected) - decodable,
                   bad=len(messages) - decodable)
    finally:
        probe.close()
        if process.poll() is None:
            process.kill()


def test_thousands_of_hostile_raw_images(ros_domain, tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    # stamps go up, but now and then back in time (a looping bag): those frames reset the window
    stamps = np.cumsum(rng.integers(1, 3, N_RAW)) * 10_000_000
    stamps[rng.choice(N_RAW, N_RAW // 50, replace=False)] -= 5 * SECOND
    messages = [hostile_raw(rng, int(max(stamps[i], 1)), i) for i in range(N_RAW)]
    valid = [_image_at(frame, (1000 + i) * SECOND) for i, frame in enumerate(textured_frames(8))]
    valid += [_image_at(frame, (2000 + i) * SECOND) for i, frame in enumerate(textured_frames(8, seed=1))]
    _survive(ros_domain, tmp_path, monkeypatch, [], Image, messages, valid)


def test_a_thousand_hostile_compressed_images(ros_domain, tmp_path, monkeypatch):
    import cv2

    rng = np.random.default_rng(1)
    bomb = cv2_png(np.zeros((8192, 8192), np.uint8))
    frames = textured_frames(6)
    jpeg = cv2.imencode(".jpg", frames[0])[1].tobytes()
    messages = [hostile_compressed(rng, (10 + i) * 10_000_000, i, bomb, jpeg) for i in range(N_COMPRESSED)]
    valid = [CompressedImage(header=_header((1000 + i) * SECOND), format="jpeg",
                             data=cv2.imencode(".jpg", f)[1].tobytes()) for i, f in enumerate(frames)]
    _survive(ros_domain, tmp_path, monkeypatch, ["compressed_input:=true"], CompressedImage, messages, valid)


def _image_at(frame: np.ndarray, stamp_ns: int) -> Image:
    from moseg_ros.io.image import image_from_array

    return image_from_array(Image, frame, "rgb8", _header(stamp_ns))
