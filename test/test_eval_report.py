"""The evaluations' strict JSON reports (moseg_ros.eval.report)."""

from __future__ import annotations

import json
import math

from moseg_ros.eval.report import without_nan, write_json


class TestWithoutNan:
    def test_known_values(self):
        report = {"j": float("nan"), "rows": [{"x": 1.5, "y": float("inf")}, (2, -math.inf)], "name": "a"}
        assert without_nan(report) == {"j": None, "rows": [{"x": 1.5, "y": None}, [2, None]], "name": "a"}

    def test_write_json_is_strict_json(self, tmp_path):
        write_json(tmp_path / "r.json", {"mean_j": float("nan"), "clips": []})
        text = (tmp_path / "r.json").read_text()
        assert "NaN" not in text and text.endswith("\n")
        assert json.loads(text, parse_constant=lambda name: 1 / 0) == {"mean_j": None, "clips": []}
