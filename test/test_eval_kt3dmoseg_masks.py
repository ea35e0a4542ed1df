"""Dynamic masks on real KT3DMoSeg street frames, scored at the labelled points, on a folder of the same layout."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import shared_data
from moseg_ros.cli import main as moseg
from moseg_ros.eval.kt3dmoseg_masks import (ClipMaskScore, holds_points, object_frame_detections, pooled,
                                            trajectory_frames)
from moseg_ros.methods import moving_objects


def _subset(tmp_path, clips_with_frames, clips_without_frames=(), rename=None):
    """A KT3DMoSeg-layout folder with a few clips (symlinks into ../shared/data), optionally renamed."""
    rename = rename or {}
    source = shared_data("kt3dmoseg")
    (tmp_path / "Data").mkdir(parents=True)
    (tmp_path / "OriginalSequences").mkdir()
    for clip in (*clips_with_frames, *clips_without_frames):
        (tmp_path / "Data" / f"{rename.get(clip, clip)}.mat").symlink_to(source / "Data" / f"{clip}_Tracks.mat")
    for clip in clips_with_frames:
        (tmp_path / "OriginalSequences" / rename.get(clip, clip)).symlink_to(source / "OriginalSequences" / clip)
    return tmp_path


def test_scores_real_frames_at_labelled_points(tmp_path, capsys):
    """Seq005_Clip02 (a car and a cyclist crossing a residential street). Measured with the default method
    (moving_objects): 75 % of moving-point observations flagged, 3.4 % of static ones, 27 of the 38
    object-frames detected (the epipolar baseline: 38 %, 0.5 %, 18)."""
    root = _subset(tmp_path / "kt", ["Seq005_Clip02"], ["Seq020_Clip01"])
    assert moseg(["eval", "kt3dmoseg-masks", str(root), "--json", str(tmp_path / "r.json")]) == 0
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["clips_scored"] == 1 and result["clips_without_frames"] == ["Seq020_Clip01"]
    row = result["clips"][0]
    assert row["frames"] == 20 and row["moving_points"] > 1000 and row["static_points"] > 1000
    assert row["moving_recall"] > 0.6
    assert row["static_flagged"] < 0.06
    # One clip: the pooled figures are the clip's own.
    assert result["recall"] == pytest.approx(row["moving_recall"])
    assert result["static_flagged"] == pytest.approx(row["static_flagged"])
    assert result["object_frames"] == row["object_frames"] == 2 * 19  # two movers, frames 1..19
    assert result["object_frames_detected"] == pytest.approx(row["object_frames_detected"] / 38)
    assert result["object_frames_detected"] > 0.55
    printed = capsys.readouterr().out
    assert "Seq005_Clip02" in printed and "object-frames detected" in printed and "id switches" in printed


def test_the_car_and_the_cyclist_keep_instances_of_their_own(tmp_path, monkeypatch):
    """Seq005_Clip02's car and cyclist come close in the image: their regions join, and the tracker keeps the
    two regions it saw apart for three frames apart (``keep_apart_after``) while they move apart. Measured: 0
    object-frames of 38 whose instance holds the other mover and 2 id switches; with the regions joined, 18 and 3."""
    root = _subset(tmp_path / "kt", ["Seq005_Clip02"])
    assert moseg(["eval", "kt3dmoseg-masks", str(root), "--json", str(tmp_path / "kept.json")]) == 0
    kept = json.loads((tmp_path / "kept.json").read_text())
    plain = moving_objects.front_end_config
    monkeypatch.setattr(moving_objects, "front_end_config", lambda config: replace(plain(config), keep_apart_after=0))
    assert moseg(["eval", "kt3dmoseg-masks", str(root), "--json", str(tmp_path / "joined.json")]) == 0
    joined = json.loads((tmp_path / "joined.json").read_text())
    assert kept["shared_object_frames"] <= 4 and joined["shared_object_frames"] >= 10
    assert kept["id_switches"] <= joined["id_switches"]
    # The car's front and back, flagged apart for frames 4-7, move alike and join (kept apart they split the car
    # over two instances in 11 object-frames).
    assert kept["split_object_frames"] <= joined["split_object_frames"] + 1
    assert kept["recall"] == pytest.approx(joined["recall"], abs=0.01)  # the same masks, numbered apart


def test_live_scores_what_the_node_publishes_at_a_camera_rate(tmp_path):
    """--live HZ: the refit on its worker, frames at HZ. With the default ``refit_wait_ms`` (-1) a frame waits for
    its own refit while the camera leaves time, and at 2 Hz every frame scores as offline, exactly (a slow rate: the
    auto wait takes no refit slower than the time left, and a loaded machine once made 5 Hz too fast); frames that
    never wait apply decisions a frame old and lose recall on Seq038_Clip02, a near walker's swinging legs (measured
    2026-12-05: 91.3 % offline, 85.6 % never waiting at 10 Hz)."""
    root = _subset(tmp_path / "kt", ["Seq038_Clip02"])
    runs = {}
    for name, extra in (("offline", []), ("live", ["--live", "2"]),
                        ("never_waiting", ["--live", "10", "--set", "refit_wait_ms=0"])):
        assert moseg(["eval", "kt3dmoseg-masks", str(root), "--json", str(tmp_path / f"{name}.json"), *extra]) == 0
        runs[name] = json.loads((tmp_path / f"{name}.json").read_text())
    assert runs["live"]["live_hz"] == 2.0 and runs["offline"]["live_hz"] == 0.0
    assert runs["live"]["recall"] == runs["offline"]["recall"]
    assert runs["live"]["static_flagged"] == runs["offline"]["static_flagged"]
    assert runs["never_waiting"]["recall"] < runs["offline"]["recall"]
    with pytest.raises(SystemExit, match="2"):
        moseg(["eval", "kt3dmoseg-masks", str(root), "--live", "-1"])


def test_an_unreadable_frame_is_skipped_listed_and_not_scored(tmp_path, capsys):
    """Seq005_Clip02 with its frames copied and the fourth one damaged: 19 frames run, its points unscored."""
    root = _subset(tmp_path / "kt", [], ["Seq005_Clip02"])
    frames = root / "OriginalSequences" / "Seq005_Clip02"
    frames.mkdir()
    source = sorted(shared_data("kt3dmoseg", "OriginalSequences", "Seq005_Clip02").glob("*.png"))
    for path in source:
        (frames / path.name).write_bytes(path.read_bytes())
    (frames / source[3].name).write_bytes(b"not a png")
    assert moseg(["eval", "kt3dmoseg-masks", str(root), "--json", str(tmp_path / "r.json")]) == 0
    row, = json.loads((tmp_path / "r.json").read_text())["clips"]
    assert row["unreadable"] == [source[3].name] and row["frames"] == 20
    assert row["object_frames"] == 2 * 18  # two movers, frames 1..19 but the damaged one
    assert f"Seq005_Clip02: unreadable, skipped: {source[3].name}" in capsys.readouterr().out


def test_clip_files_of_any_name(tmp_path, capsys):
    """A clip file and its frames under another name are found; SeqList.mat (no Data struct) is passed over."""
    root = _subset(tmp_path / "kt", ["Seq070_Clip01"], rename={"Seq070_Clip01": "street"})
    (root / "Data" / "SeqList.mat").symlink_to(shared_data("kt3dmoseg", "Data", "SeqList.mat"))
    assert moseg(["eval", "kt3dmoseg-masks", str(root), "--json", str(tmp_path / "r.json")]) == 0
    result = json.loads((tmp_path / "r.json").read_text())
    assert [c["clip"] for c in result["clips"]] == ["street"] and result["clips_without_frames"] == []
    assert moseg(["eval", "kt3dmoseg-masks", str(tmp_path / "empty")]) == 2
    assert "no KT3DMoSeg clip files (*.mat with a Data struct)" in capsys.readouterr().out
    frameless = _subset(tmp_path / "frameless", [], ["Seq020_Clip01"])
    assert moseg(["eval", "kt3dmoseg-masks", str(frameless), "--json", str(tmp_path / "f.json")]) == 2
    printed = capsys.readouterr().out
    assert "has readable frames" in printed and "skipped: Seq020_Clip01" in printed and "nan" not in printed
    assert not (tmp_path / "f.json").exists()


def _copied(tmp_path, clip, rename_frame=None, edit=None):
    """A folder with ``clip``'s .mat linked and its frames copied, each renamed by ``rename_frame(index, path)``
    (None: left out) and its pixels passed through ``edit(index, image)``."""
    root = _subset(tmp_path, [], [clip])
    frames = root / "OriginalSequences" / clip
    frames.mkdir()
    for index, path in enumerate(sorted(shared_data("kt3dmoseg", "OriginalSequences", clip).glob("*.png"))):
        name = rename_frame(index, path) if rename_frame else path.name
        if name is None:
            continue
        if edit is None:
            (frames / name).write_bytes(path.read_bytes())
        else:
            cv2.imwrite(str(frames / name), edit(index, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)))
    return root


def _scored(tmp_path, root, name):
    assert moseg(["eval", "kt3dmoseg-masks", str(root), "--json", str(tmp_path / f"{name}.json")]) == 0
    row, = json.loads((tmp_path / f"{name}.json").read_text())["clips"]
    return row


def test_frames_named_by_plain_numbers_or_as_jpeg_score_as_the_layout(tmp_path):
    """Seq070_Clip01 (10 frames) as 000001.png..., as 0.png ... 9.png, as 1.png ... 10.png (10 after 9, not
    after 1) and as JPEG: the same frames for the same trajectory frames."""
    reference = _scored(tmp_path, _subset(tmp_path / "kt", ["Seq070_Clip01"]), "layout")
    for name, rename in (("from0", lambda i, p: f"{i}.png"), ("from1", lambda i, p: f"{i + 1}.png"),
                         ("cut", lambda i, p: f"{i + 45:010d}.png")):  # from a longer sequence
        row = _scored(tmp_path, _copied(tmp_path / name, "Seq070_Clip01", rename), name)
        assert row["moving_recall"] == reference["moving_recall"]
        assert row["static_flagged"] == reference["static_flagged"] and row["missing"] == []
    as_jpeg = _scored(tmp_path, _copied(tmp_path / "jpeg", "Seq070_Clip01", lambda i, p: f"{p.stem}.jpg",
                                        lambda i, image: image), "jpeg")
    assert as_jpeg["object_frames"] == reference["object_frames"]
    assert as_jpeg["moving_recall"] == pytest.approx(reference["moving_recall"], abs=0.1)


def test_a_missing_frame_shifts_no_other(tmp_path, capsys):
    """Seq070_Clip01 without its fifth frame (000005.png, trajectory frame 4): listed, and the frames after it
    keep their trajectory frames (paired by position, each would be scored against the frame before)."""
    reference = _scored(tmp_path, _subset(tmp_path / "kt", ["Seq070_Clip01"]), "layout")
    root = _copied(tmp_path / "gap", "Seq070_Clip01", lambda i, p: None if i == 4 else p.name)
    row = _scored(tmp_path, root, "gap")
    assert row["missing"] == [4] and row["frames"] == 10
    assert row["object_frames"] == reference["object_frames"] - 1
    assert row["moving_recall"] > 0.5 and row["static_flagged"] < 0.05
    assert "trajectory frames without a file (from 0): 4" in capsys.readouterr().out


def test_frames_not_of_the_trajectories_size_are_listed_not_scored(tmp_path, capsys):
    """Resized frames do not hold the trajectories: the clip is skipped with the reason; one smaller frame in a
    clip is listed and the others are scored (no traceback)."""
    half = _copied(tmp_path / "half", "Seq070_Clip01", edit=lambda i, image: cv2.resize(image, (621, 188)))
    assert moseg(["eval", "kt3dmoseg-masks", str(half)]) == 2
    assert "do not hold its trajectories" in capsys.readouterr().out
    double = _copied(tmp_path / "double", "Seq070_Clip01", edit=lambda i, image: cv2.resize(image, (2484, 750)))
    assert moseg(["eval", "kt3dmoseg-masks", str(double)]) == 2
    one_small = _copied(tmp_path / "one", "Seq070_Clip01",
                        edit=lambda i, image: image[:300, :900] if i == 5 else image)
    row = _scored(tmp_path, one_small, "one")
    assert row["mismatched"] == ["000006.png (900x300)"] and row["moving_recall"] > 0.5
    padded = _copied(tmp_path / "padded", "Seq070_Clip01",
                     edit=lambda i, image: cv2.copyMakeBorder(image, 0, 8, 0, 8, cv2.BORDER_REPLICATE) if i == 5
                     else image)  # holds the points, but the pipeline would start over on it
    assert _scored(tmp_path, padded, "padded")["mismatched"] == ["000006.png (1250x383)"]


def test_damaged_clip_files_and_one_frame_clips_are_skipped_with_the_reason(tmp_path, capsys):
    root = _subset(tmp_path / "kt", ["Seq070_Clip01"])
    whole = shared_data("kt3dmoseg", "Data", "Seq070_Clip01_Tracks.mat").read_bytes()
    (root / "Data" / "Seq070_Clip01.mat").unlink()
    (root / "Data" / "Seq070_Clip01.mat").write_bytes(whole[:len(whole) // 2])
    assert moseg(["eval", "kt3dmoseg-masks", str(root)]) == 2
    assert "not a readable KT3DMoSeg clip" in capsys.readouterr().out
    single = _copied(tmp_path / "single", "Seq070_Clip01", lambda i, p: p.name if i == 0 else None)
    assert moseg(["eval", "kt3dmoseg-masks", str(single)]) == 2
    assert "skipped (no frame to score after the pipeline's first): Seq070_Clip01" in capsys.readouterr().out


def test_the_first_frame_the_pipeline_gets_is_not_scored(tmp_path):
    """With Seq070_Clip01's first file damaged the pipeline's first frame is trajectory frame 1: not scored."""
    reference = _scored(tmp_path, _subset(tmp_path / "kt", ["Seq070_Clip01"]), "layout")
    root = _copied(tmp_path / "first", "Seq070_Clip01")
    (root / "OriginalSequences" / "Seq070_Clip01" / "000001.png").write_bytes(b"")
    row = _scored(tmp_path, root, "first")
    assert row["unreadable"] == ["000001.png"] and row["object_frames"] == reference["object_frames"] - 1


class TestTrajectoryFrames:
    def test_by_number_from_one_or_from_zero(self):
        files = [Path("000001.png"), Path("000002.png"), Path("000004.png")]
        assert trajectory_frames(files, 4) == [files[0], files[1], None, files[2]]
        zero = [Path("0.png"), Path("1.png"), Path("2.png")]
        assert trajectory_frames(zero, 2) == zero[:2]  # beyond the trajectories: not used

    def test_names_without_numbers_or_with_repeated_ones_go_by_order(self):
        files = [Path("a.png"), Path("b.png")]
        assert trajectory_frames(files, 3) == [*files, None]
        twice = [Path("left_1.png"), Path("right_1.png")]
        assert trajectory_frames(twice, 2) == twice


class TestHoldsPoints:
    def test_known_values(self):
        extent = np.array([1240.5, 373.6])
        assert holds_points((375, 1242), extent) and holds_points((375, 1242, 3), extent)
        assert not holds_points((188, 621), extent)  # smaller than the points reach
        assert not holds_points((750, 2484), extent)  # twice their extent both ways
        assert not holds_points((487, 1615), extent)  # 1.3 times
        assert holds_points((375, 1500), np.array([1050.0, 370.0]))  # points short of the right side


def test_object_frames_need_half_of_their_visible_points():
    labels = np.array([1, 2, 2, 2, 3, 3])
    scored = np.ones((6, 3), dtype=bool)
    scored[4:, 2] = False  # object 3 not visible in frame 2: not an object-frame
    hits = np.zeros((6, 3), dtype=bool)
    hits[1, 0] = True  # object 2, frame 0: 1 of 3 points
    hits[1:3, 1] = True  # object 2, frame 1: 2 of 3
    hits[4, 0] = True  # object 3, frame 0: 1 of 2 (half counts)
    hits[0, :] = True  # background points never count
    assert object_frame_detections(hits, scored, labels) == (5, 2)
    assert object_frame_detections(hits, scored, np.ones(6, dtype=int)) == (0, 0)


def test_pooled_figures_weigh_clips_by_their_points():
    def clip(moving, hits, objects, detected):
        return ClipMaskScore(clip="c", frames=10, moving_points=moving, static_points=100,
                             moving_recall=hits / moving, static_flagged=0.01, ms_per_frame=5.0, moving_hits=hits,
                             static_hits=1, object_frames=objects, object_frames_detected=detected)

    totals = pooled([clip(100, 50, 10, 5), clip(300, 30, 30, 3)])
    assert totals["recall"] == pytest.approx(80 / 400)  # the per-clip mean would be 0.3
    assert totals["static_flagged"] == pytest.approx(2 / 200)
    assert totals["object_frames"] == 40 and totals["object_frames_detected"] == pytest.approx(8 / 40)
    assert np.isnan(pooled([])["recall"])
