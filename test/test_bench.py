"""`moseg bench pipeline` and `moseg bench synth` print their numbers (speed targets live here, not in tests)."""

import json
import time

import numpy as np
import pytest

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
    assert "needs instance maps" in capsys.readouterr().err


def test_benches_refuse_bad_input_with_a_clear_error(tmp_path, capsys):
    """No traceback: a missing bag, a folder that is no bag, a bag with two image topics and no --topic, too
    few frames to render."""
    from moseg_ros.io.bag_writer import BagWriter

    two = tmp_path / "two"
    with BagWriter(two) as writer:
        for stamp in range(1, 5):
            for topic in ("/left/image_raw", "/right/image_raw"):
                writer.write_image(topic, stamp, "cam", np.full((32, 48), 9 * stamp, np.uint8), "mono8")
    cases = [(["bench", "pipeline", str(tmp_path / "nope")], "not found"),
             (["bench", "pipeline", str(tmp_path)], "rosbag2 folder"),
             (["bench", "pipeline", str(two)], "several image topics"),
             (["bench", "fleet", str(tmp_path / "nope")], "not a bag"),
             (["bench", "synth", "--frames", "0"], "n_frames must be >= 1")]
    for argv, reason in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"moseg {argv[0]} {argv[1]}: error:" in err and reason in err and "Traceback" not in err, (argv, err)
    assert main(["bench", "pipeline", str(two), "--topic", "/right/image_raw", "--frames", "4"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 3


def test_pipeline_bench_reports_stages_floor_and_the_refit_worker(textured_bag, tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "pipeline", str(textured_bag), "--frames", "12", "--json", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    result = json.loads(out.read_text())
    assert printed == result
    assert result["method"] == "moving_objects" and result["refit"] == "background" and result["frames"] == 11
    for key in ("ms_p50", "ms_p95", "floor_ms_p50", "floor_ms_p95", "refit_ms_p50", "refit_ms_p95"):
        assert result[key] > 0, key
    assert result["ratio"] == result["ms_p95"] / result["floor_ms_p95"]
    assert {"decode", "prepare", "tracks", "flow", "regions", "render"} <= set(result["stages"])
    assert "fit" not in result["stages"]  # on the worker, not on the frame path
    assert result["refits"] >= 1 and result["refit_age_max"] >= 1
    inline = main(["bench", "pipeline", str(textured_bag), "--frames", "6", "--set", "refit=inline"])
    assert inline == 0 and {"fit", "dense_fit"} <= set(json.loads(capsys.readouterr().out)["stages"])


def test_memory_slope_and_process_sample():
    import os

    from moseg_ros.bench.soak import memory_by_minute, memory_slope, process_sample

    samples = [(t, 100.0 + 0.5 * t, 0.0) for t in range(0, 300, 10)]  # 0.5 MB/s = 30 MB/min
    assert abs(memory_slope(samples, 60.0) - 30.0) < 1e-6
    assert memory_by_minute(samples) == [100.0, 130.0, 160.0, 190.0, 220.0]  # t = 0, 60, ..., 240 s
    assert memory_slope(samples[:3], 60.0) != memory_slope(samples[:3], 60.0)  # too few samples: nan
    rss, cpu = process_sample(os.getpid())
    assert rss > 10 and cpu > 0


def test_soak_runs_the_real_node_and_reports(textured_bag, ros_domain, tmp_path, capsys):
    out = tmp_path / "soak.json"
    code = main(["bench", "soak", str(textured_bag), "--rate", "5", "--seconds", "4", "--domain", str(ros_domain),
                 "--set", "queue_size=2", "--set", "refit_wait_ms=20", "--json", str(out)])
    report = json.loads(out.read_text())
    assert code == 0, report
    assert report["frames"] == 20 and 0 < report["masks"] <= 20
    assert report["masked_fraction"] == report["masks"] / 20
    assert 0 < report["latency_ms_p50"] <= report["latency_ms_p95"]
    assert report["node_dropped"] >= 0 and report["node_carried"] >= 0 and report["node_exit_code"] == 0
    assert 0 < report["processed_fraction"] <= report["masked_fraction"] and report["node_latency_ms_p95"] > 0
    assert report["rss_mb_start"] > 10 and report["rss_mb_end"] > 10 and report["cpu_percent"] > 0
    assert report["rss_mb_by_minute"] == [round(report["rss_mb_start"], 1)]  # a 4 s run: its start only
    assert main(["bench", "soak", str(textured_bag), "--set", "nope=1"]) == 2


def test_soak_writes_each_setting_as_ros_reads_its_type_back():
    from moseg_ros.bench.soak import _node_params

    assert _node_params(["refit_wait_ms=100", "queue_size=2", "object_level.ground_contact=True", "refit=inline"]) == [
        "refit_wait_ms:=100.0", "queue_size:=2", "object_level.ground_contact:=true", "refit:=inline"]
    with pytest.raises(ValueError, match="queue_size must be a int"):
        _node_params(["queue_size=two"])
    with pytest.raises(ValueError, match="refit_wait_ms -5.0 must be within"):
        _node_params(["refit_wait_ms=-5"])


def test_pipeline_bench_paces_frames_at_a_camera_rate(textured_bag, capsys, monkeypatch):
    import moseg_ros.bench.pipeline as bench

    starts = []
    process = bench.Pipeline.process
    monkeypatch.setattr(bench.Pipeline, "process",
                        lambda self, *a, **k: starts.append(time.perf_counter()) or process(self, *a, **k))
    assert main(["bench", "pipeline", str(textured_bag), "--frames", "8", "--rate", "20"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["rate_hz"] == 20.0 and result["frames"] == 7
    # every frame starts no earlier than its time at 20 Hz after the first
    assert all(t - starts[0] >= i / 20 - 1e-3 for i, t in enumerate(starts))
    assert main(["bench", "pipeline", str(textured_bag), "--rate", "-1"]) == 2


class TestRepeated:
    RUNS = [{"frames": 11, "ms_p95": 30.0, "ratio": 1.2, "refit": "background", "stages": {"flow": {"p50": 5.0}}},
            {"frames": 11, "ms_p95": 50.0, "ratio": 2.0, "refit": "background", "stages": {"flow": {"p50": 9.0}}},
            {"frames": 11, "ms_p95": 40.0, "ratio": 1.5, "refit": "background", "stages": {"flow": {"p50": 6.0}}}]

    def test_one_run_is_reported_as_it_is(self):
        from moseg_ros.bench.pipeline import repeated

        assert repeated(self.RUNS[:1]) == self.RUNS[0]

    def test_medians_with_their_ranges(self):
        from moseg_ros.bench.pipeline import repeated

        result = repeated(self.RUNS)
        assert result["repeats"] == 3 and result["ms_p95"] == 40.0 and result["ratio"] == 1.5
        assert result["stages"] == {"flow": {"p50": 6.0}}
        assert result["ranges"] == {"ms_p95": [30.0, 50.0], "ratio": [1.2, 2.0]}
        assert result["frames"] == 11 and result["refit"] == "background"  # shared by every run: as it is
        assert "partial" not in result

    def test_a_number_only_some_runs_have_is_the_median_of_those(self):
        from moseg_ros.bench.pipeline import repeated

        runs = [dict(self.RUNS[0], fusion_ms_p50=8.0), self.RUNS[1],
                dict(self.RUNS[2], fusion_ms_p50=4.0, stages={"flow": {"p50": 6.0}, "fusion": {"p50": 1.0}})]
        result = repeated(runs)
        assert result["fusion_ms_p50"] == 6.0 and result["ranges"]["fusion_ms_p50"] == [4.0, 8.0]
        assert result["partial"] == {"fusion_ms_p50": 2}
        assert result["stages"] == {"flow": {"p50": 6.0}, "fusion": {"p50": 1.0}}
        assert repeated(runs[1:2] + runs[:1])["fusion_ms_p50"] == 8.0  # the first run need not have it


def test_pipeline_bench_repeats_on_the_same_frames(textured_bag, capsys, monkeypatch):
    import moseg_ros.bench.pipeline as bench

    runs = []
    run = bench.bench_pipeline
    monkeypatch.setattr(bench, "bench_pipeline", lambda frames, *a, **k: runs.append(frames) or run(frames, *a, **k))
    assert main(["bench", "pipeline", str(textured_bag), "--frames", "6", "--repeat", "2"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert len(runs) == 2 and runs[0] is runs[1] and result["repeats"] == 2 and result["frames"] == 5
    assert result["ranges"]["ms_p95"][0] <= result["ms_p95"] <= result["ranges"]["ms_p95"][1]
    assert main(["bench", "pipeline", str(textured_bag), "--repeat", "0"]) == 2
    assert "--repeat >= 1" in capsys.readouterr().err


def test_the_fused_decisions_are_timed_once_each_and_their_ages_kept():
    from types import SimpleNamespace

    from moseg_ros.bench.pipeline import _fusion_numbers

    def frame(age, seconds):
        named = {"fusion_age": age, "fusion_seconds": seconds}
        return SimpleNamespace(telemetry={key: value for key, value in named.items() if value is not None})

    numbers = _fusion_numbers([frame(None, None), frame(0, 0.02), frame(1, None), frame(2, 0.04), frame(1, None)])
    assert numbers["fusions"] == 2
    assert numbers["fusion_ms_p50"] == pytest.approx(30.0)
    assert numbers["fusion_age_mean"] == pytest.approx(1.0)
    assert numbers["fusion_age_max"] == 2
    assert _fusion_numbers([frame(None, None)]) == {}


def test_each_refit_counts_once_with_all_it_did():
    """A refit's track half can reach a frame before its dense half: the refit of frame 2, applied by frame 2
    with its track half (10 ms) and by frame 3 whole (50 ms), is one refit of 50 ms beside those of frames 1
    (20 ms) and 3 (30 ms)."""
    from types import SimpleNamespace

    from moseg_ros.bench.pipeline import _refit_numbers

    def frame(age, stages):
        return SimpleNamespace(telemetry={} if age is None else {"refit_age": age}, refit_stages=stages)

    results = [frame(None, {}), frame(0, {"fit": 0.02}), frame(0, {"fit": 0.01}),
               frame(1, {"fit": 0.01, "dense_fit": 0.04}), frame(1, {"fit": 0.03}), frame(2, {})]
    numbers = _refit_numbers(results, "background")
    assert numbers["refits"] == 3
    assert numbers["refit_ms_p50"] == pytest.approx(30.0)
    assert numbers["refit_age_max"] == 2
