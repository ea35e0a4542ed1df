"""`moseg process`: every frame in gets its masks out, with the input's stamps, deterministically."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from moseg_ros.cli import main as moseg
from moseg_ros.io.bag_writer import BagWriter
from moseg_ros.io.bags import BagDamagedError, iter_messages, stamp_to_ns
from moseg_ros.io.image import image_to_array
from moseg_ros.tools.bag_masks import process_bag


def _masks(bag):
    return {stamp_to_ns(m.header.stamp): image_to_array(m).copy()
            for _, _, m in iter_messages(bag, ["/segmenter/dynamic_mask"])}


def test_process_writes_one_mask_per_frame_deterministically(textured_bag, tmp_path):
    first = process_bag(textured_bag, tmp_path / "a")
    assert moseg(["process", str(textured_bag), "-o", str(tmp_path / "b"), "--no-progress"]) == 0
    assert first["frames_in"] == first["masks_out"] == 20 and not first["skipped"]
    a, b = _masks(tmp_path / "a"), _masks(tmp_path / "b")
    inputs = [stamp_to_ns(m.header.stamp) for _, _, m in iter_messages(textured_bag, ["/camera/image_raw"])]
    assert sorted(a) == inputs
    assert all(np.array_equal(a[s], b[s]) for s in inputs)
    assert np.mean([a[s].mean() for s in inputs[5:]]) > 2.0  # the sliding block is found


def test_frames_get_the_bags_camera_info_as_the_nodes_would(textured_bag, tmp_path, monkeypatch):
    from moseg_ros.pipeline import Pipeline

    given = []
    process = Pipeline.process

    def spy(self, image, stamp_ns, instances=None, camera_matrix=None, **kwargs):
        given.append(camera_matrix)
        return process(self, image, stamp_ns, instances, camera_matrix, **kwargs)

    monkeypatch.setattr(Pipeline, "process", spy)
    counts = process_bag(textured_bag, tmp_path / "out")
    assert counts["camera_info"] == "/camera/camera_info" and counts["calibrated_frames"] == 20
    assert len(given) == 20 and all(k is not None and k[0, 0] == 500.0 for k in given)


def test_live_frames_that_wait_for_their_own_refit_give_the_offline_masks(textured_bag, tmp_path):
    offline = process_bag(textured_bag, tmp_path / "offline")
    assert moseg(["process", str(textured_bag), "-o", str(tmp_path / "live"), "--no-progress", "--live", "20",
                  "--set", "refit_wait_ms=1000"]) == 0
    a, b = _masks(tmp_path / "offline"), _masks(tmp_path / "live")
    assert offline["masks_out"] == 20 and sorted(a) == sorted(b)
    assert all(np.array_equal(a[s], b[s]) for s in a)
    assert moseg(["process", str(textured_bag), str(textured_bag), "-o", str(tmp_path / "two"), "--live", "10"]) == 2


def test_undecodable_frames_are_skipped_and_reported(tmp_path):
    bag = tmp_path / "bad"
    with BagWriter(bag) as writer:
        frame = np.zeros((20, 30, 3), np.uint8)
        writer.write_image("/camera/image_raw", 1, "cam", frame, "rgb8")
        writer.write_image("/camera/image_raw", 2, "cam", np.zeros((20, 30), np.float32), "32FC1")
        writer.write_image("/camera/image_raw", 3, "cam", frame, "rgb8")
    counts = process_bag(bag, tmp_path / "out")
    assert counts["frames_in"] == 3 and counts["masks_out"] == 2
    assert [s["stamp_ns"] for s in counts["skipped"]] == [2]
    assert "32FC1" in counts["skipped"][0]["reason"]
    assert moseg(["process", str(bag), "-o", str(tmp_path / "out2"), "--no-progress"]) == 1


def test_real_kitti_street_is_mostly_left_usable(tmp_path):
    """The first 40 real KITTI frames (odometry 07, a residential street, few movers): every frame gets a mask
    and almost nothing static is flagged: what is masked is a pedestrian leaving a shop (frames 12-20) and, at
    the corner of frames 26-32, a sign on its post (the share of pixels over the frames is in the README, with
    what each change did to it)."""
    from conftest import shared_data
    from moseg_ros.io.kitti import kitti_to_bag

    kitti_to_bag(shared_data("kitti_odom07"), tmp_path / "k07", limit=40)
    counts = process_bag(tmp_path / "k07", tmp_path / "masks")
    assert counts["frames_in"] == counts["masks_out"] == 40
    flagged = [image_to_array(m).mean() / 255 for _, _, m in iter_messages(tmp_path / "masks",
                                                                           ["/segmenter/dynamic_mask"])]
    assert len(flagged) == 40
    assert np.mean(flagged) < 0.0075


def test_near_parked_cars_of_a_real_street_are_mostly_left_usable():
    """KITTI 07's frames 36-60 pass close by parked cars whose windows, reflections and glints moved a lot and a
    little off their epipolar lines: 2.99 % of the pixels of frames 40-55 were masked before the epipole
    allowance and the texture gate of the dense footing test (2026-12-04), 1.53 % with them, 1.21 % with the dense
    flow's own allowance (``dense_allowance``, 2026-12-05), 1.09 % with the corroborating dense residual counted
    beyond it too, 0.54 % since a track's footing needs something clearly under its object (``footing_clearance``:
    the white van cut by the image's lower edge, frames 46-49). Over frames 40-60: 0.65 % with that, 0.52 % since a
    pixel's dense footing needs road clearly under it (``dense_footing_clearance``: frame 59's number plate on a
    parked car cut by the image's lower edge), 0.31 % on 2026-12-05, 0.28 % since the footing's allowance grows
    with the footing's nearness (``TrackMotionConfig.footing_overhang``; 0.92 % with the road's tolerance alone as
    the margin)."""
    import cv2
    from dataclasses import replace

    from conftest import shared_data
    from moseg_ros.io.kitti import find_sequence
    from moseg_ros.pipeline import Pipeline, PipelineConfig

    sequence = find_sequence(shared_data("kitti_odom07"), limit=61)
    flagged = []
    with Pipeline(replace(PipelineConfig(), refit="inline")) as pipeline:
        for i in range(36, 61):
            frame = cv2.imread(str(sequence.images[i]), cv2.IMREAD_GRAYSCALE)
            flagged.append((pipeline.process(frame, sequence.stamps_ns[i], None, sequence.K).masks.dynamic > 0).mean())
    assert np.mean(flagged[4:]) < 0.0045


def test_missing_bag_and_existing_output_are_clear_errors(textured_bag, tmp_path, capsys):
    assert moseg(["process", str(tmp_path / "nope"), "-o", str(tmp_path / "out"), "--no-progress"]) == 2
    assert "moseg process: error:" in capsys.readouterr().err
    assert moseg(["process", str(textured_bag), "-o", str(textured_bag), "--no-progress"]) == 2
    assert "moseg process: error:" in capsys.readouterr().err


def test_overwrite_replaces_an_earlier_output_bag_and_nothing_else(textured_bag, tmp_path, capsys):
    out = tmp_path / "out"
    assert moseg(["process", str(textured_bag), "-o", str(out), "--no-progress", "--method", "epipolar_baseline"]) == 0
    baseline = _masks(out)
    assert moseg(["process", str(textured_bag), "-o", str(out), "--no-progress"]) == 2
    assert "--overwrite replaces" in capsys.readouterr().err
    assert moseg(["process", str(textured_bag), "-o", str(out), "--no-progress", "--overwrite"]) == 0
    replaced = _masks(out)
    assert sorted(replaced) == sorted(baseline)
    assert any(not np.array_equal(replaced[s], baseline[s]) for s in baseline)  # the default method's masks now
    assert len(list(out.glob("*.mcap"))) == 1
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "keep.txt").write_text("mine")
    assert moseg(["process", str(textured_bag), "-o", str(folder), "--no-progress", "--overwrite"]) == 2
    assert "is not a bag" in capsys.readouterr().err and (folder / "keep.txt").read_text() == "mine"
    assert moseg(["process", str(textured_bag), "-o", str(textured_bag), "--no-progress", "--overwrite"]) == 2
    assert "the input bag itself" in capsys.readouterr().err
    assert len(list(iter_messages(textured_bag, ["/camera/image_raw"]))) == 20


def test_damaged_input_is_processed_up_to_the_damage(textured_bag, tmp_path, capsys):
    file = next(textured_bag.glob("*.mcap"))
    file.write_bytes(file.read_bytes()[:file.stat().st_size * 2 // 3])
    assert moseg(["process", str(textured_bag), "-o", str(tmp_path / "out"), "--no-progress"]) == 1
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    assert "is damaged" in captured.err and "wrote the masks of the" in captured.err
    counts = json.loads(captured.out)
    assert 5 <= counts["masks_out"] == counts["frames_in"] < 20
    assert "ends inside a record" in counts["input_damage"]
    assert len(_masks(tmp_path / "out")) == counts["masks_out"]


def test_killed_run_leaves_a_readable_compressed_bag(tmp_path):
    """SIGKILL in the middle of `moseg process`: every complete chunk of the output is read back."""
    from conftest import textured_frames

    bag = tmp_path / "long"
    with BagWriter(bag) as writer:
        for i, frame in enumerate(textured_frames(50) * 4):
            writer.write_image("/camera/image_raw", 1_000 + i * 100_000_000, "cam", frame, "rgb8")
    out = tmp_path / "out"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    run = subprocess.Popen([sys.executable, "-m", "moseg_ros.cli", "process", str(bag), "-o", str(out)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    progress = b""
    while b"40 frames" not in progress:
        chunk = run.stderr.read1(4096)
        assert chunk, f"moseg process ended early: {progress[-500:]!r}"
        progress += chunk
    run.send_signal(signal.SIGKILL)
    run.wait(timeout=30)
    run.stderr.close()
    assert run.returncode == -signal.SIGKILL
    assert not (out / "metadata.yaml").exists()
    masks: list[np.ndarray] = []
    with pytest.raises(BagDamagedError):
        for _, _, msg in iter_messages(out, ["/segmenter/dynamic_mask"]):
            masks.append(image_to_array(msg))
    assert 35 <= len(masks) < 200
    assert all(mask.shape == (188, 621) for mask in masks)
