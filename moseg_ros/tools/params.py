"""`moseg params`: the node's parameter file, every setting at its default under its description, nested by method.

The shipped ``config/segmenter.yaml`` is this output (a test checks it): ``moseg params > config/segmenter.yaml``.
"""

from __future__ import annotations

import argparse

from moseg_ros.config import parameters_yaml


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """`moseg params` takes no options."""


def run(args: argparse.Namespace) -> int:
    """Print the parameter file."""
    print(parameters_yaml(), end="")
    return 0
