"""`moseg eval davis` on synthetic folders of the DAVIS-2016 layout and on one real clip (skipped without it)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import PIL.Image
import pytest

from conftest import shared_data, textured_frames
from moseg_ros.cli import main as moseg
from moseg_ros.eval.davis import pair_annotations, read_annotation

HEIGHT, WIDTH = 160, 320  # at 96x160 the default pipeline flags nothing on these frames (measured)


def block_truth(index: int, height: int = HEIGHT, width: int = WIDTH, speed: int = 3) -> np.ndarray:
    """The sliding block of conftest.textured_frames in frame ``index`` (as in test_pipeline.py)."""
    truth = np.zeros((height, width), dtype=bool)
    y = height // 6 + speed * index
    truth[y:y + height // 3, width // 4:width // 4 + width // 8] = True
    return truth


def _write_clip(root: Path, clip: str, image_names: list[str], annotation_names: list[str], seed: int) -> None:
    """One clip of textured frames (RGB, written as BGR like any image file) and its block annotations."""
    images = root / "JPEGImages" / "480p" / clip
    images.mkdir(parents=True)
    for name, frame in zip(image_names, textured_frames(len(image_names), HEIGHT, WIDTH, seed=seed)):
        cv2.imwrite(str(images / name), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    if annotation_names:
        annotations = root / "Annotations" / "480p" / clip
        annotations.mkdir(parents=True)
        for i, name in enumerate(annotation_names):
            cv2.imwrite(str(annotations / name), block_truth(i).astype(np.uint8) * 255)


def test_scores_synthetic_clips_of_any_names_and_lists_a_clip_without_annotations(tmp_path, capsys):
    root = tmp_path / "davis"
    letters = "abcdef"
    # Stems match: paired by stem. Different stems (and png frames): paired by sorted order.
    _write_clip(root, "block-a", [f"frame_{c}.jpg" for c in letters], [f"frame_{c}.png" for c in letters], seed=0)
    _write_clip(root, "block-b", [f"img{i:03d}.png" for i in range(6)], [f"gt_{i}.png" for i in range(6)], seed=1)
    _write_clip(root, "no-gt", [f"{i}.jpg" for i in range(3)], [], seed=2)
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert {"mean_j", "precision", "recall", "ms_per_frame"} <= result.keys()
    assert [c["clip"] for c in result["clips"]] == ["block-a", "block-b"]
    assert result["clips_skipped"] == ["no-gt"]
    assert all(c["frames"] == 6 and c["scored_frames"] == 5 for c in result["clips"])  # frame 0 not scored
    # Measured: J 0.58 and 0.57 (frame 1 is always empty: a region must persist 2 frames), pooled precision
    # 0.74, recall 0.76.
    assert all(0.3 < c["j"] <= 1.0 for c in result["clips"])
    assert 0.3 < result["mean_j"] <= 1.0
    assert 0.5 < result["precision"] <= 1.0 and 0.5 < result["recall"] <= 1.0
    assert result["ms_per_frame"] > 0
    printed = capsys.readouterr().out
    assert "block-b" in printed and "mean over 2 clips" in printed and "skipped" in printed and "no-gt" in printed


def test_live_frames_that_wait_for_their_own_refit_score_as_offline(tmp_path):
    root = tmp_path / "davis"
    _write_clip(root, "block", [f"{i:02d}.jpg" for i in range(8)], [f"{i:02d}.png" for i in range(8)], seed=0)
    runs = {}
    for name, extra in (("offline", []), ("live", ["--live", "20", "--set", "refit_wait_ms=1000"])):
        assert moseg(["eval", "davis", str(root), "--json", str(tmp_path / f"{name}.json"), *extra]) == 0
        runs[name] = json.loads((tmp_path / f"{name}.json").read_text())
    assert runs["live"]["live_hz"] == 20.0 and runs["live"]["config"]["refit_wait_ms"] == 1000.0
    assert runs["live"]["mean_j"] == runs["offline"]["mean_j"] > 0.3


def test_unreadable_frames_and_annotations_are_skipped_and_listed(tmp_path, capsys):
    root = tmp_path / "davis"
    names = [f"{i:05d}" for i in range(6)]
    _write_clip(root, "damaged", [f"{n}.jpg" for n in names], [f"{n}.png" for n in names], seed=0)
    _write_clip(root, "unreadable", [f"{n}.jpg" for n in names[:3]], [f"{n}.png" for n in names[:3]], seed=1)
    (root / "JPEGImages" / "480p" / "damaged" / "00003.jpg").write_bytes(b"not a jpeg")
    (root / "Annotations" / "480p" / "damaged" / "00004.png").write_bytes(b"not a png")
    for name in names[:3]:
        (root / "JPEGImages" / "480p" / "unreadable" / f"{name}.jpg").write_bytes(b"")
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    clip, = result["clips"]
    assert clip["clip"] == "damaged" and clip["unreadable"] == ["00003.jpg", "00004.png"]
    assert clip["frames"] == 6 and clip["scored_frames"] == 3  # frames 1, 2 and 5
    assert result["clips_skipped"] == ["unreadable"]
    printed = capsys.readouterr().out
    assert "damaged: unreadable, skipped: 00003.jpg, 00004.png" in printed


def test_max_frames_and_a_folder_without_clips(tmp_path, capsys):
    root = tmp_path / "davis"
    _write_clip(root, "short", [f"{i:05d}.jpg" for i in range(5)], [f"{i:05d}.png" for i in range(5)], seed=0)
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--max-frames", "3", "--json", str(out)]) == 0
    clip = json.loads(out.read_text())["clips"][0]
    assert clip["frames"] == 3 and clip["scored_frames"] == 2
    assert moseg(["eval", "davis", str(tmp_path / "empty")]) == 2
    assert "no DAVIS clips" in capsys.readouterr().out
    frames_only = tmp_path / "frames_only"
    _write_clip(frames_only, "unlabelled", [f"{i:05d}.jpg" for i in range(3)], [], seed=1)
    out.unlink()
    assert moseg(["eval", "davis", str(frames_only), "--json", str(out)]) == 2
    printed = capsys.readouterr().out
    assert "has a frame scored" in printed and "skipped: unlabelled" in printed and "nan" not in printed
    assert "skipped (no annotations): unlabelled" in printed
    assert not out.exists()


def test_annotations_pair_by_stem_by_order_or_by_number():
    images = [Path(f"{i:05d}.jpg") for i in range(4)]
    # Annotated on a subset of the frames: the others have none.
    assert pair_annotations(images, [Path("00000.png"), Path("00002.png")]) == [
        Path("00000.png"), None, Path("00002.png"), None]
    # No stem in common, as many annotations as frames: by order.
    annotations = [Path(f"gt_{c}.png") for c in "abcd"]
    assert pair_annotations(images, annotations) == annotations
    # No stem in common and fewer annotations: by the number in their names, none without one.
    assert pair_annotations(images, [Path("m0.png"), Path("m2.png")]) == [Path("m0.png"), None, Path("m2.png"), None]
    assert pair_annotations(images, [Path("a.png"), Path("b.png")]) == [None] * 4


class TestReadAnnotation:
    def test_a_palette_image_counts_its_indices_not_its_colours(self, tmp_path):
        indices = np.zeros((4, 6), dtype=np.uint8)
        indices[1:3, 2:5] = 1
        image = PIL.Image.fromarray(indices, mode="P")
        image.putpalette([255, 255, 255, 0, 0, 0] + [0] * 762)  # index 0 white: the background's colour
        image.save(tmp_path / "p.png")
        np.testing.assert_array_equal(read_annotation(tmp_path / "p.png"), indices > 0)

    def test_an_alpha_channel_is_not_the_object(self, tmp_path):
        rgba = np.zeros((4, 6, 4), dtype=np.uint8)
        rgba[..., 3] = 255  # opaque everywhere
        rgba[2, 3, :3] = 200
        PIL.Image.fromarray(rgba, mode="RGBA").save(tmp_path / "a.png")
        grey_alpha = np.stack([rgba[..., 0], rgba[..., 3]], axis=-1)
        PIL.Image.fromarray(grey_alpha, mode="LA").save(tmp_path / "la.png")
        for name in ("a.png", "la.png"):
            mask = read_annotation(tmp_path / name)
            assert mask.shape == (4, 6) and mask.sum() == 1 and mask[2, 3]

    def test_a_damaged_file_is_an_error(self, tmp_path):
        (tmp_path / "bad.png").write_bytes(b"not a png")
        with pytest.raises(ValueError, match="cannot read annotation"):
            read_annotation(tmp_path / "bad.png")


def test_frames_named_by_plain_numbers_are_taken_in_their_order(tmp_path):
    """0.jpg ... 11.jpg: 10.jpg after 9.jpg, not after 1.jpg; hidden files left out. The same J as zero-padded."""
    runs = {}
    for kind, names in (("padded", [f"{i:05d}" for i in range(12)]), ("plain", [str(i) for i in range(12)])):
        root = tmp_path / kind
        _write_clip(root, "block", [f"{n}.jpg" for n in names], [f"{n}.png" for n in names], seed=0)
        (root / "JPEGImages" / "480p" / "block" / "._0.jpg").write_bytes(b"a macOS companion file")
        assert moseg(["eval", "davis", str(root), "--json", str(tmp_path / f"{kind}.json")]) == 0
        runs[kind] = json.loads((tmp_path / f"{kind}.json").read_text())["clips"][0]
    assert runs["plain"]["scored_frames"] == runs["padded"]["scored_frames"] == 11
    assert runs["plain"]["unreadable"] == []
    assert runs["plain"]["j"] == runs["padded"]["j"] > 0.3


def test_annotations_at_another_size_are_scored_at_theirs_or_listed(tmp_path, capsys):
    """Frames resized apart from their annotations: the same aspect is scored at the annotation's size, another
    aspect is listed and not scored (no traceback)."""
    root = tmp_path / "davis"
    names = [f"{i:05d}" for i in range(6)]
    _write_clip(root, "scaled", [f"{n}.jpg" for n in names], [f"{n}.png" for n in names], seed=0)
    _write_clip(root, "squeezed", [f"{n}.jpg" for n in names], [f"{n}.png" for n in names], seed=0)
    for clip, size in (("scaled", (2 * WIDTH, 2 * HEIGHT)), ("squeezed", (WIDTH, 2 * HEIGHT))):
        for path in (root / "Annotations" / "480p" / clip).iterdir():
            cv2.imwrite(str(path), cv2.resize(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), size,
                                              interpolation=cv2.INTER_NEAREST))
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    clip, = result["clips"]
    assert clip["clip"] == "scaled" and clip["scored_frames"] == 5 and clip["j"] > 0.3
    assert result["clips_skipped"] == ["squeezed"]
    assert "skipped" in capsys.readouterr().out


def test_the_first_frame_the_pipeline_gets_is_not_scored_and_a_truncated_frame_is_unreadable(tmp_path):
    root = tmp_path / "davis"
    names = [f"{i:05d}" for i in range(7)]
    _write_clip(root, "damaged", [f"{n}.jpg" for n in names], [f"{n}.png" for n in names], seed=0)
    frames = root / "JPEGImages" / "480p" / "damaged"
    (frames / "00000.jpg").write_bytes(b"")
    whole = (frames / "00004.jpg").read_bytes()
    (frames / "00004.jpg").write_bytes(whole[:len(whole) // 3])  # OpenCV would decode it half grey
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--json", str(out)]) == 0
    clip, = json.loads(out.read_text())["clips"]
    assert clip["unreadable"] == ["00000.jpg", "00004.jpg"]
    assert clip["scored_frames"] == 4  # frames 2, 3, 5 and 6: frame 1 is the pipeline's first


def test_a_clip_without_a_scored_frame_is_skipped(tmp_path, capsys):
    root = tmp_path / "davis"
    _write_clip(root, "one-frame", ["00000.jpg"], ["00000.png"], seed=0)
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--json", str(out)]) == 2
    printed = capsys.readouterr().out
    assert "skipped: one-frame" in printed and "nan" not in printed and not out.exists()
    assert "skipped (one frame: nothing after the pipeline's first): one-frame" in printed


def test_max_frames_cuts_the_pairs_not_the_pairing(tmp_path):
    """Six frames and six annotations without a stem in common pair by order; --max-frames 3 keeps that pairing
    (cut first, three frames against six annotations would have paired by numbers their names do not hold)."""
    root = tmp_path / "davis"
    _write_clip(root, "block", [f"{i:05d}.jpg" for i in range(6)], [f"gt_{c}.png" for c in "abcdef"], seed=0)
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--max-frames", "3", "--json", str(out)]) == 0
    clip, = json.loads(out.read_text())["clips"]
    assert clip["frames"] == 3 and clip["scored_frames"] == 2


def test_a_frame_of_another_size_is_listed_not_run(tmp_path, capsys):
    """The pipeline would start over on a frame of another size (and score frames without motion evidence after
    it): it is listed and left out, and the clip scores as without it."""
    root = tmp_path / "davis"
    names = [f"{i:05d}" for i in range(8)]
    _write_clip(root, "block", [f"{n}.jpg" for n in names], [f"{n}.png" for n in names], seed=0)
    frame = root / "JPEGImages" / "480p" / "block" / "00004.jpg"
    cv2.imwrite(str(frame), cv2.resize(cv2.imread(str(frame)), (WIDTH // 2, HEIGHT // 2)))
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--json", str(out)]) == 0
    clip, = json.loads(out.read_text())["clips"]
    assert clip["mismatched"] == [f"00004.jpg ({WIDTH // 2}x{HEIGHT // 2}, the clip's {WIDTH}x{HEIGHT})"]
    assert clip["scored_frames"] == 6 and clip["j"] > 0.3
    assert "block: not scored, of another size or aspect: 00004.jpg" in capsys.readouterr().out


def _real_clip(tmp_path: Path, clip: str, frames: int) -> dict:
    """`moseg eval davis` on one clip of ../shared/data/davis2016 (linked into a folder of its own)."""
    source = shared_data("davis2016")
    root = tmp_path / "davis"
    for kind in ("JPEGImages", "Annotations"):
        (root / kind / "480p").mkdir(parents=True)
        (root / kind / "480p" / clip).symlink_to(source / kind / "480p" / clip)
    out = tmp_path / "r.json"
    assert moseg(["eval", "davis", str(root), "--max-frames", str(frames), "--json", str(out)]) == 0
    return json.loads(out.read_text())


def test_one_real_clip(tmp_path):
    """DAVIS-2016 'dog' (a dog running, tracking camera), 12 frames: only checks the figures are well formed."""
    result = _real_clip(tmp_path, "dog", 12)
    assert 1 <= len(result["clips"]) <= 10 and result["clips"][0]["scored_frames"] == 11
    for key in ("mean_j", "precision", "recall"):
        assert math.isfinite(result[key]) and 0.0 <= result[key] <= 1.0, key
    assert math.isfinite(result["ms_per_frame"]) and result["ms_per_frame"] > 0


def test_the_default_method_finds_the_camel(tmp_path):
    """DAVIS-2016 'camel' (a camel walking, the camera panning after it), 30 frames. Measured with the default
    method: J 0.60, precision 0.63, recall 0.92 (2026-12-02, DIS balanced; the epipolar baseline: J below 0.01)."""
    result = _real_clip(tmp_path, "camel", 30)
    assert result["mean_j"] > 0.35 and result["recall"] > 0.55 and result["precision"] > 0.4


def test_the_default_method_finds_the_dog_a_turning_camera_follows(tmp_path):
    """DAVIS-2016 'libby' (a dog running, the camera panning after it about 2 degrees a frame), 30 frames: with
    the guessed camera matrix such pairs sign only what lies behind infinity by half the rotation's image
    motion. Measured: J 0.49, recall 0.72 (2026-12-02, DIS balanced); 0.20 and 0.26 when such pairs gave no
    sign at all."""
    result = _real_clip(tmp_path, "libby", 30)
    assert result["mean_j"] > 0.3 and result["recall"] > 0.4


def test_the_flow_view_covers_the_cows_smooth_bodies(tmp_path):
    """DAVIS-2016 'cows' (a cow walking, the camera following), 30 frames: its smooth flank holds few tracks,
    and the flow view around its hulls (core/object_flow.py) grows the region over it. Measured: J 0.71,
    recall 0.89 (2026-12-02, DIS balanced; 0.72 / 0.88 with medium); with DIS fast J 0.65, recall 0.80, and
    without the flow view J 0.46, recall 0.55."""
    result = _real_clip(tmp_path, "cows", 30)
    assert result["mean_j"] > 0.55 and result["recall"] > 0.7 and result["precision"] > 0.65
