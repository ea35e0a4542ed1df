"""`moseg synth-eval`: the pipeline's per-object decisions scored on rendered presets (moseg_ros.synth.evaluate)."""

import json

from moseg_ros.cli import main
from moseg_ros.pipeline import PipelineConfig
from moseg_ros.synth.evaluate import score_scene, totals


def test_car_ahead_scored_by_both_methods():
    common = dict(n_frames=8, width=621)
    object_level = score_scene("ahead", 0, PipelineConfig(method="object_level"), **common)
    baseline = score_scene("ahead", 0, PipelineConfig(), **common)
    assert set(object_level) == {"car_ahead"} and object_level["car_ahead"]["moving"]
    assert object_level["car_ahead"]["seen"] == 5  # 8 frames, the first 3 not counted
    assert object_level["car_ahead"]["flagged"] >= 4  # decided at the first refit (frame 2)
    assert baseline["car_ahead"]["flagged"] == 0  # moves along the epipolar lines
    assert totals([object_level, baseline]) == {
        "moving_flagged": object_level["car_ahead"]["flagged"], "moving_seen": 10,
        "static_flagged": 0, "static_seen": 0}


def test_command_prints_and_writes_totals(tmp_path, capsys):
    out = tmp_path / "scores.json"
    assert main(["synth-eval", "--presets", "parked", "--seeds", "1", "--frames", "6", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "parked_car_1:0/3" in printed and "static object-frames flagged 0/3" in printed
    data = json.loads(out.read_text())
    assert data["totals"]["static_seen"] == 3 and data["scenes"][0]["preset"] == "parked"


def test_unknown_preset_is_refused(capsys):
    assert main(["synth-eval", "--presets", "highway"]) == 2
    assert "presets must be among" in capsys.readouterr().out
