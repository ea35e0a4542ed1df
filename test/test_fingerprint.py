"""`moseg fingerprint`: one digest per frame, equal for equal masks, and a comparison that names what differs.

Scene: the textured pan with a block sliding across it (conftest.textured_frames), as a bag with camera_info
and as a folder of PNG frames.
"""

from __future__ import annotations

import json

import cv2
import numpy as np

from conftest import textured_frames
from moseg_ros.cli import main
from moseg_ros.pipeline import FrameResult, PipelineConfig
from moseg_ros.render import Masks
from moseg_ros.methods.base import Status
from moseg_ros.tools.fingerprint import digest, fingerprints, first_differences


def _result(dynamic: np.ndarray, status: Status = Status.OK) -> FrameResult:
    labels = dynamic.astype(np.int32)
    return FrameResult(0, Masks(dynamic, 255 - dynamic, labels), status, np.zeros(0, np.int32), 0.0)


class TestDigest:
    def test_equal_masks_equal_digests_and_one_pixel_or_the_status_changes_it(self):
        mask = np.zeros((4, 6), np.uint8)
        other = mask.copy()
        other[2, 3] = 255
        assert digest(_result(mask)) == digest(_result(mask.copy()))
        assert digest(_result(mask)) != digest(_result(other))
        assert digest(_result(mask)) != digest(_result(mask, Status.WARMUP))
        assert digest(_result(mask)) != digest(_result(mask.reshape(6, 4)))  # the shape counts


class TestFirstDifferences:
    def test_names_the_first_frame_the_count_and_missing_inputs(self):
        before = {"a": ["1", "2", "3"], "b": ["1"], "c": ["1"]}
        now = {"a": ["1", "x", "y"], "b": ["1", "2"], "d": ["1"]}
        assert first_differences(now, before) == {"a": "2 frames differ, the first frame 1",
                                                  "b": "2 frames against 1", "c": "only in the earlier run",
                                                  "d": "only in this run"}
        assert first_differences(before, before) == {}


def test_a_bag_and_an_image_folder_give_the_same_digests_twice(textured_bag, tmp_path, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, frame in enumerate(textured_frames(6)):
        cv2.imwrite(str(folder / f"{i}.png"), frame)
    config = PipelineConfig()
    first = fingerprints(folder, config)
    assert len(first) == 6 and first == fingerprints(folder, config)
    assert len(set(first)) > 1  # the warm-up frame and the frames with the block differ
    report = tmp_path / "digests.json"
    assert main(["fingerprint", str(textured_bag), str(folder), "-o", str(report)]) == 0
    assert len(json.loads(report.read_text())[str(textured_bag)]) == 20
    assert main(["fingerprint", str(textured_bag), str(folder), "--against", str(report)]) == 0
    assert capsys.readouterr().out.rstrip().endswith("identical")
    assert main(["fingerprint", str(folder), "--set", "mask_margin_px=0", "--against", str(report)]) == 1
    assert "differs: " + str(folder) in capsys.readouterr().out
