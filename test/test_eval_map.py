"""`moseg eval map`: COLMAP (pycolmap) with and without masks, and the trajectory errors it reports."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from moseg_ros.cli import main as moseg
from moseg_ros.eval.colmap import (Frames, colmap_camera, export_frames, extract_features, keypoints_by_image,
                                   run_colmap, write_colmap_masks)
from moseg_ros.eval.map import camera_centres, dynamic_landmark_pct, landmarks_by_instance, trajectory_errors
from moseg_ros.eval.masks import GT_DYNAMIC_TOPIC, masks_by_stamp

pycolmap = pytest.importorskip("pycolmap", reason="pycolmap is not installed (requirements.txt pins it)")


def _trajectory(n: int = 20) -> dict[int, np.ndarray]:
    poses = {}
    for i in range(n):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("y", 0.05 * i).as_matrix()
        T[:3, 3] = [0.3 * np.sin(0.2 * i), 0.0, 1.0 * i]
        poses[1_000 + i * 100_000_000] = T
    return poses


class TestTrajectoryErrors:
    def test_a_trajectory_against_itself_is_zero(self) -> None:
        poses = _trajectory()
        errors = trajectory_errors(poses, poses)
        assert errors["ate"] == pytest.approx(0.0, abs=1e-9) and errors["rpe"] == pytest.approx(0.0, abs=1e-9)

    def test_a_scaled_rotated_shifted_copy_is_zero_after_alignment(self) -> None:
        poses = _trajectory()
        S = np.eye(4)
        S[:3, :3] = 2.5 * Rotation.from_euler("xyz", [0.3, -1.1, 0.7]).as_matrix()
        S[:3, 3] = [4.0, -2.0, 7.0]
        moved = {}
        for stamp, T in poses.items():
            copy = np.eye(4)
            copy[:3, :3] = S[:3, :3] / 2.5 @ T[:3, :3]
            copy[:3, 3] = S[:3, :3] @ T[:3, 3] + S[:3, 3]
            moved[stamp] = copy
        errors = trajectory_errors(moved, poses)
        assert errors["ate"] == pytest.approx(0.0, abs=1e-6) and errors["rpe"] == pytest.approx(0.0, abs=1e-6)

    def test_noise_shows_and_too_few_frames_give_none(self) -> None:
        poses = _trajectory()
        rng = np.random.default_rng(0)
        noisy = {s: T.copy() for s, T in poses.items()}
        for T in noisy.values():
            T[:3, 3] += rng.normal(0, 0.1, 3)
        assert 0.05 < trajectory_errors(noisy, poses)["ate"] < 0.2
        two = dict(list(poses.items())[:2])
        assert trajectory_errors(two, two)["ate"] is None


class _Observation:
    def __init__(self, x: float, y: float, point: int) -> None:
        self.xy, self.point3D_id = np.array([x, y]), point


class _Image:
    def __init__(self, name: str, observations: list[_Observation]) -> None:
        self.name, self._observations = name, observations

    def get_observation_points2D(self) -> list[_Observation]:
        return self._observations


class _Reconstruction:
    """What the landmark counts read of a pycolmap.Reconstruction: its images' observations, its point count."""

    def __init__(self, images: list[_Image], points: int) -> None:
        self.images, self._points = dict(enumerate(images)), points

    def num_points3D(self) -> int:
        return self._points


