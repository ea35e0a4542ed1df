"""Tests of moseg_ros.io.kitti (`moseg kitti2bag`): real KITTI odometry 07 and a tiny KITTI-raw folder."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest

from moseg_ros.io import kitti
from moseg_ros.io.bags import iter_messages, read_images, stamp_to_ns
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


def test_odometry_sequence_to_bag(tmp_path: Path) -> None:
    src = odometry_or_skip()
    out = tmp_path / "odom07"
    counts = kitti_to_bag(src, out, limit=10)
    assert counts == {"/camera/image_raw": 10, "/camera/camera_info": 10}
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
    assert "/camera/image_raw: 2 messages" in capsys.readouterr().out
    assert kitti.run(parser.parse_args([str(drive), "-o", str(tmp_path / "bag")])) == 2
    assert "already exists" in capsys.readouterr().err
    assert kitti.run(parser.parse_args([str(drive), "-o", str(tmp_path / "b2"), "--camera", "03"])) == 2
    assert "camera '03'" in capsys.readouterr().err
