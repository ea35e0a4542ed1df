"""Tests of moseg_ros.io.kitti (`moseg kitti2bag`): real KITTI odometry 07 (with its ground-truth poses) and
tiny KITTI-raw and odometry folders."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import shared_data
from scipy.spatial.transform import Rotation

from moseg_ros.io import kitti
from moseg_ros.io.bag_images import read_images
from moseg_ros.io.bags import iter_messages, list_topics, stamp_to_ns
from moseg_ros.io.kitti import kitti_to_bag

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
ODOM07 = DATA / "kitti_odom07"

RAW_STAMPS = ["2011-09-26 13:02:25.964389445", "2011-09-26 13:02:26.074456200", "2011-09-26 13:02:26.184522"]
P_RECT_02 = np.array([[721.5377, 0.0, 609.5593, 44.85728], [0.0, 721.5377, 172.854, 0.2163791],
                      [0.0, 0.0, 1.0, 0.002745884]])


def odometry_or_skip() -> Path:
    if not (ODOM07 / "image_0").is_dir():
        pytest.skip(f"KITTI odometry 07 data absent: {ODOM07}")
    return ODOM07


def calib_line(key: str, values: np.ndarray) -> str:
    return f"{key}: " + " ".join(f"{v:.6e}" for v in np.ravel(values))


K_02 = np.array([[959.8, 0.0, 696.0], [0.0, 956.9, 224.2], [0.0, 0.0, 1.0]])
D_02 = np.array([-0.37, 0.20, 0.0022, 0.0014, -0.07])


def make_raw_drive(root: Path, n: int = 3, *, width: int = 10, height: int = 6,
                   rect_size: tuple[int, int] | None = None) -> tuple[Path, list[np.ndarray]]:
    """A KITTI raw layout: <date>/calib_cam_to_cam.txt and <date>/<drive>/image_02/{data/*.png,timestamps.txt}."""
    drive = root / "2011_09_26" / "2011_09_26_drive_0001_sync"
    (drive / "image_02" / "data").mkdir(parents=True)
    rng = np.random.default_rng(5)
    images = [rng.integers(0, 256, (height, width, 3), dtype=np.uint8) for _ in range(n)]
    for i, rgb in enumerate(images):
        cv2.imwrite(str(drive / "image_02" / "data" / f"{i:010d}.png"), rgb[:, :, ::-1])
    (drive / "image_02" / "timestamps.txt").write_text("\n".join(RAW_STAMPS[:n]) + "\n")
    (drive.parent / "calib_cam_to_cam.txt").write_text("\n".join([
        "calib_time: 09-Jan-2012 13:57:47",
        calib_line("S_02", [width, height]),
        calib_line("K_02", K_02),
        calib_line("D_02", D_02),
        calib_line("S_rect_02", rect_size or (width, height)),
        calib_line("P_rect_02", P_RECT_02),
    ]) + "\n")
    return drive, images


P0_SMALL = np.array([[7.0, 0.0, 5.0, 0.0], [0.0, 7.0, 3.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


def synthetic_pose(i: int) -> np.ndarray:
    """Camera-to-world of frame i of the synthetic odometry sequence: turning left while driving forward."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("y", 0.05 * i).as_matrix()
    T[:3, 3] = [0.1 * i, -0.01 * i, 0.5 * i]
    return T


def pose_text(poses: list[np.ndarray], *, with_stamps: bool = False) -> str:
    """KITTI pose-file lines (12 values, or 13 with a leading timestamp) that parse back to exactly ``poses``."""
    return "".join((f"{0.1 * i!r} " if with_stamps else "") + " ".join(repr(float(v)) for v in T[:3].ravel()) + "\n"
                   for i, T in enumerate(poses))


def make_odometry_sequence(root: Path, frames: range = range(3), n_lines: int = 10) -> tuple[Path, list[np.ndarray]]:
    """A KITTI odometry layout root/dataset/sequences/07/{image_0/<frames>.png,times.txt,calib.txt} (no pose file);
    returns the sequence folder and the ``n_lines`` poses of the whole sequence (frame i = line i)."""
    seq = root / "dataset" / "sequences" / "07"
    (seq / "image_0").mkdir(parents=True)
    rng = np.random.default_rng(7)
    for i in frames:
        cv2.imwrite(str(seq / "image_0" / f"{i:06d}.png"), rng.integers(0, 256, (6, 10), dtype=np.uint8))
    (seq / "times.txt").write_text("".join(f"{0.1 * i:.6e}\n" for i in range(n_lines)))
    (seq / "calib.txt").write_text(calib_line("P0", P0_SMALL) + "\n")
    return seq, [synthetic_pose(i) for i in range(n_lines)]


def read_poses(bag: Path) -> tuple[list[int], set[str], np.ndarray]:
    """(header stamps, frame_ids, camera-to-world 4x4 transforms) of the bag's /gt/pose messages."""
    msgs = [msg for _, _, msg in iter_messages(bag, ["/gt/pose"])]
    poses = np.tile(np.eye(4), (len(msgs), 1, 1))
    for T, msg in zip(poses, msgs):
        q, t = msg.pose.orientation, msg.pose.position
        T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        T[:3, 3] = [t.x, t.y, t.z]
    return [stamp_to_ns(m.header.stamp) for m in msgs], {m.header.frame_id for m in msgs}, poses


def image_stamps(bag: Path, topic: str = "/camera/image_raw") -> list[int]:
    return [stamp_to_ns(msg.header.stamp) for _, _, msg in iter_messages(bag, [topic])]


def assert_poses_equal(got: np.ndarray, expected: list[np.ndarray]) -> None:
    """Translations exactly (float64 all the way), rotations up to the quaternion round trip."""
    np.testing.assert_array_equal(got[:, :3, 3], np.array(expected)[:, :3, 3])
    np.testing.assert_allclose(got[:, :3, :3], np.array(expected)[:, :3, :3], atol=1e-12)


def test_odometry_sequence_to_bag(tmp_path: Path) -> None:
    src = odometry_or_skip()
    out = tmp_path / "odom07"
    counts = kitti_to_bag(src, out, limit=10)  # poses_07_with_timestamps.txt beside the frames is found
    assert counts == {"/camera/image_raw": 10, "/camera/camera_info": 10, "/gt/pose": 10}
    times = np.loadtxt(src / "times.txt")[:10]
    P0 = np.array([float(v) for v in (src / "calib.txt").read_text().splitlines()[0].split()[1:]]).reshape(3, 4)
    images = list(read_images(out))
    assert [im.stamp_ns for im in images] == [round(t * 1e9) for t in times]
    for im, name in zip(images[:3], ["000000.png", "000001.png", "000002.png"]):
        pixels, encoding = im.decoded
        assert encoding == "mono8" and pixels.shape == (370, 1226) and im.frame_id == "camera"
        np.testing.assert_array_equal(pixels, cv2.imread(str(src / "image_0" / name), cv2.IMREAD_UNCHANGED))
    infos = [msg for _, _, msg in iter_messages(out, ["/camera/camera_info"])]
    assert [stamp_to_ns(m.header.stamp) for m in infos] == [im.stamp_ns for im in images]
    K = infos[0].k.reshape(3, 3)
    assert K[0, 0] == pytest.approx(707.0912) and K[1, 1] == pytest.approx(707.0912)
    np.testing.assert_allclose(K, P0[:, :3])
    np.testing.assert_allclose(infos[0].p.reshape(3, 4), P0)
    assert (infos[0].width, infos[0].height) == (1226, 370)


def test_odometry_ground_truth_poses(tmp_path: Path) -> None:
    """All 160 real frames of odometry 07 with the 13-value pose file: one /gt/pose per image at its stamp."""
    src = shared_data("kitti_odom07")
    pose_file = src / "poses_07_with_timestamps.txt"
    out = tmp_path / "odom07"
    counts = kitti_to_bag(src, out, poses=pose_file)
    assert counts == {"/camera/image_raw": 160, "/camera/camera_info": 160, "/gt/pose": 160}
    stamps, frame_ids, poses = read_poses(out)
    assert stamps == image_stamps(out)
    assert stamps == [round(t * 1e9) for t in np.loadtxt(src / "times.txt")[:160]]
    assert frame_ids == {"world"}
    lines = np.loadtxt(pose_file)[:160, 1:].reshape(160, 3, 4)
    np.testing.assert_array_equal(poses[:, :3, 3], lines[:, :, 3])
    # The file's rotations are orthonormal to ~2e-7 only, so the quaternion round trip moves them that much.
    np.testing.assert_allclose(poses[:, :3, :3], lines[:, :, :3], atol=1e-6)
    # Line 2 (frame 1) and line 160 (frame 159) of the file, verbatim.
    assert tuple(poses[1, :3, 3]) == (-0.004596714, -0.002001524, 0.09154274)
    assert tuple(poses[159, :3, 3]) == (-76.96463, 0.9352274, 15.68785)
    assert poses[159, 0, 0] == pytest.approx(0.9926196, abs=1e-6)


def test_odometry_poses_found_and_matched_by_frame_number(tmp_path: Path) -> None:
    """A subset of frames 4..7: dataset/poses/07.txt is found and frame i gets line i, also with --limit."""
    seq, poses = make_odometry_sequence(tmp_path, frames=range(4, 8))
    pose_file = tmp_path / "dataset" / "poses" / "07.txt"
    pose_file.parent.mkdir()
    pose_file.write_text(pose_text(poses))
    assert kitti.find_poses(seq) == pose_file
    out = tmp_path / "bag"
    counts = kitti_to_bag(seq, out, limit=3)
    assert counts == {"/camera/image_raw": 3, "/camera/camera_info": 3, "/gt/pose": 3}
    stamps, frame_ids, got = read_poses(out)
    assert stamps == image_stamps(out) == [400_000_000, 500_000_000, 600_000_000]
    assert frame_ids == {"world"}
    assert_poses_equal(got, poses[4:7])


def test_pose_file_places(tmp_path: Path) -> None:
    seq, poses = make_odometry_sequence(tmp_path)
    assert kitti.find_poses(seq) is None
    counts = kitti_to_bag(seq, tmp_path / "no_poses")
    assert counts == {"/camera/image_raw": 3, "/camera/camera_info": 3}
    assert "/gt/pose" not in list_topics(tmp_path / "no_poses")
    for place in (seq.parent / "poses" / "07.txt", seq / "poses" / "07.txt", seq / "poses.txt"):
        place.parent.mkdir(exist_ok=True)
        place.write_text(pose_text(poses))
        assert kitti.find_poses(seq) == place
        place.unlink()


def test_cli_poses_with_timestamps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq, poses = make_odometry_sequence(tmp_path)
    pose_file = tmp_path / "gt_with_stamps.txt"
    pose_file.write_text(pose_text(poses, with_stamps=True))
    parser = argparse.ArgumentParser()
    kitti.add_arguments(parser)
    assert kitti.run(parser.parse_args([str(seq), "-o", str(tmp_path / "bag"), "--poses", str(pose_file)])) == 0
    out = capsys.readouterr().out
    assert "/gt/pose: 3 messages" in out and "no pose file" not in out
    stamps, _, got = read_poses(tmp_path / "bag")
    assert stamps == image_stamps(tmp_path / "bag") == [0, 100_000_000, 200_000_000]
    assert_poses_equal(got, poses[:3])


def test_bad_pose_files(tmp_path: Path) -> None:
    seq, poses = make_odometry_sequence(tmp_path, frames=range(4, 8))
    pose_file = tmp_path / "gt.txt"
    out = tmp_path / "out"
    good = pose_text(poses).splitlines(keepends=True)
    scaled, reflected = 2.0 * poses[1], poses[2] @ np.diag([1.0, 1.0, -1.0, 1.0])
    cases = [
        (good[:1] + [good[1].rsplit(" ", 1)[0] + "\n"] + good[2:], r"gt.txt:2: 11 values, expected 12"),
        (good[:2] + pose_text(poses[2:3], with_stamps=True).splitlines(keepends=True) + good[3:],
         r"gt.txt:3: 13 values, but line 1 has 12"),
        (["1 0 0 0 0 1 0 0 0 0 1 zero\n"] + good[1:], r"gt.txt:1: not a list of numbers"),
        (good[:7], r"pose count mismatch: .*gt.txt has 7 poses but frame 000007.png needs line 8"),
        (good[:1] + pose_text([scaled]).splitlines(keepends=True) + good[2:],
         r"gt.txt:2: the 3x3 part is not a rotation matrix \(det 8,"),
        (good[:2] + pose_text([reflected]).splitlines(keepends=True) + good[3:],
         r"gt.txt:3: the 3x3 part is not a rotation matrix \(det -1,"),
        (["\n"], r"gt.txt: no poses"),
    ]
    for lines, message in cases:
        pose_file.write_text("".join(lines))
        with pytest.raises(ValueError, match=message):
            kitti_to_bag(seq, out, poses=pose_file)
        assert not out.exists()
    with pytest.raises(FileNotFoundError, match="KITTI pose file not found: .*missing.txt"):
        kitti_to_bag(seq, out, poses=tmp_path / "missing.txt")
    assert not out.exists()


def test_raw_drive_to_bag(tmp_path: Path) -> None:
    drive, images = make_raw_drive(tmp_path)
    out = tmp_path / "raw_bag"
    counts = kitti_to_bag(drive, out, topic="/cam2/image", info_topic="/cam2/info", frame_id="cam2")
    assert counts == {"/cam2/image": 3, "/cam2/info": 3}
    read = list(read_images(out))
    expected = [int(np.datetime64(s.replace(" ", "T"), "ns").astype(np.int64)) for s in RAW_STAMPS]
    assert [im.stamp_ns for im in read] == expected
    for im, rgb in zip(read, images):
        pixels, encoding = im.decoded
        assert encoding == "rgb8" and im.frame_id == "cam2"
        np.testing.assert_array_equal(pixels, rgb)
    info = next(msg for _, _, msg in iter_messages(out, ["/cam2/info"]))
    np.testing.assert_allclose(info.k.reshape(3, 3), P_RECT_02[:, :3], rtol=1e-6)
    np.testing.assert_allclose(info.p.reshape(3, 4), P_RECT_02, rtol=1e-6)
    assert (info.width, info.height) == (10, 6)


def test_limit_and_layout_detection(tmp_path: Path) -> None:
    drive, _ = make_raw_drive(tmp_path)
    sequence = kitti.find_sequence(drive, limit=2)
    assert (sequence.layout, sequence.camera, len(sequence.images), sequence.size) == ("raw", "02", 2, (10, 6))


def test_unrectified_raw_frames_use_raw_camera_matrix(tmp_path: Path) -> None:
    drive, _ = make_raw_drive(tmp_path, width=12, height=8, rect_size=(10, 6))
    sequence = kitti.find_sequence(drive)
    np.testing.assert_allclose(sequence.K, K_02)
    np.testing.assert_allclose(sequence.D, D_02)
    assert sequence.size == (12, 8)


def test_timestamp_count_mismatch(tmp_path: Path) -> None:
    drive, _ = make_raw_drive(tmp_path)
    (drive / "image_02" / "timestamps.txt").write_text(RAW_STAMPS[0] + "\n")
    with pytest.raises(ValueError, match="timestamp count mismatch: .* has 1 entries but frame 0000000002.png"):
        kitti_to_bag(drive, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_bad_calibration_and_stamps(tmp_path: Path) -> None:
    drive, _ = make_raw_drive(tmp_path)
    calib = drive.parent / "calib_cam_to_cam.txt"
    text = calib.read_text()
    calib.write_text(text.replace("P_rect_02: ", "P_rect_02: 1.0 x "))
    with pytest.raises(ValueError, match="P_rect_02 is not a list of numbers"):
        kitti.find_sequence(drive)
    calib.write_text(text + "this line has no colon\n")
    with pytest.raises(ValueError, match=r"calib_cam_to_cam.txt:7: bad calibration line"):
        kitti.find_sequence(drive)
    calib.write_text(text.replace("S_rect_02: ", "S_rect_02: 3.0 "))
    with pytest.raises(ValueError, match="S_rect_02 has 3 numbers, expected 2"):
        kitti.find_sequence(drive)
    calib.unlink()
    with pytest.raises(FileNotFoundError, match="calibration file not found"):
        kitti.find_sequence(drive)
    make_raw_drive(tmp_path / "b")
    other = tmp_path / "b" / "2011_09_26" / "2011_09_26_drive_0001_sync"
    (other / "image_02" / "timestamps.txt").write_text("26/09/2011 13:02:25\n")
    with pytest.raises(ValueError, match="bad timestamp"):
        kitti.find_sequence(other)
    with pytest.raises(FileNotFoundError, match="neither a KITTI raw drive"):
        kitti.find_sequence(tmp_path / "b")


def test_cli_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drive, _ = make_raw_drive(tmp_path)
    parser = argparse.ArgumentParser()
    kitti.add_arguments(parser)
    assert kitti.run(parser.parse_args([str(drive), "-o", str(tmp_path / "bag"), "--limit", "2"])) == 0
    out = capsys.readouterr().out
    assert "/camera/image_raw: 2 messages" in out
    assert "/gt/pose: no pose file found (looked for " in out and "give one with --poses" in out
    assert kitti.run(parser.parse_args([str(drive), "-o", str(tmp_path / "bag")])) == 2
    assert "already exists" in capsys.readouterr().err
    assert kitti.run(parser.parse_args([str(drive), "-o", str(tmp_path / "b2"), "--camera", "03"])) == 2
    assert "camera '03'" in capsys.readouterr().err


def test_a_bag_cut_short_by_a_bad_frame_is_removed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Closed, a partial bag would look complete and block the rerun once the frame is mended."""
    drive, _ = make_raw_drive(tmp_path)
    damaged = drive / "image_02" / "data" / f"{1:010d}.png"
    damaged.write_bytes(b"not a png")
    parser = argparse.ArgumentParser()
    kitti.add_arguments(parser)
    assert kitti.run(parser.parse_args([str(drive), "-o", str(tmp_path / "bag")])) == 2
    assert str(damaged) in capsys.readouterr().err
    assert not (tmp_path / "bag").exists()
    make_raw_drive(tmp_path / "mended")
    assert kitti.run(parser.parse_args([str(tmp_path / "mended" / drive.relative_to(tmp_path)), "-o",
                                        str(tmp_path / "bag")])) == 0
    assert len(image_stamps(tmp_path / "bag")) == 3

