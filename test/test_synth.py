"""Tests of the synthetic street generator: determinism, self-consistent ground truth, presets, bags."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from moseg_ros.io.bag_images import read_images
from moseg_ros.synth import cli
from moseg_ros.synth.scenarios import PRESETS, build_scene, check_scene, render_sequence
from moseg_ros.synth.street import GT_TOPICS, SynthFrame, SynthScene, render_frames, write_bag

SMALL = {"width": 414, "height": 125}
MEDIUM = {"width": 621, "height": 188}
N_FRAMES = 40


@pytest.fixture(scope="module")
def default_run() -> tuple[SynthScene, list[SynthFrame]]:
    scene = build_scene("default", seed=0, n_frames=N_FRAMES, **MEDIUM)
    return scene, list(render_frames(scene))


def _grey(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


def _project(K: np.ndarray, pose: np.ndarray, X_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (2, N) and depths (N,) of world points (3, N) in a camera with camera-to-world pose."""
    inv = np.linalg.inv(pose)
    X = inv[:3, :3] @ X_world + inv[:3, 3:4]
    return (K @ X)[:2] / X[2], X[2]


def _back_project(K: np.ndarray, pose: np.ndarray, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """World points (3, N) of pixels uv (2, N) at camera depths (N,)."""
    rays = np.linalg.inv(K) @ np.vstack([uv, np.ones(uv.shape[1])])
    return pose[:3, :3] @ (rays * depth) + pose[:3, 3:4]


def _transfer(K: np.ndarray, f0: SynthFrame, f1: SynthFrame, select: np.ndarray,
              motion: dict[int, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Carry the selected pixels of f0 into f1 with f0's depth and both poses (and a per-id world motion).

    Returns, for points landing inside f1 in front of the camera: ``visible`` (the four pixels around the
    landing point hold the point's own instance id: not occluded), ``depth_ok`` (f1's depth, interpolated in
    inverse depth — exact on planes — agrees within 1 %), ``back_px`` (distance in pixels between the pixel
    and the landing point carried back with f1's depth, assuming the same motion), ``grey_diff`` and
    ``shift_px`` (the image motion).
    """
    H, W = f0.depth.shape
    v, u = np.nonzero(select)
    uv0 = np.vstack([u, v]).astype(np.float64)
    ids = f0.instances[v, u]
    X = _back_project(K, f0.pose, uv0, f0.depth[v, u].astype(np.float64))
    M = np.tile(np.eye(4), (len(ids), 1, 1))
    for box_id, transform in (motion or {}).items():
        M[ids == box_id] = transform
    X = np.einsum("nij,jn->in", M[:, :3, :3], X) + M[:, :3, 3].T
    uv1, z1 = _project(K, f1.pose, X)
    inside = (z1 > 0) & (uv1[0] >= 0) & (uv1[0] <= W - 1) & (uv1[1] >= 0) & (uv1[1] <= H - 1)
    uv0, uv1, z1, ids, M = uv0[:, inside], uv1[:, inside], z1[inside], ids[inside], M[inside]
    x0, y0 = np.floor(uv1).astype(int)
    visible = np.ones(len(ids), dtype=bool)
    for yy in (y0, np.minimum(y0 + 1, H - 1)):
        for xx in (x0, np.minimum(x0 + 1, W - 1)):
            visible &= (f1.instances[yy, xx] == ids) & np.isfinite(f1.depth[yy, xx])
    with np.errstate(divide="ignore"):
        inverse_depth = map_coordinates(1.0 / f1.depth.astype(np.float64), uv1[::-1], order=1)
    depth_ok = np.abs(inverse_depth * z1 - 1.0) < 0.01
    back = np.linalg.inv(M)
    X1 = _back_project(K, f1.pose, uv1, 1.0 / np.where(inverse_depth > 0, inverse_depth, np.nan))
    X0 = np.einsum("nij,jn->in", back[:, :3, :3], X1) + back[:, :3, 3].T
    back_px = np.linalg.norm(_project(K, f0.pose, X0)[0] - uv0, axis=0)
    grey_diff = np.abs(map_coordinates(_grey(f1.rgb), uv1[::-1], order=1) - _grey(f0.rgb)[uv0[1].astype(int),
                                                                                          uv0[0].astype(int)])
    return {"visible": visible, "depth_ok": depth_ok, "back_px": back_px, "grey_diff": grey_diff,
            "shift_px": np.linalg.norm(uv1 - uv0, axis=0)}


@pytest.fixture(scope="module")
def full_size_scene() -> SynthScene:
    return build_scene("default", seed=0, n_frames=3)


def test_same_seed_gives_identical_frames_and_another_seed_other_textures() -> None:
    first = render_sequence("parked", seed=3, n_frames=3, **SMALL)
    again = render_sequence("parked", seed=3, n_frames=3, **SMALL)
    for a, b in zip(first.frames, again.frames, strict=True):
        for name in ("rgb", "instances", "dynamic", "depth", "pose"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.stamp_ns == b.stamp_ns
    scenes = [build_scene("parked", seed=seed, n_frames=3, **SMALL) for seed in (3, 4)]
    ground = [scene.street.ground.image.astype(int) for scene in scenes]
    assert np.mean(np.abs(ground[0] - ground[1])) > 5.0
    other = next(iter(render_frames(scenes[1])))
    assert np.mean(np.abs(first.frames[0].rgb.astype(int) - other.rgb.astype(int))) > 5.0


def test_geometry_of_a_seed_does_not_depend_on_image_size(full_size_scene: SynthScene) -> None:
    small = build_scene("default", seed=0, n_frames=3, **SMALL)
    full = full_size_scene
    assert np.array_equal(small.poses, full.poses)
    assert [b.name for b in small.boxes] == [b.name for b in full.boxes]
    for a, b in zip(small.boxes, full.boxes, strict=True):
        assert np.array_equal(a.centres, b.centres)
    assert small.K[0, 0] == pytest.approx(full.K[0, 0] / 3.0)


def test_static_pixels_reproject_with_ground_truth_depth_and_poses(default_run) -> None:
    scene, frames = default_run
    for t in (0, 13, 26, N_FRAMES - 2):
        f0, f1 = frames[t], frames[t + 1]
        static = (f0.instances == 0) & np.isfinite(f0.depth)
        result = _transfer(scene.K, f0, f1, static)
        visible = result["visible"]
        assert visible.mean() > 0.9, f"frame {t}: too few static points stay visible ({visible.mean():.3f})"
        agree = result["depth_ok"] & (result["back_px"] < 0.5)
        assert agree[visible].mean() > 0.99, f"frame {t}: static depth/position agree for {agree[visible].mean():.4f}"
        grey = result["grey_diff"][visible & agree]
        # Texture is fixed to the world: the colour travels with the point (up to resampling and mip level).
        assert np.median(grey) < 3.0 and np.percentile(grey, 90) < 12.0, (np.median(grey), np.percentile(grey, 90))


def test_moving_boxes_violate_the_static_reprojection_but_follow_their_own_motion(default_run) -> None:
    scene, frames = default_run
    boxes = {b.id: b for b in scene.boxes}
    moving_ids = sorted(scene.dynamic_ids())
    for t in (0, 13, 26, N_FRAMES - 2):
        f0, f1 = frames[t], frames[t + 1]
        moving = np.isin(f0.instances, moving_ids)
        assert moving.sum() > 500
        as_static = _transfer(scene.K, f0, f1, moving)
        static_ok = as_static["visible"] & as_static["depth_ok"] & (as_static["grey_diff"] < 5.0)
        assert static_ok.mean() < 0.2, f"frame {t}: {static_ok.mean():.3f} of moving pixels look static"
        motion = {i: boxes[i].pose(t + 1) @ np.linalg.inv(boxes[i].pose(t)) for i in moving_ids}
        followed = _transfer(scene.K, f0, f1, moving, motion)
        visible = followed["visible"]
        assert visible.mean() > 0.8  # small objects: many landing points touch the silhouette
        assert (followed["depth_ok"] & (followed["back_px"] < 0.5))[visible].mean() > 0.99
        assert np.median(followed["grey_diff"][visible]) < 2.0


def test_dynamic_mask_is_the_union_of_moving_boxes_and_excludes_parked_cars(default_run) -> None:
    scene, frames = default_run
    names = scene.object_names()
    moving = scene.dynamic_ids()
    assert {names[i] for i in moving} == {"car_ahead", "car_oncoming", "car_crossing", "pedestrian"}
    parked = [i for i, name in names.items() if name.startswith("parked_car")]
    assert len(parked) == 2 and not set(parked) & moving
    parked_seen = 0
    for frame in frames:
        assert np.array_equal(frame.dynamic, np.isin(frame.instances, sorted(moving)))
        on_parked = np.isin(frame.instances, parked)
        parked_seen += on_parked.any()
        assert not frame.dynamic[on_parked].any()
    assert parked_seen > len(frames) // 2
    # The parked cars are truly static: their pixels satisfy the static reprojection.
    for f0, f1 in zip(frames[::10], frames[1::10]):
        result = _transfer(scene.K, f0, f1, np.isin(f0.instances, parked))
        assert (result["depth_ok"] & (result["back_px"] < 0.5))[result["visible"]].mean() > 0.99


@pytest.mark.parametrize("scenario, movers", [
    ("default", {"car_ahead", "car_oncoming", "car_crossing", "pedestrian"}),
    ("ahead", {"car_ahead"}),
    ("oncoming", {"car_oncoming"}),
    ("crossing", {"car_crossing"}),
    ("pedestrian", {"pedestrian"}),
    ("parked", set()),
    ("parallax", set()),
])
def test_each_scenario_shows_its_objects_in_most_frames(scenario: str, movers: set[str]) -> None:
    sequence = render_sequence(scenario, seed=1, n_frames=N_FRAMES, **SMALL)
    names = sequence.object_names
    assert {names[i] for i in sequence.dynamic_ids} == movers
    watched = sequence.dynamic_ids or set(names)  # presets without movers: their static objects
    seen = {i: sum(np.count_nonzero(f.instances == i) >= 8 for f in sequence.frames) for i in watched}
    if movers:
        assert all(count >= 0.8 * N_FRAMES for count in seen.values()), {names[i]: c for i, c in seen.items()}
    else:
        assert all(f.instances.any() and not f.dynamic.any() for f in sequence.frames)
    if scenario == "parallax":
        # Near static objects: their pixels move far between frames (strong parallax), yet reproject statically.
        shifts = []
        for f0, f1 in zip(sequence.frames[::8], sequence.frames[1::8]):
            result = _transfer(sequence.K, f0, f1, f0.instances > 0)
            assert (result["depth_ok"] & (result["back_px"] < 0.5))[result["visible"]].mean() > 0.99
            shifts.append(np.percentile(result["shift_px"], 95))
        assert max(shifts) > 15.0, shifts


def test_oncoming_car_approaches_and_crossing_car_moves_right() -> None:
    for scenario, name in (("oncoming", "car_oncoming"), ("crossing", "car_crossing")):
        scene = build_scene(scenario, seed=2, n_frames=N_FRAMES, **SMALL)
        box = next(b for b in scene.boxes if b.name == name)
        if scenario == "oncoming":
            rel = np.array([(np.linalg.inv(pose) @ np.append(c, 1.0))[2] for pose, c in zip(scene.poses, box.centres)])
            assert np.all(np.diff(rel) < -1.0) and rel[int(0.8 * N_FRAMES)] > 5.0
        else:
            assert np.all(np.diff(box.centres[:, 0]) > 0) and np.all(np.diff(box.centres[:, 2]) == 0)
            assert box.centres[0, 0] < -6.0 and box.centres[-1, 0] > 4.0


def test_full_size_frames_have_hundreds_of_trackable_corners(full_size_scene: SynthScene) -> None:
    frame = next(iter(render_frames(full_size_scene)))
    assert frame.rgb.shape == (375, 1242, 3) and frame.rgb.dtype == np.uint8
    corners = cv2.goodFeaturesToTrack(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), maxCorners=3000,
                                      qualityLevel=0.01, minDistance=7)
    assert corners is not None and len(corners) > 500


def test_check_scene_names_what_is_wrong_without_building() -> None:
    check_scene("map", 2, 16, 16)  # the smallest valid arguments pass
    for args, reason in ((("rainy", 40, 621, 188), "presets: default"), (("default", 1, 621, 188), "at least 2"),
                         (("default", 40, 621, 15), "16x16, got 621x15")):
        with pytest.raises(ValueError, match=reason):
            check_scene(*args)


def test_unknown_scenario_names_the_presets() -> None:
    with pytest.raises(ValueError, match="presets: default, ahead"):
        render_sequence("rainy", n_frames=2, **SMALL)
    with pytest.raises(ValueError, match="at least 2 frames"):
        build_scene("default", n_frames=1, **SMALL)


def test_written_bag_has_six_topics_with_equal_counts_and_stamps(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    sequence = render_sequence("parked", seed=0, n_frames=3, **SMALL)
    counts = write_bag(sequence, tmp_path / "bag", start_ns=5_000_000_000)
    assert counts == {topic: 3 for topic in GT_TOPICS.values()}
    stamps: dict[str, list[int]] = {}
    with AnyReader([tmp_path / "bag"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert set(reader.topics) == set(GT_TOPICS.values())
        for connection, _, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            stamps.setdefault(connection.topic, []).append(stamp)
            index = len(stamps[connection.topic]) - 1
            frame = sequence.frames[index]
            if connection.topic == GT_TOPICS["instances"]:
                assert msg.encoding == "32SC1"
                assert np.array_equal(np.frombuffer(msg.data, np.int32).reshape(125, 414), frame.instances)
            elif connection.topic == GT_TOPICS["depth"]:
                assert msg.encoding == "32FC1"
                assert np.array_equal(np.frombuffer(msg.data, np.float32).reshape(125, 414), frame.depth)
            elif connection.topic == GT_TOPICS["image"]:
                assert (msg.encoding, msg.header.frame_id) == ("rgb8", "camera")
                assert np.array_equal(np.frombuffer(msg.data, np.uint8).reshape(125, 414, 3), frame.rgb)
            elif connection.topic == GT_TOPICS["pose"]:
                assert msg.header.frame_id == "world"
                position = msg.pose.position
                assert np.allclose([position.x, position.y, position.z], frame.pose[:3, 3])
    expected = [5_000_000_000 + i * 100_000_000 for i in range(3)]
    assert all(values == expected for values in stamps.values()), stamps


def test_cli_writes_a_bag_and_reports_frames_per_second(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    args = parser.parse_args(["-o", str(tmp_path / "out"), "--scenario", "ahead", "--frames", "3",
                              "--width", "414", "--height", "125"])
    assert cli.run(args) == 0
    out = capsys.readouterr().out
    assert "frames/s" in out and "/gt/dynamic_mask" in out and "car_ahead" in out
    assert (tmp_path / "out" / "metadata.yaml").is_file()
    assert cli.run(args) == 2  # the output exists: refused, not overwritten
    assert "already exists" in capsys.readouterr().err
    assert set(PRESETS) >= {"default", "ahead", "oncoming", "crossing", "pedestrian", "parallax", "parked", "map"}


def test_map_scene_is_the_busy_street_at_half_speed(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    street, slow = (build_scene(name, seed=0, n_frames=40, **SMALL) for name in ("default", "map"))
    movers = {street.object_names()[i] for i in street.dynamic_ids()}
    assert movers == {slow.object_names()[i] for i in slow.dynamic_ids()} >= {"car_ahead", "car_crossing"}
    step = np.linalg.norm(np.diff([T[:3, 3] for T in slow.poses], axis=0), axis=1)
    assert 0.45 < step.mean() < 0.55 and 0.9 < np.linalg.norm(np.diff([T[:3, 3] for T in street.poses],
                                                                        axis=0), axis=1).mean() < 1.1
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    args = parser.parse_args(["-o", str(tmp_path / "m"), "--scenario", "map", "--width", "160", "--height", "64"])
    assert cli.run(args) == 0 and "120 frames" in capsys.readouterr().out


def _footprints_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test of two convex ground footprints given as corner arrays (4, 2)."""
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        for normal in np.stack([-edges[:, 1], edges[:, 0]], axis=1):
            pa, pb = a @ normal, b @ normal
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_two_objects_ever_overlap(seed: int) -> None:
    scene = build_scene("default", seed=seed, n_frames=N_FRAMES, **SMALL)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    for t in range(0, N_FRAMES, 3):
        prints = []
        for box in scene.boxes:
            w, _, l = box.size
            c, s = np.cos(box.yaws[t]), np.sin(box.yaws[t])
            # Footprint in the ground plane (x, z): local (x, z) rotated by the yaw.
            local = corners * [w / 2, l / 2]
            prints.append(np.stack([c * local[:, 0] + s * local[:, 1], -s * local[:, 0] + c * local[:, 1]], axis=1)
                          + box.centres[t, [0, 2]])
        for i in range(len(prints)):
            for j in range(i + 1, len(prints)):
                assert not _footprints_overlap(prints[i], prints[j]), (t, scene.boxes[i].name, scene.boxes[j].name)
        # Facades bound every object (they stand on the street, not inside buildings).
        for box, fp in zip(scene.boxes, prints):
            assert scene.street.x_left <= fp[:, 0].min() and fp[:, 0].max() <= scene.street.x_right or \
                box.name == "car_crossing", box.name


@pytest.fixture(scope="module")
def scene() -> SynthScene:
    return build_scene("default", seed=0, n_frames=7, **SMALL)


class TestAtRate:
    """SynthScene.at_rate: the same scene and motion per second seen by a camera at another frame rate."""

    def test_own_rate_keeps_poses_boxes_and_stamps(self, scene: SynthScene) -> None:
        same = scene.at_rate(10.0)
        np.testing.assert_array_equal(same.stamps_ns, scene.stamps_ns)
        np.testing.assert_allclose(same.poses, scene.poses, atol=1e-12)
        for box, kept in zip(scene.boxes, same.boxes):
            np.testing.assert_allclose(kept.centres, box.centres, atol=1e-12)
        assert same.dynamic_ids() == scene.dynamic_ids()

    def test_three_times_the_rate_fills_each_frame_period_with_two_frames(self, scene: SynthScene) -> None:
        fast = scene.at_rate(30.0)
        assert fast.n_frames == 3 * (scene.n_frames - 1) + 1
        assert np.all(np.abs(np.diff(fast.stamps_ns) - 1e9 / 30) <= 1) and fast.stamps_ns[-1] == scene.stamps_ns[-1]
        np.testing.assert_allclose(fast.poses[::3], scene.poses, atol=1e-9)
        car = next(b for b in scene.boxes if b.name == "car_oncoming")
        fast_car = next(b for b in fast.boxes if b.name == "car_oncoming")
        np.testing.assert_allclose(fast_car.centres[1], car.centres[0] + (car.centres[1] - car.centres[0]) / 3)
        # the camera's centre steps a third of the way too; movers stay movers, parked cars stay parked
        np.testing.assert_allclose(fast.poses[2, :3, 3], scene.poses[0, :3, 3] + 2 / 3 * (
            scene.poses[1, :3, 3] - scene.poses[0, :3, 3]))
        assert fast.dynamic_ids() == scene.dynamic_ids()

    def test_half_the_rate_takes_every_second_frame(self, scene: SynthScene) -> None:
        slow = scene.at_rate(5.0)
        np.testing.assert_array_equal(slow.stamps_ns, scene.stamps_ns[::2])
        np.testing.assert_allclose(slow.poses, scene.poses[::2], atol=1e-9)

    def test_a_frame_at_the_same_time_is_the_same_image(self, scene: SynthScene) -> None:
        slow, fast = list(render_frames(scene)), list(render_frames(scene.at_rate(30.0)))
        assert fast[3].stamp_ns == slow[1].stamp_ns
        np.testing.assert_array_equal(fast[3].instances, slow[1].instances)
        assert np.mean(np.abs(fast[3].rgb.astype(int) - slow[1].rgb.astype(int))) < 0.5
        assert not np.array_equal(fast[2].instances, slow[1].instances)  # a frame in between: the movers moved

    def test_rate_must_be_positive(self, scene: SynthScene) -> None:
        for rate in (0.0, -10.0, float("nan")):
            with pytest.raises(ValueError, match="rate must be positive"):
                scene.at_rate(rate)
            with pytest.raises(ValueError, match="rate must be positive"):
                check_scene("default", 7, 414, 125, rate)

    def test_cli_writes_the_frames_of_a_faster_camera(self, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
        parser = argparse.ArgumentParser()
        cli.add_arguments(parser)
        args = parser.parse_args(["-o", str(tmp_path / "fast"), "--scenario", "ahead", "--frames", "3",
                                  "--width", "160", "--height", "64", "--rate", "30"])
        assert cli.run(args) == 0
        assert "7 frames 160x64 at 30 Hz" in capsys.readouterr().out
        stamps = [image.stamp_ns for image in read_images(tmp_path / "fast", GT_TOPICS["image"])]
        assert len(stamps) == 7 and np.all(np.abs(np.diff(stamps) - 1e9 / 30) <= 1)
