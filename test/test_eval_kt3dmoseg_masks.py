"""Dynamic masks on real KT3DMoSeg street frames, scored at the labelled points, on a folder of the same layout."""

from __future__ import annotations

import json

from conftest import shared_data
from moseg_ros.cli import main as moseg


def _subset(tmp_path, clips_with_frames, clips_without_frames=()):
    """A KT3DMoSeg-layout folder with a few clips (symlinks into ../shared/data)."""
    source = shared_data("kt3dmoseg")
    (tmp_path / "Data").mkdir(parents=True)
    (tmp_path / "OriginalSequences").mkdir()
    for clip in (*clips_with_frames, *clips_without_frames):
        (tmp_path / "Data" / f"{clip}_Tracks.mat").symlink_to(source / "Data" / f"{clip}_Tracks.mat")
    for clip in clips_with_frames:
        (tmp_path / "OriginalSequences" / clip).symlink_to(source / "OriginalSequences" / clip)
    return tmp_path


def test_scores_real_frames_at_labelled_points(tmp_path, capsys):
    """Seq005_Clip02 (a car and a cyclist crossing a residential street). Measured with the shipped settings:
    38 % of moving-point observations flagged, 0.5 % of static ones."""
    root = _subset(tmp_path / "kt", ["Seq005_Clip02"], ["Seq020_Clip01"])
    assert moseg(["eval", "kt3dmoseg-masks", str(root), "--json", str(tmp_path / "r.json")]) == 0
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["clips_scored"] == 1 and result["clips_without_frames"] == ["Seq020_Clip01"]
    row = result["clips"][0]
    assert row["frames"] == 20 and row["moving_points"] > 1000 and row["static_points"] > 1000
    assert row["moving_recall"] > 0.25
    assert row["static_flagged"] < 0.02
    assert "Seq005_Clip02" in capsys.readouterr().out