class TestLandmarksOnMovers:
    """Two frames of a 4x6 image: mover 2 in columns 0-1, mover 5 in column 5 of the second frame only; five
    landmarks, observed at pixel centres +0.5 (COLMAP's convention)."""

    frames = Frames(Path("."), ["a.png", "b.png"], [10, 20], None, (4, 6))
    movers = {10: np.zeros((4, 6), np.int32), 20: np.zeros((4, 6), np.int32)}
    movers[10][:, :2] = 2
    movers[20][:, :2], movers[20][:, 5] = 2, 5
    reconstruction = _Reconstruction([
        _Image("a.png", [_Observation(0.5, 0.5, 0), _Observation(1.9, 3.5, 1), _Observation(3.5, 1.5, 2),
                         _Observation(5.5, 2.5, 3)]),
        _Image("b.png", [_Observation(0.5, 1.5, 0), _Observation(5.5, 2.5, 3), _Observation(2.5, 0.5, 4),
                         _Observation(5.99, 3.99, 1)]),
        _Image("unknown.png", [_Observation(0.5, 0.5, 4)]),  # no map for its stamp: not counted
    ], points=8)

    def test_each_landmark_counts_once_per_mover_it_is_seen_on(self) -> None:
        # Point 0 twice on mover 2, point 1 on 2 (frame a) and 5 (frame b), point 3 on 5 in frame b only.
        assert landmarks_by_instance(self.reconstruction, self.frames, self.movers) == {2: 2, 5: 2}

    def test_the_share_of_landmarks_on_any_mover(self) -> None:
        moving = {stamp: ids > 0 for stamp, ids in self.movers.items()}
        assert dynamic_landmark_pct(self.reconstruction, self.frames, moving) == pytest.approx(100.0 * 3 / 8)

    def test_no_mover_seen_gives_empty_counts_and_zero(self) -> None:
        still = {stamp: np.zeros_like(ids) for stamp, ids in self.movers.items()}
        assert landmarks_by_instance(self.reconstruction, self.frames, still) == {}
        assert dynamic_landmark_pct(self.reconstruction, self.frames, {s: m > 0 for s, m in still.items()}) == 0.0
        assert landmarks_by_instance(_Reconstruction([], 0), self.frames, self.movers) == {}


