"""Folders of image files (moseg_ros.io.files)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import PIL.Image
import pytest

from moseg_ros.io.files import frame_number, image_files, natural_key, read_frame


class TestNaturalKey:
    def test_numbers_compare_as_numbers(self):
        names = ["10.jpg", "2.jpg", "1.jpg", "frame_10.png", "frame_9.png", "000011.png", "000003.png"]
        assert sorted(names, key=natural_key) == ["1.jpg", "2.jpg", "000003.png", "10.jpg", "000011.png",
                                                  "frame_9.png", "frame_10.png"]

    def test_zero_padded_names_keep_their_plain_order(self):
        names = [f"{i:06d}.png" for i in (12, 3, 7)]
        assert sorted(names, key=natural_key) == sorted(names)


class TestImageFiles:
    def test_suffixes_in_any_case_hidden_files_and_folders_left_out(self, tmp_path):
        for name in ("10.JPG", "2.jpg", "._2.jpg", "notes.txt", "1.png"):
            (tmp_path / name).write_bytes(b"")
        (tmp_path / "3.jpg").mkdir()
        assert [p.name for p in image_files(tmp_path, (".jpg", ".png"))] == ["1.png", "2.jpg", "10.JPG"]
        assert image_files(tmp_path / "absent", (".jpg",)) == []

    def test_one_file_per_stem(self, tmp_path):
        for name in ("00000.png", "00000.jpg", "00001.png"):
            (tmp_path / name).write_bytes(b"")
        assert [p.name for p in image_files(tmp_path, (".jpg", ".png"))] == ["00000.jpg", "00001.png"]


class TestFrameNumber:
    def test_known_values(self):
        assert frame_number(Path("000042.png")) == 42
        assert frame_number(Path("cam0_frame_7.jpg")) == 7
        assert frame_number(Path("left.png")) is None


class TestReadFrame:
    def test_grey_colour_and_sixteen_bit(self, tmp_path):
        PIL.Image.fromarray(np.full((4, 5), 9, dtype=np.uint8)).save(tmp_path / "g.png")
        PIL.Image.fromarray(np.zeros((4, 5, 3), dtype=np.uint8)).save(tmp_path / "c.jpg")
        PIL.Image.fromarray(np.full((4, 5), 0x1234, dtype=np.uint16)).save(tmp_path / "d.png")
        assert read_frame(tmp_path / "g.png").shape == (4, 5)
        assert read_frame(tmp_path / "c.jpg").shape == (4, 5, 3)
        deep = read_frame(tmp_path / "d.png")
        assert deep.dtype == np.uint8 and (deep == 0x12).all()

    def test_a_truncated_or_missing_file_is_an_error(self, tmp_path):
        rng = np.random.default_rng(0)
        PIL.Image.fromarray(rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)).save(tmp_path / "f.jpg")
        whole = (tmp_path / "f.jpg").read_bytes()
        (tmp_path / "f.jpg").write_bytes(whole[:len(whole) // 3])
        with pytest.raises(ValueError, match="could not decode"):
            read_frame(tmp_path / "f.jpg")
        with pytest.raises(ValueError, match="cannot read"):
            read_frame(tmp_path / "absent.png")
