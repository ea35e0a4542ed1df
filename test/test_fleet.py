"""`moseg process` over many bags: one output per input, sequentially or as Ray tasks, with the same masks."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import textured_frames
from moseg_ros.cli import main as moseg
from moseg_ros.io.bag_writer import BagWriter
from moseg_ros.io.bags import iter_messages, stamp_to_ns
from moseg_ros.io.image import image_to_array
from moseg_ros.tools.fleet import LOCAL, find_bags, plan_jobs, process_fleet

MASKS = "/segmenter/dynamic_mask"


def _write_bag(path: Path, seed: int, n: int = 12) -> Path:
    with BagWriter(path) as writer:
        for i, frame in enumerate(textured_frames(n, seed=seed)):
            writer.write_image("/camera/image_raw", 1_000 + i * 100_000_000, "cam", frame, "rgb8")
    return path


def _masks(bag: Path) -> dict[int, np.ndarray]:
    return {stamp_to_ns(m.header.stamp): image_to_array(m).copy() for _, _, m in iter_messages(bag, [MASKS])}


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of three small bags (two rosbag2 folders and a bare .mcap) and a corrupt .mcap."""
    folder = tmp_path_factory.mktemp("fleet") / "in"
    folder.mkdir()
    _write_bag(folder / "drive_a", 0)
    _write_bag(folder / "drive_b", 1)
    single = _write_bag(folder.parent / "drive_c", 2)
    next(single.glob("*.mcap")).rename(folder / "drive_c.mcap")
    (folder / "corrupt.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    return folder


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray with 2 CPUs for this module."""
    ray = pytest.importorskip("ray", reason="ray is not installed (requirements.txt pins it)")
    from moseg_ros.tools.fleet import start_ray

    start_ray(LOCAL, workers=2)
    yield ray
    ray.shutdown()


class TestPlanJobs:
    def test_a_folder_of_bags_and_single_bags(self, bags: Path, tmp_path: Path) -> None:
        assert [p.name for p in find_bags([bags])] == ["corrupt.mcap", "drive_a", "drive_b", "drive_c.mcap"]
        jobs = plan_jobs([bags / "drive_a", bags / "drive_c.mcap"], tmp_path / "out")
        assert [(j.name, j.output) for j in jobs] == [("drive_a", tmp_path / "out" / "drive_a"),
                                                      ("drive_c", tmp_path / "out" / "drive_c")]

    def test_refusals_are_specific(self, bags: Path, tmp_path: Path) -> None:
        with pytest.raises(ValueError, match=r"several input bags are named \['drive_a'\]"):
            plan_jobs([bags / "drive_a", bags / "drive_a"], tmp_path)
        (tmp_path / "empty").mkdir()
        with pytest.raises(ValueError, match="neither a bag"):
            find_bags([tmp_path / "empty"])
        with pytest.raises(FileNotFoundError, match="bag not found"):
            find_bags([tmp_path / "nope"])


def test_ray_gives_the_sequential_masks_and_reports_the_corrupt_bag(bags: Path, tmp_path: Path, local_ray) -> None:
    sequential = process_fleet([bags], tmp_path / "seq")
    on_ray = process_fleet([bags], tmp_path / "ray", ray_address=LOCAL, workers=2)
    for summary in (sequential, on_ray):
        status = {row["name"]: row["status"] for row in summary["bags"]}
        assert status == {"corrupt": "failed", "drive_a": "ok", "drive_b": "ok", "drive_c": "ok"}
        corrupt = next(row for row in summary["bags"] if row["name"] == "corrupt")
        assert "corrupt.mcap is damaged" in corrupt["error"]
        assert summary["totals"]["masks_out"] == summary["totals"]["frames_in"] == 36
    assert json.loads((tmp_path / "ray" / "summary.json").read_text())["bags"] == on_ray["bags"]
    assert not (tmp_path / "ray" / "corrupt").exists()
    for name in ("drive_a", "drive_b", "drive_c"):
        first, second = _masks(tmp_path / "seq" / name), _masks(tmp_path / "ray" / name)
        assert len(first) == 12 and first.keys() == second.keys()
        assert all(np.array_equal(first[stamp], second[stamp]) for stamp in first)
    assert max(mask.mean() for mask in _masks(tmp_path / "ray" / "drive_a").values()) > 2.0


def test_complete_outputs_are_skipped_unless_overwritten(bags: Path, tmp_path: Path) -> None:
    inputs = [bags / "drive_a", bags / "drive_b"]
    assert process_fleet(inputs, tmp_path / "out")["totals"]["ok"] == 2
    kept = (tmp_path / "out" / "drive_a" / "drive_a.mcap").stat().st_mtime_ns
    # a run killed inside drive_b leaves .partial/drive_b, and no finished drive_b
    (tmp_path / "out" / "drive_b").rename(tmp_path / "out" / ".partial" / "drive_b")
    again = process_fleet(inputs, tmp_path / "out")
    assert [row["status"] for row in again["bags"]] == ["skipped", "ok"]
    assert (tmp_path / "out" / "drive_a" / "drive_a.mcap").stat().st_mtime_ns == kept
    assert not (tmp_path / "out" / ".partial" / "drive_b").exists()
    redone = process_fleet(inputs, tmp_path / "out", overwrite=True)
    assert [row["status"] for row in redone["bags"]] == ["ok", "ok"]
    assert len(_masks(tmp_path / "out" / "drive_a")) == 12


def test_command_line_prints_the_table_and_exits_by_the_worst_bag(bags: Path, tmp_path: Path, capsys) -> None:
    code = moseg(["process", str(bags / "drive_a"), str(bags / "drive_b"), "-o", str(tmp_path / "o"),
                  "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0 and "2 ok, 0 damaged, 0 failed, 0 skipped (sequential)" in out
    assert moseg(["process", str(bags / "corrupt.mcap"), str(bags / "drive_a"), "-o", str(tmp_path / "o"),
                  "--no-progress"]) == 1
    assert moseg(["process", str(bags), "-o", str(tmp_path / "o"), "--ray", "--workers", "0"]) == 2
    assert "--workers must be >= 1" in capsys.readouterr().err


def test_bench_fleet_reports_every_run(bags: Path, local_ray) -> None:
    from moseg_ros.bench.fleet import bench_fleet

    result = bench_fleet(bags / "drive_a", copies=2, workers=2)
    assert result["bags"] == 2 and result["frames_per_bag"] == 12 and result["workers"] == 2
    for run in ("sequential", "ray_1_worker", "ray_2_workers"):
        assert result[run]["seconds"] > 0 and result[run]["bags_per_second"] == pytest.approx(
            2 / result[run]["seconds"])
    assert result["speedup"] == pytest.approx(result["sequential"]["seconds"] / result["ray_2_workers"]["seconds"])
    assert result["ray_startup_seconds"] >= 0 and "ray_overhead_seconds_per_bag" in result
    assert np.isfinite(result["parallel_ceiling"]) and result["parallel_ceiling"] > 0  # a ratio of timings:
    # its value depends on the machine's load, which a test cannot bound
