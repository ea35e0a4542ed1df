"""The one settings schema: every setting declared once, and the YAML, README, node and tools derive from it."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import pytest
import yaml

from moseg_ros.config import parameters_yaml, settings_class, add_settings_arguments, all_settings, pipeline_config
from moseg_ros.params import NodeSettings, Setting, read_parameter_file, settings_of
from moseg_ros.methods import METHODS
from moseg_ros.pipeline import Pipeline, PipelineConfig

ROOT = Path(__file__).resolve().parents[1]


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_settings_arguments(parser)
    return parser.parse_args(list(argv))


class TestSchema:
    def test_every_field_of_the_configs_and_the_methods_settings_is_a_documented_setting(self):
        for cls in (PipelineConfig, NodeSettings, *map(settings_class, METHODS)):
            names = [f.name for f in dataclasses.fields(cls) if f.name != "methods"]
            assert [entry.name for entry in settings_of(cls)] == names
        assert all(entry.description for entry in all_settings())
        assert len({entry.name for entry in all_settings()}) == len(all_settings())  # declared once

    def test_shipped_yaml_holds_exactly_the_schema_defaults_nested_by_method(self):
        shipped = read_parameter_file(ROOT / "config" / "segmenter.yaml")
        assert shipped == {entry.name: entry.default for entry in all_settings()}
        assert shipped["moving_objects.window_length"] == shipped["object_level.window_length"] == 8
        assert (ROOT / "config" / "segmenter.yaml").read_text() == parameters_yaml()  # generated: `moseg params`

    def test_readme_table_lists_every_setting_with_its_default(self):
        readme = (ROOT / "README.md").read_text()
        for entry in all_settings():
            default = entry.default
            shown = str(default).lower() if isinstance(default, bool) else (
                f"`{default}`" if isinstance(default, str) else str(default))
            assert f"| `{entry.name}` | {shown} |" in readme, entry.name


class TestSetting:
    def test_check_names_the_setting_and_the_problem(self):
        width = Setting("working_width", 640, "w", low=64, high=4096)
        width.check(640)
        with pytest.raises(ValueError, match="working_width 10 must be within 64..4096"):
            width.check(10)
        with pytest.raises(ValueError, match="working_width must be a int"):
            width.check("640")
        with pytest.raises(ValueError, match="is not one of"):
            Setting("method", "a", "m", choices=("a", "b")).check("c")
        Setting("fraction", 0.3, "f", low=0.0, high=1.0).check(1)  # an int where a float is due is fine

    def test_parse_follows_the_default_type(self):
        assert Setting("x", 1, "").parse("7") == 7
        assert Setting("x", 1.0, "").parse("0.5") == 0.5
        assert Setting("x", True, "").parse("False") is False
        with pytest.raises(ValueError, match="true or false"):
            Setting("x", True, "").parse("yes")


class TestPipelineConfig:
    def test_defaults_without_options(self):
        assert pipeline_config(_parse()) == PipelineConfig()

    def test_params_file_then_set_then_method(self, tmp_path):
        path = tmp_path / "p.yaml"
        path.write_text(yaml.safe_dump({"segmenter": {"ros__parameters": {
            "working_width": 320, "queue_size": 2, "method": "object_level"}}}))
        config = pipeline_config(_parse("--params", str(path), "--set", "mask_margin_px=0",
                                        "--method", "epipolar_baseline"))
        assert (config.working_width, config.mask_margin_px, config.method) == (320, 0, "epipolar_baseline")
        Pipeline(config)  # a valid configuration

    @pytest.mark.parametrize("argv, message", [
        (("--set", "nonsense=1"), "expected NAME=VALUE"),
        (("--set", "working_width=wide"), "working_width must be a int"),
        (("--set", "working_width=8"), "working_width 8 must be within"),
        (("--set", "queue_size=2"), "expected NAME=VALUE"),  # a node setting, not the pipeline's
    ])
    def test_bad_overrides_are_named(self, argv, message):
        with pytest.raises(ValueError, match=message):
            pipeline_config(_parse(*argv))

    def test_unknown_key_in_a_params_file_is_refused(self, tmp_path):
        path = tmp_path / "p.yaml"
        path.write_text("/**:\n  ros__parameters:\n    wrking_width: 320\n")
        with pytest.raises(ValueError, match="unknown parameters"):
            pipeline_config(_parse("--params", str(path)))


def test_a_tool_refuses_a_bad_setting_with_exit_code_2(capsys):
    from moseg_ros.cli import main

    assert main(["synth-eval", "--presets", "parked", "--set", "working_width=8"]) == 2
    assert "moseg: error: working_width 8 must be within 64..4096" in capsys.readouterr().err


class TestMethodSettings:
    """A method's settings are its stages' and are named ``method.name``; the bare names of before still work, with a
    deprecation warning, for every method that has the setting."""

    def test_nested_names_in_a_params_file_and_in_set(self, tmp_path):
        path = tmp_path / "p.yaml"
        path.write_text("/**:\n  ros__parameters:\n    working_width: 320\n    moving_objects:\n"
                        "      object_fusion: false\n    object_level:\n      window_length: 12\n")
        config = pipeline_config(_parse("--params", str(path), "--set", "moving_objects.track_width=621"))
        assert config.working_width == 320 and config.settings.object_fusion is False
        assert config.settings.track_width == 621 and config.settings.window_length == 8
        assert config.settings_of("object_level").window_length == 12

    def test_bare_names_warn_and_apply_to_every_method_that_has_them(self, tmp_path, capsys):
        path = tmp_path / "p.yaml"
        path.write_text("segmenter:\n  ros__parameters:\n    window_length: 10\n")
        config = pipeline_config(_parse("--params", str(path), "--set", "object_fusion=false"))
        assert config.settings.window_length == config.settings_of("object_level").window_length == 10
        assert config.settings.object_fusion is False
        err = capsys.readouterr().err
        assert "'window_length' is deprecated: name it moving_objects.window_length / object_level" in err
        assert "'object_fusion' is deprecated" in err

    def test_set_wins_over_the_file_bare_or_nested(self, tmp_path):
        path = tmp_path / "p.yaml"
        path.write_text("/**:\n  ros__parameters:\n    moving_objects:\n      object_fusion: true\n")
        assert pipeline_config(_parse("--params", str(path), "--set", "object_fusion=false")).settings.object_fusion \
            is False

    def test_a_bad_nested_value_is_named(self):
        with pytest.raises(ValueError, match="moving_objects.track_width 8 must be within 64..4096"):
            pipeline_config(_parse("--set", "moving_objects.track_width=8"))
        with pytest.raises(ValueError, match="unknown parameters"):
            PipelineConfig.of(**{"moving_objects.nonsense": 1})

    def test_of_takes_bare_names_and_replace_keeps_the_methods_settings(self):
        from dataclasses import replace

        config = PipelineConfig.of(refit="inline", object_fusion=False, min_region_area=5)
        assert config.settings.object_fusion is False and config.settings_of("epipolar_baseline").min_region_area == 5
        assert replace(config, method="object_level").settings_of("moving_objects").object_fusion is False
        assert PipelineConfig() == PipelineConfig.of()
