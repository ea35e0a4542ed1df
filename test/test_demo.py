"""`moseg demo` end to end on a short sequence: synthetic bag -> real node over DDS -> summary and pictures."""

from __future__ import annotations

import json

import cv2

from moseg_ros.cli import main as moseg


def test_demo_accounts_for_every_frame_and_writes_its_outputs(tmp_path, ros_domain):
    out, bag = tmp_path / "out", tmp_path / "bag"
    # Half speed: this test checks the accounting and the outputs, not the node's speed (a benchmark's job).
    code = moseg(["demo", "--out", str(out), "--bag", str(bag), "--frames", "12", "--domain", str(ros_domain),
                  "--rate", "0.5"])
    summary = json.loads((out / "summary.json").read_text())
    assert code == 0, summary
    assert summary["frames_in"] == summary["masks_out"] == 12
    assert summary["frames_without_mask"] == 0 and summary["header_mismatches"] == 0
    assert summary["node_exit_code"] == 0
    assert summary["frames_scored"] == 12
    for key in ("iou_mean", "latency_ms_p50", "latency_ms_p95"):
        assert isinstance(summary[key], float)
    assert 0.0 <= summary["false_positive_rate_mean"] < 0.05
    sheet = cv2.imread(str(out / "overlay_sheet.png"))
    assert sheet is not None and sheet.shape[1] == 1242
    assert (out / "overlay.mp4").stat().st_size > 10_000


def test_object_level_demo_gets_the_instances_and_catches_movers(tmp_path, ros_domain):
    """--method object_level: the replay forwards /gt/instances, the node pairs every frame with its map and the
    fused method with the ground-contact test finds the moving cars (baseline on this scene: IoU about 0)."""
    out, bag = tmp_path / "out", tmp_path / "bag"
    code = moseg(["demo", "--out", str(out), "--bag", str(bag), "--frames", "12", "--domain", str(ros_domain),
                  "--rate", "0.5", "--method", "object_level"])
    summary = json.loads((out / "summary.json").read_text())
    assert code == 0, summary
    assert summary["method"] == "object_level" and summary["masks_out"] == 12
    assert summary["node_diagnostics"]["frames_without_instances"] == "0"
    assert summary["iou_mean"] > 0.3 and summary["false_positive_rate_mean"] < 0.02



def test_the_default_method_takes_the_bags_instances_with_instances(tmp_path, ros_domain):
    """--instances: the default method decides the renderer's exact instances, which stand in for an upstream
    segmenter (60 frames, measured: IoU 0.593 against 0.421 on its own regions)."""
    out, bag = tmp_path / "out", tmp_path / "bag"
    code = moseg(["demo", "--out", str(out), "--bag", str(bag), "--frames", "12", "--domain", str(ros_domain),
                  "--rate", "0.5", "--instances"])
    summary = json.loads((out / "summary.json").read_text())
    assert code == 0, summary
    assert summary["method"] == "moving_objects" and summary["instances"] and summary["masks_out"] == 12
    assert summary["node_diagnostics"]["frames_without_instances"] == "0"
    assert summary["iou_mean"] > 0.5 and summary["false_positive_rate_mean"] < 0.02  # 12 frames: 0.68 measured

def test_a_camera_bag_without_ground_truth_gets_masks_and_pictures_unscored(textured_bag, tmp_path, ros_domain,
                                                                             capsys):
    out = tmp_path / "out"
    code = moseg(["demo", "--out", str(out), "--bag", str(textured_bag), "--domain", str(ros_domain),
                  "--rate", "0.5"])
    summary = json.loads((out / "summary.json").read_text())
    assert code == 0, summary
    assert summary["frames_in"] == summary["masks_out"] == 20 and summary["node_exit_code"] == 0
    assert "iou_mean" not in summary and "frames_scored" not in summary
    assert "mask IoU, mean over frames with movers  no ground truth" in capsys.readouterr().out
    assert cv2.imread(str(out / "overlay_sheet.png")) is not None
    assert moseg(["demo", "--out", str(out), "--bag", str(textured_bag), "--domain", str(ros_domain),
                  "--method", "object_level"]) == 2
    err = capsys.readouterr().err
    assert "moseg demo: error:" in err and "/gt/instances" in err


def test_bad_scene_arguments_are_refused_before_any_node_starts(tmp_path, capsys):
    for argv, reason in ((["--frames", "0"], "at least 2 frames"), (["--scenario", "rainy"], "presets: default")):
        assert moseg(["demo", "--out", str(tmp_path / "out"), "--bag", str(tmp_path / "bag"), *argv]) == 2
        err = capsys.readouterr().err
        assert "moseg demo: error:" in err and reason in err
    assert not (tmp_path / "bag").exists() and not (tmp_path / "out").exists()