def test_colmap_camera_from_a_ros_camera_matrix() -> None:
    square = np.array([[721.5, 0, 609.6], [0, 721.0, 172.9], [0, 0, 1]])
    model, params = colmap_camera(square)
    assert model == "SIMPLE_PINHOLE" and np.allclose([float(v) for v in params.split(",")], [721.25, 610.1, 173.4])
    model, params = colmap_camera(np.array([[700.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]))
    assert model == "PINHOLE" and np.allclose([float(v) for v in params.split(",")], [700, 500, 320.5, 240.5])


class TestExportFrames:
    """The frames COLMAP reads, and the camera matrix it is given."""

    def test_frames_and_the_k_of_the_camera_info_beside_the_images(self, textured_bag: Path, tmp_path: Path):
        frames = export_frames(textured_bag, tmp_path / "images", every=2)
        assert len(frames.names) == 10 and frames.shape == (188, 621)
        assert all((frames.folder / name).is_file() for name in frames.names)
        np.testing.assert_allclose(frames.camera_matrix, [[500.0, 0, 310], [0, 500, 94], [0, 0, 1]])

    @pytest.mark.parametrize("k, size", [(np.zeros((3, 3)), (621, 188)),  # a driver's placeholder
                                         (np.diag([500.0, 500.0, 1.0]), (1242, 375))])  # another size's K
    def test_no_usable_camera_info_leaves_colmap_to_estimate(self, tmp_path: Path, k: np.ndarray,
                                                            size: tuple[int, int]):
        from conftest import textured_frames
        from moseg_ros.io.bag_writer import BagWriter

        bag = tmp_path / "bag"
        with BagWriter(bag) as writer:
            for i, frame in enumerate(textured_frames(4)):
                stamp = 1_700_000_000_000_000_000 + i * 100_000_000
                writer.write_image("/cam/image_raw", stamp, "cam", frame, "rgb8", log_time_ns=stamp)
                writer.write_camera_info("/cam/camera_info", stamp, "cam", k, *size, log_time_ns=stamp)
        assert export_frames(bag, tmp_path / "images").camera_matrix is None


@pytest.fixture(scope="module")
def street(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The synthetic `map` street, 16 frames at 621x188 (ground-truth masks and poses included)."""
    path = tmp_path_factory.mktemp("map") / "street"
    assert moseg(["synth", "-o", str(path), "--scenario", "map", "--frames", "16", "--width", "621",
                  "--height", "188"]) == 0
    return path


def test_masks_reach_colmap_exactly(street: Path, tmp_path: Path) -> None:
    """COLMAP extracts no feature on a masked pixel, and the mask takes features away."""
    frames = export_frames(street, tmp_path / "images")
    truth = masks_by_stamp(street, GT_DYNAMIC_TOPIC)
    assert write_colmap_masks(frames, truth, tmp_path / "masks") == len(frames.names) == 16
    masked = keypoints_by_image(extract_features(frames, tmp_path / "masked", tmp_path / "masks"))
    plain = keypoints_by_image(extract_features(frames, tmp_path / "plain", None))
    on_movers = 0
    for name, stamp in zip(frames.names, frames.stamps):
        moving = truth[stamp]
        for keypoints, expect_none in ((masked[name], True), (plain[name], False)):
            x, y = np.floor(keypoints).astype(int).T
            hits = int(moving[y, x].sum())
            if expect_none:
                assert hits == 0, name
            else:
                on_movers += hits
    assert on_movers > 50  # unmasked, SIFT does find the movers' texture
    assert sum(map(len, masked.values())) < sum(map(len, plain.values()))


def test_colmap_runs_are_reproducible_from_a_seed(street: Path, tmp_path: Path) -> None:
    """The same frames and seed give the same map, twice in one process (multi-threaded, COLMAP numbered the
    images in the order their features were done and the maps differed from run to run)."""
    frames = export_frames(street, tmp_path / "images")
    maps = [run_colmap(frames, tmp_path / f"run{i}", None) for i in range(2)]
    centres = [camera_centres(m, frames) for m in maps]
    assert len(centres[0]) == 16 and centres[0].keys() == centres[1].keys()
    assert all(np.array_equal(centres[0][s], centres[1][s]) for s in centres[0])
    assert maps[0].num_points3D() == maps[1].num_points3D() > 1000


def test_eval_map_on_the_synthetic_street_sees_landmarks_on_movers(street: Path, tmp_path: Path) -> None:
    """All three modes on the synthetic street (known K held fixed): unmasked, SIFT puts landmarks on the
    movers; the ground-truth masks leave none and give the best trajectory."""
    from moseg_ros.eval.map import evaluate_map

    results = evaluate_map(street, progress=False)
    assert set(results) == {"none", "ours", "gt"}
    for row in results.values():
        assert row["images_registered"] == 16 and row["points3d"] > 1000 and row["ate"] < 0.05
    assert results["none"]["dynamic_landmark_pct"] > 3.0
    assert results["gt"]["dynamic_landmark_pct"] == 0.0 and results["gt"]["features_lost_pct"] > 5.0
    # Which movers leak: every landmark on a mover is counted on at least one of them, none with the truth's masks.
    leaked = results["none"]["dynamic_landmarks_by_instance"]
    on_movers = results["none"]["dynamic_landmark_pct"] * results["none"]["points3d"] / 100.0
    assert len(leaked) >= 2 and sum(leaked.values()) >= round(on_movers) >= max(leaked.values())
    assert results["gt"]["dynamic_landmarks_by_instance"] == {}
    assert results["gt"]["ate"] < results["none"]["ate"]


def test_eval_map_on_real_kitti_frames(tmp_path: Path, capsys) -> None:
    """16 real KITTI odometry-07 frames with their poses: COLMAP's global mapper with no mask and with ours."""
    from conftest import shared_data
    from moseg_ros.io.kitti import kitti_to_bag

    kitti_to_bag(shared_data("kitti_odom07"), tmp_path / "k07", limit=16)
    out = tmp_path / "map.json"
    assert moseg(["eval", "map", str(tmp_path / "k07"), "--json", str(out)]) == 0
    results = json.loads(out.read_text())
    assert json.loads(capsys.readouterr().out) == results
    assert set(results) == {"none", "ours"}  # no ground-truth masks in a KITTI bag
    for mode, row in results.items():
        for key in ("ate", "rpe", "points3d", "images_registered", "features_lost_pct", "dynamic_landmark_pct"):
            assert key in row, (mode, key)
        assert row["images"] == 16 and row["images_registered"] >= 12 and row["points3d"] > 1000
        assert 0 <= row["ate"] < 0.5 and row["reprojection_error_px"] < 1.5
    assert results["none"]["features_lost_pct"] == 0.0 and 0 <= results["ours"]["features_lost_pct"] < 10
    assert out.with_suffix(".png").stat().st_size > 5_000


def test_a_kitti_pose_file_gives_the_reference_by_image_order(street: Path, tmp_path: Path) -> None:
    from moseg_ros.eval.map import _poses, file_poses

    in_bag = _poses(street)
    lines = [" ".join(f"{v:.9f}" for v in T[:3, :4].ravel()) for _, T in sorted(in_bag.items())]
    (tmp_path / "poses.txt").write_text("\n".join(lines) + "\n")
    from_file = file_poses(tmp_path / "poses.txt", street)
    assert from_file.keys() == in_bag.keys()
    assert all(np.allclose(from_file[s], in_bag[s], atol=1e-6) for s in in_bag)
    (tmp_path / "short.txt").write_text("\n".join(lines[:5]) + "\n")
    with pytest.raises(ValueError, match="has 5 poses for the 16 images"):
        file_poses(tmp_path / "short.txt", street)


def test_bag_without_frames_is_a_clear_error(tmp_path: Path, capsys) -> None:
    from moseg_ros.io.bag_writer import BagWriter

    with BagWriter(tmp_path / "two") as writer:
        for i in range(2):
            writer.write_image("/camera/image_raw", 1 + i, "cam", np.zeros((40, 60, 3), np.uint8), "rgb8")
    assert moseg(["eval", "map", str(tmp_path / "two")]) == 2
    assert "a map needs at least 3" in capsys.readouterr().err


def test_masks_of_another_bag_are_refused_before_colmap(street: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    """Masks at none of the bag's stamps would make "ours" a second unmasked run, found out minutes later."""
    import moseg_ros.eval.map as eval_map
    from moseg_ros.eval.map import OUR_MASKS
    from moseg_ros.io.bag_writer import BagWriter

    monkeypatch.setattr(eval_map, "run_colmap", lambda *a, **k: pytest.fail("COLMAP ran"))
    with BagWriter(tmp_path / "other") as writer:
        for stamp in (1, 2, 3):
            writer.write_image(OUR_MASKS, stamp, "cam", np.zeros((188, 621), np.uint8), "mono8")
    assert moseg(["eval", "map", str(street), "--masks", str(tmp_path / "other")]) == 2
    assert "has no /segmenter/dynamic_mask at any stamp" in capsys.readouterr().err


def test_masks_for_some_frames_only_are_run_with_a_warning(tmp_path: Path, capsys) -> None:
    from moseg_ros.eval.colmap import Frames
    from moseg_ros.eval.map import _check_masks_match

    frames = Frames(tmp_path, ["a", "b", "c"], [10, 20, 30], None, (4, 6))
    _check_masks_match({20: np.zeros((4, 6), bool)}, frames, tmp_path / "masks", tmp_path / "bag")
    assert "has masks for 1 of 3 frames; the others keep every feature" in capsys.readouterr().err
    _check_masks_match({}, frames, None, tmp_path / "bag")  # our own masks, made from the bag: never checked
    _check_masks_match({t: np.zeros((4, 6), bool) for t in (10, 20, 30)}, frames, tmp_path / "masks", tmp_path)
    assert capsys.readouterr().err == ""

