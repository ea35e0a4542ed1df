"""Tests of moseg_ros.io.bags: BagWriter output read back by rosbags, by mcap and by our readers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from moseg_ros.io.bag_images import Calibration, camera_info_topic, image_camera, pick_image_topic, read_images
from moseg_ros.io.bag_writer import BagWriter
from moseg_ros.io.bags import BagDamagedError, iter_messages, list_topics, ns_to_stamp_fields, stamp_to_ns

T0 = 1_317_384_506_123_456_789  # a 2011 UTC stamp with nanosecond digits
DT = 100_000_000
N = 4
K = np.array([[707.0912, 0.0, 601.8873], [0.0, 707.0912, 183.1104], [0.0, 0.0, 1.0]])


def frames(n: int = N) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    return [rng.integers(0, 256, (6, 8, 3), dtype=np.uint8) for _ in range(n)]


def poses(n: int = N) -> list[np.ndarray]:
    out = []
    for i in range(n):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", [0.1 * i, -0.2, 0.05 * i]).as_matrix()
        T[:3, 3] = [i, 2.0 * i, -0.5]
        out.append(T)
    return out


def write_street_bag(path: Path, storage: str = "mcap") -> dict[str, int]:
    with BagWriter(path, storage=storage) as writer:
        for i, (rgb, T) in enumerate(zip(frames(), poses())):
            stamp = T0 + i * DT
            writer.write_image("/camera/image_raw", stamp, "camera", rgb, "rgb8")
            writer.write_camera_info("/camera/camera_info", stamp, "camera", K, 8, 6)
            writer.write_image("/gt/instances", stamp, "camera", np.full((6, 8), i - 1, np.int32), "32SC1")
            writer.write_pose("/gt/pose", stamp, "world", T, log_time_ns=stamp + 5)
        return dict(writer.counts)


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "street"
    counts = write_street_bag(path)
    assert counts == {"/camera/image_raw": N, "/camera/camera_info": N, "/gt/instances": N, "/gt/pose": N}
    return path


def test_rosbags_reads_back_everything(bag: Path) -> None:
    with AnyReader([bag]) as reader:
        topics = {t: (i.msgtype, i.msgcount) for t, i in reader.topics.items()}
        assert topics == {"/camera/image_raw": ("sensor_msgs/msg/Image", N),
                          "/camera/camera_info": ("sensor_msgs/msg/CameraInfo", N),
                          "/gt/instances": ("sensor_msgs/msg/Image", N),
                          "/gt/pose": ("geometry_msgs/msg/PoseStamped", N)}
        seen = {topic: [] for topic in topics}
        for connection, log_time, raw in reader.messages():
            seen[connection.topic].append((log_time, reader.deserialize(raw, connection.msgtype)))
    for i, (rgb, (log_time, msg)) in enumerate(zip(frames(), seen["/camera/image_raw"])):
        assert log_time == T0 + i * DT == stamp_to_ns(msg.header.stamp)
        assert msg.header.frame_id == "camera" and msg.encoding == "rgb8" and msg.step == 24
        np.testing.assert_array_equal(msg.data.reshape(6, 8, 3), rgb)
    info = seen["/camera/camera_info"][2][1]
    np.testing.assert_allclose(info.k.reshape(3, 3), K)
    np.testing.assert_allclose(info.p.reshape(3, 4)[:, :3], K)
    assert (info.width, info.height, info.distortion_model) == (8, 6, "plumb_bob")
    for i, (T, (log_time, msg)) in enumerate(zip(poses(), seen["/gt/pose"])):
        assert log_time == T0 + i * DT + 5 and stamp_to_ns(msg.header.stamp) == T0 + i * DT
        q = msg.pose.orientation
        np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), T[:3, :3], atol=1e-12)
        p = msg.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], T[:3, 3])
        assert msg.header.frame_id == "world"


def test_mcap_library_sees_channels_and_schemas(bag: Path) -> None:
    (mcap_file,) = bag.glob("*.mcap")
    with mcap_file.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        channels = {c.topic: (summary.schemas[c.schema_id].name, summary.schemas[c.schema_id].encoding,
                              c.message_encoding) for c in summary.channels.values()}
        assert channels["/camera/image_raw"] == ("sensor_msgs/msg/Image", "ros2msg", "cdr")
        assert channels["/gt/pose"] == ("geometry_msgs/msg/PoseStamped", "ros2msg", "cdr")
        assert len(channels) == 4
        assert summary.statistics.message_count == 4 * N
        image_schema = next(s for s in summary.schemas.values() if s.name == "sensor_msgs/msg/Image")
        # Foxglove resolves nested types from the schema text itself.
        assert "MSG: std_msgs/Header" in image_schema.data.decode()
        assert sum(1 for _ in reader.iter_messages(topics=["/camera/image_raw"])) == N


@pytest.mark.parametrize("which", ["folder", "bare_mcap"])
def test_read_images_from_folder_and_bare_mcap(bag: Path, which: str) -> None:
    path = bag if which == "folder" else next(bag.glob("*.mcap"))
    images = list(read_images(path))
    assert [im.topic for im in images] == ["/camera/image_raw"] * N
    for i, (rgb, im) in enumerate(zip(frames(), images)):
        assert (im.stamp_ns, im.log_time_ns, im.frame_id) == (T0 + i * DT, T0 + i * DT, "camera")
        pixels, encoding = im.decoded
        assert encoding == "rgb8" and not im.compressed
        np.testing.assert_array_equal(pixels, rgb)
        np.testing.assert_array_equal(im.rgb(), rgb)
        assert im.gray().shape == (6, 8)
    labels = [im.decoded[0] for im in read_images(path, "/gt/instances")]
    assert [int(lab[0, 0]) for lab in labels] == [-1, 0, 1, 2] and labels[0].dtype == np.int32


def test_iter_messages_is_in_log_time_order(tmp_path: Path) -> None:
    path = tmp_path / "unordered"
    with BagWriter(path) as writer:
        for log_time in [50, 10, 40, 20, 30]:
            writer.write_pose("/a" if log_time % 20 else "/b", log_time, "w", np.eye(4), log_time_ns=log_time)
    for source in (path, next(path.glob("*.mcap"))):
        got = [(topic, t, stamp_to_ns(msg.header.stamp)) for topic, t, msg in iter_messages(source)]
        assert [t for _, t, _ in got] == [10, 20, 30, 40, 50]
        assert [topic for topic, _, _ in got] == ["/a", "/b", "/a", "/b", "/a"]
        assert all(t == stamp for _, t, stamp in got)
        assert [t for _, t, _ in iter_messages(source, ["/b"])] == [20, 40]


def test_sqlite3_storage_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "db"
    write_street_bag(path, storage="sqlite3")
    assert len(list(path.glob("*.db3"))) == 1
    assert list_topics(path)["/gt/pose"] == "geometry_msgs/msg/PoseStamped"
    images = list(read_images(path))
    assert len(images) == N
    np.testing.assert_array_equal(images[-1].decoded[0], frames()[-1])
    assert images[-1].stamp_ns == T0 + (N - 1) * DT


def test_ros1_bag_is_readable(tmp_path: Path) -> None:
    path = tmp_path / "old.bag"
    typestore = get_typestore(Stores.ROS1_NOETIC)
    types = typestore.types
    mono = np.arange(12, dtype=np.uint8).reshape(3, 4)
    with Ros1Writer(path) as writer:
        connection = writer.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=typestore)
        for i in range(3):
            sec, nanosec = ns_to_stamp_fields(T0 + i * DT)
            header = types["std_msgs/msg/Header"](seq=i, stamp=types["builtin_interfaces/msg/Time"](
                sec=sec, nanosec=nanosec), frame_id="cam")
            msg = types["sensor_msgs/msg/Image"](header=header, height=3, width=4, encoding="mono8",
                                                 is_bigendian=0, step=4, data=(mono + i).reshape(-1))
            writer.write(connection, T0 + i * DT, typestore.serialize_ros1(msg, "sensor_msgs/msg/Image"))
    assert list_topics(path) == {"/cam/image": "sensor_msgs/msg/Image"}
    images = list(read_images(path))
    assert [im.stamp_ns for im in images] == [T0 + i * DT for i in range(3)]
    np.testing.assert_array_equal(images[2].gray(), mono + 2)


def test_compressed_images_are_read(tmp_path: Path) -> None:
    cv2 = pytest.importorskip("cv2")
    path = tmp_path / "compressed"
    rgb = frames(1)[0]
    with BagWriter(path) as writer:
        types = writer.typestore.types
        msg = types["sensor_msgs/msg/CompressedImage"](
            header=writer.header(T0, "cam"), format="png",
            data=np.frombuffer(cv2.imencode(".png", rgb[:, :, ::-1])[1].tobytes(), np.uint8))
        writer.write("/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", msg, T0)
    (image,) = read_images(path)
    assert image.compressed and image.decoded[1] == "rgb8" and image.stamp_ns == T0
    np.testing.assert_array_equal(image.rgb(), rgb)


def test_pick_image_topic_rules() -> None:
    image, compressed, info = "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"
    assert pick_image_topic({"/cam": image, "/gt/instances": image, "/cam/info": info}) == "/cam"
    assert pick_image_topic({"/cam/compressed": compressed, "/gt/dynamic_mask": image}) == "/cam/compressed"
    assert pick_image_topic({"/camera/image_raw": image, "/other": image}) == "/camera/image_raw"
    assert pick_image_topic({"/a": image, "/b": image}, "/b") == "/b"
    assert pick_image_topic({"/a": "sensor_msgs/Image"}) == "/a"  # ROS 1 style type name
    with pytest.raises(ValueError, match=r"several image topics, choose one: \['/a', '/b'\]"):
        pick_image_topic({"/a": image, "/b": image})
    with pytest.raises(ValueError, match=r"'/c' not in the bag; available: \['/a', '/b'\]"):
        pick_image_topic({"/a": image, "/b": info}, "/c")
    with pytest.raises(ValueError, match="is sensor_msgs/msg/CameraInfo, not sensor_msgs/Image"):
        pick_image_topic({"/a": image, "/b": info}, "/b")
    with pytest.raises(ValueError, match="no image topic"):
        pick_image_topic({"/gt/instances": image, "/b": info})


def test_camera_info_topic_is_the_one_beside_the_image() -> None:
    image, info = "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo"
    beside = camera_info_topic({"/cam/image_raw": image, "/cam/camera_info": info}, "/cam/image_raw")
    assert beside == "/cam/camera_info"
    assert camera_info_topic({"/cam/image_raw": image, "/other/camera_info": info}, "/cam/image_raw") is None
    assert camera_info_topic({"/cam/image_raw": image, "/cam/camera_info": image}, "/cam/image_raw") is None


class TestCalibration:
    @staticmethod
    def bag(tmp_path: Path) -> Path:
        """camera_info at T0 (K, 1242x375), T0 + 2 DT (a zero K: invalid), T0 + 3 DT (2 K, 621x188)."""
        path = tmp_path / "calib"
        with BagWriter(path) as writer:
            writer.write_camera_info("/cam/camera_info", T0, "cam", K, 1242, 375, log_time_ns=T0)
            writer.write_camera_info("/cam/camera_info", T0 + 2 * DT, "cam", np.zeros((3, 3)), 1242, 375,
                                     log_time_ns=T0 + 2 * DT)
            writer.write_camera_info("/cam/camera_info", T0 + 3 * DT, "cam", K / 2, 621, 188,
                                     log_time_ns=T0 + 3 * DT)
        return path

    def test_the_newest_valid_k_for_the_frames_size(self, tmp_path: Path) -> None:
        calibration = Calibration(self.bag(tmp_path), "/cam/camera_info")
        assert calibration.at(T0 - 1, (375, 1242)) is None                      # before the first
        np.testing.assert_array_equal(calibration.at(T0, (375, 1242, 3)), K)    # logged at the same time
        np.testing.assert_array_equal(calibration.at(T0 + DT, (375, 1242)), K)  # kept until the next
        assert calibration.at(T0 + 2 * DT, (375, 1242)) is None                 # an invalid K is none
        assert calibration.at(T0 + 3 * DT, (375, 1242)) is None                 # a K for another size
        np.testing.assert_array_equal(calibration.at(T0 + 4 * DT, (188, 621)), K / 2)

    def test_no_topic_no_calibration(self, tmp_path: Path) -> None:
        calibration = Calibration(self.bag(tmp_path), None)
        assert calibration.topic is None and calibration.at(T0, (375, 1242)) is None


def test_image_camera_pairs_the_image_topic_with_the_camera_info_beside_it(tmp_path: Path) -> None:
    path = tmp_path / "camera"
    with BagWriter(path) as writer:
        writer.write_image("/cam/image_raw", T0, "cam", np.zeros((375, 1242), np.uint8), "mono8", log_time_ns=T0)
        writer.write_image("/gt/dynamic_mask", T0, "cam", np.zeros((375, 1242), np.uint8), "mono8", log_time_ns=T0)
        writer.write_camera_info("/cam/camera_info", T0, "cam", K, 1242, 375, log_time_ns=T0)
        writer.write_image("/other/image_raw", T0, "o", np.zeros((4, 4), np.uint8), "mono8", log_time_ns=T0)
    topic, calibration = image_camera(path, "/cam/image_raw")
    assert topic == "/cam/image_raw" and calibration.topic == "/cam/camera_info"
    np.testing.assert_array_equal(calibration.at(T0, (375, 1242)), K)
    topic, calibration = image_camera(path, "/other/image_raw")
    assert topic == "/other/image_raw" and calibration.topic is None and calibration.at(T0, (4, 4)) is None
    with pytest.raises(ValueError, match="several image topics"):
        image_camera(path)


def test_errors_are_specific(bag: Path, tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="bag not found"):
        list_topics(tmp_path / "nope")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ValueError, match="unknown bag format"):
        list_topics(tmp_path / "notes.txt")
    with pytest.raises(ValueError, match=r"topic\(s\) \['/missing'\] not in the bag"):
        list(iter_messages(bag, ["/missing"]))
    with pytest.raises(FileExistsError, match="already exists"):
        BagWriter(bag)
    with pytest.raises(ValueError, match="unknown bag storage"):
        BagWriter(tmp_path / "x", storage="zip")
    with BagWriter(tmp_path / "w") as writer:
        writer.write_pose("/p", 1, "w", np.eye(4))
        with pytest.raises(ValueError, match="already holds geometry_msgs/msg/PoseStamped"):
            writer.write_image("/p", 2, "c", np.zeros((2, 2), np.uint8), "mono8")
        with pytest.raises(ValueError, match="not a proper rotation"):
            writer.write_pose("/p", 3, "w", np.diag([1.0, 1.0, -1.0, 1.0]))
        with pytest.raises(ValueError, match="K must be 3x3"):
            writer.write_camera_info("/i", 3, "c", np.eye(2), 4, 4)
        assert writer.counts == {"/p": 1}


def test_stamp_helpers_round_trip() -> None:
    types = get_typestore(Stores.ROS2_JAZZY).types
    for ns in [0, 1, 999_999_999, 1_000_000_000, T0, -1, -1_500_000_000]:
        sec, nanosec = ns_to_stamp_fields(ns)
        assert 0 <= nanosec < 1_000_000_000
        assert stamp_to_ns(types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)) == ns


def _mask_bag(path: Path, n: int, storage: str = "mcap") -> list[np.ndarray]:
    """A bag of n sparse 375x1242 mono8 masks, about 1.9 MB of chunk data uncompressed every four frames."""
    rng = np.random.default_rng(5)
    masks = [((rng.random((375, 1242)) > 0.97) * 255).astype(np.uint8) for _ in range(n)]
    with BagWriter(path, storage=storage) as writer:
        for i, mask in enumerate(masks):
            writer.write_image("/segmenter/dynamic_mask", T0 + i * DT, "camera", mask, "mono8")
    return masks


def _read_until_damage(path: Path) -> tuple[list[np.ndarray], BagDamagedError | None]:
    images: list[np.ndarray] = []
    try:
        for image in read_images(path):
            images.append(image.gray())
    except BagDamagedError as error:
        return images, error
    return images, None


class TestOutputCompression:
    def test_mcap_chunks_are_zstd_and_small(self, tmp_path: Path) -> None:
        masks = _mask_bag(tmp_path / "z", 12)
        with (tmp_path / "z" / "z.mcap").open("rb") as stream:
            summary = make_reader(stream).get_summary()
        assert len(summary.chunk_indexes) >= 2
        assert {chunk.compression for chunk in summary.chunk_indexes} == {"zstd"}
        assert (tmp_path / "z" / "z.mcap").stat().st_size < 0.3 * sum(m.nbytes for m in masks)
        with BagWriter(tmp_path / "plain", compression=None) as writer:
            writer.write_image("/m", 1, "c", masks[0], "mono8")
        with (tmp_path / "plain" / "plain.mcap").open("rb") as stream:
            assert {c.compression for c in make_reader(stream).get_summary().chunk_indexes} == {""}

    def test_compressed_bag_reads_back_in_rosbags_and_ours(self, tmp_path: Path) -> None:
        masks = _mask_bag(tmp_path / "z", 6)
        with AnyReader([tmp_path / "z"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            assert sum(1 for _ in reader.messages()) == 6
        images, damage = _read_until_damage(tmp_path / "z")
        assert damage is None and all(np.array_equal(a, b) for a, b in zip(images, masks, strict=True))

    def test_unknown_compression_is_refused(self, tmp_path: Path) -> None:
        with pytest.raises(ValueError, match="unknown bag compression 'lzma'"):
            BagWriter(tmp_path / "x", compression="lzma")


class TestDamagedBags:
    def test_killed_writer_leaves_complete_chunks_readable(self, tmp_path: Path) -> None:
        """A writer killed mid-run leaves no metadata.yaml and no MCAP summary: what it flushed is read."""
        masks = _mask_bag(tmp_path / "full", 20)
        killed = tmp_path / "killed"
        killed.mkdir()
        data = (tmp_path / "full" / "full.mcap").read_bytes()
        (killed / "killed.mcap").write_bytes(data[:len(data) // 2])
        images, damage = _read_until_damage(killed)
        assert damage is not None and "ends inside a record" in str(damage)
        assert damage.messages_read == len(images) and 4 <= len(images) < 20
        assert all(np.array_equal(a, b) for a, b in zip(images, masks))

    def test_truncated_rosbag2_folder_with_metadata(self, tmp_path: Path) -> None:
        masks = _mask_bag(tmp_path / "t", 20)
        file = tmp_path / "t" / "t.mcap"
        file.write_bytes(file.read_bytes()[:file.stat().st_size // 2])
        assert list_topics(tmp_path / "t") == {"/segmenter/dynamic_mask": "sensor_msgs/msg/Image"}
        images, damage = _read_until_damage(tmp_path / "t")
        assert damage is not None and 4 <= len(images) < 20
        assert all(np.array_equal(a, b) for a, b in zip(images, masks))

    def test_corrupted_chunk_stops_reading_there(self, tmp_path: Path) -> None:
        masks = _mask_bag(tmp_path / "c", 20)
        file = tmp_path / "c" / "c.mcap"
        data = bytearray(file.read_bytes())
        middle = len(data) // 2
        data[middle:middle + 4000] = bytes(b ^ 0x5A for b in data[middle:middle + 4000])
        file.write_bytes(bytes(data))
        images, damage = _read_until_damage(tmp_path / "c")
        assert damage is not None and damage.path == tmp_path / "c"
        assert 4 <= len(images) < 20 and all(np.array_equal(a, b) for a, b in zip(images, masks))

    def test_truncated_sqlite3_and_ros1_bags_raise_bag_damaged(self, tmp_path: Path) -> None:
        _mask_bag(tmp_path / "db", 8, storage="sqlite3")
        (db,) = (tmp_path / "db").glob("*.db3")
        db.write_bytes(db.read_bytes()[:db.stat().st_size // 3])
        images, damage = _read_until_damage(tmp_path / "db")
        assert damage is not None and len(images) < 8
        ros1 = tmp_path / "old.bag"
        ros1.write_bytes(b"#ROSBAG V2.0\n" + bytes(200))
        with pytest.raises(BagDamagedError, match="old.bag is damaged"):
            list_topics(ros1)
