"""The shipped parameter file, the README and the node declare the same parameters with the same defaults."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
node = pytest.importorskip("moseg_ros.node", reason="rclpy (ROS 2 Jazzy from PyPI) is not installed")


def test_parameter_file_matches_the_node():
    shipped = yaml.safe_load((ROOT / "config" / "segmenter.yaml").read_text())["segmenter"]["ros__parameters"]
    declared = {name: default for name, (default, _) in node.PARAMETERS.items()}
    assert shipped == declared


def test_readme_documents_every_parameter():
    readme = (ROOT / "README.md").read_text()
    missing = [name for name in node.PARAMETERS if f"| `{name}` |" not in readme]
    assert not missing


def test_every_parameter_has_a_description():
    assert all(descriptor.description for _, descriptor in node.PARAMETERS.values())
