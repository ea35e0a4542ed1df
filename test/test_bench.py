"""`moseg bench pipeline` and `moseg bench synth` print their numbers (speed targets live here, not in tests)."""

import json

from moseg_ros.cli import main


def test_pipeline_bench_prints_timing_for_both_methods(capsys):
    for method, preset in (("epipolar_baseline", "fast"), ("object_level", "medium")):
        assert main(["bench", "pipeline", "--frames", "5", "--method", method]) == 0
        result = json.loads(capsys.readouterr().out)
        assert result["method"] == method and result["flow_preset"] == preset
        assert result["frames"] == 4 and (result["width"], result["height"]) == (1242, 375)
        assert 0 < result["ms_p50"] <= result["ms_p95"] <= result["ms_max"]


def test_object_level_bench_needs_the_synthetic_instances(tmp_path, capsys):
    assert main(["bench", "pipeline", str(tmp_path), "--method", "object_level"]) == 2
    assert "needs instance maps" in capsys.readouterr().out
