"""The node declares exactly the schema's parameters, with descriptors carrying the schema's ranges."""

from __future__ import annotations

import pytest

from moseg_ros.config import all_settings

node = pytest.importorskip("moseg_ros.node", reason="rclpy (ROS 2 Jazzy from PyPI) is not installed")


def test_node_parameters_are_the_schema():
    assert {name: default for name, (default, _) in node.PARAMETERS.items()} == {
        entry.name: entry.default for entry in all_settings()}


def test_descriptors_carry_ranges_and_choices():
    _, width = node.PARAMETERS["working_width"]
    assert (width.integer_range[0].from_value, width.integer_range[0].to_value) == (64, 4096)
    _, fraction = node.PARAMETERS["moving_objects.instance_min_fraction"]
    assert fraction.floating_point_range[0].to_value == 1.0
    _, method = node.PARAMETERS["method"]
    assert "moving_objects" in method.additional_constraints and method.description


def test_the_method_settings_bare_names_are_declared_deprecated_and_unset():
    assert set(node.DEPRECATED) == {"window_length", "track_width", "max_tracks", "min_region_area", "object_fusion",
                                    "instance_min_fraction", "instance_hold_fraction", "instance_unknown_regions",
                                    "residual_threshold_px", "min_persistence", "refit_interval", "ground_contact"}
    assert "moving_objects.window_length / object_level.window_length" in node.DEPRECATED["window_length"].description
