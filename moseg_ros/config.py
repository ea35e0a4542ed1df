"""The pipeline's settings (``PipelineConfig``) and how tools and the node read every setting.

Each setting is declared once with ``setting(...)`` (moseg_ros/params.py); the node's parameter descriptors, the
check of ``config/segmenter.yaml``, the README's parameter table (checked by a test) and every tool's
``--params FILE`` / ``--set NAME=VALUE`` derive from these declarations.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import importlib
import sys
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from moseg_ros.frontend.flow import DIS_PRESETS
from moseg_ros.methods import DEFAULT_METHOD, METHODS, method_class
from moseg_ros.params import (NodeSettings, Setting, SettingsError, apply_overrides, check_all, read_parameter_file,
                              setting, settings_of)


# auto: each method's own preset (methods/*.py: fast for epipolar_baseline, balanced for moving_objects; medium
# for object_level, whose ground-contact test compares flows of a pixel or two).
FLOW_PRESETS = ("auto", *DIS_PRESETS)
REFIT_MODES = ("auto", "background", "inline")


@dataclass(frozen=True)
class PipelineConfig:
    """Every setting of the pipeline, each declared once with its range and description (moseg_ros/params.py);
    the node's parameters, the YAML file and every tool's --params/--set map one to one onto these fields."""

    method: str = setting(DEFAULT_METHOD, "motion decision method: moving_objects finds the moving objects itself "
                          "(tracks + dense flow, no weights); epipolar_baseline; object_level (needs use_instances)",
                          choices=tuple(METHODS))
    working_width: int = setting(640, "frames are processed at this width (pixels; dense flow)", low=64, high=4096)
    working_pixels: int = setting(128_000, "frames are processed at no more than this many pixels (dense flow; a "
                                  "4:3 camera at working_width would hold 2.5 times a KITTI frame's; 0: no "
                                  "limit)", low=0, high=16_777_216)
    flow_preset: str = setting("auto", "DIS optical flow preset (auto: fast for epipolar_baseline, balanced for "
                               "moving_objects, medium for object_level)",
                               choices=FLOW_PRESETS)
    mask_margin_px: int = setting(6, "dilation of published masks (output pixels)", low=0, high=100)
    instance_model: str = setting("", "path of a TorchScript instance-segmentation model run on every frame "
                                  "(empty: none; see frontend/torch_instances.py); upstream instances win")
    refit: str = setting("auto", "moving_objects: where the motion models are refitted: background (a worker "
                         "thread; a frame's mask never waits for a refit and applies the newest one done, whose track "
                         "test comes before its dense half), inline "
                         "(every frame waits for its own; deterministic), auto (background in the node, inline in "
                         "the offline tools)", choices=REFIT_MODES)
    refit_nice: int = setting(10, "moving_objects: niceness added to the background refit's thread, so on a busy "
                              "CPU the frame path goes first and the refit takes the time left (0: same priority)",
                              low=0, high=19)
    refit_duty: float = setting(0.75, "moving_objects: the largest share of the time the background refit may fit; "
                                "after each refit its worker rests so long that it fits no more (1: back to back). "
                                "Below 1 the frame path keeps the second core oftener, and decisions are older",
                                low=0.05, high=1.0)
    refit_dense_every: int = setting(2, "moving_objects: while whole background refits, with the worker's rests, "
                                     "take longer than the camera's frame interval, only every this many refits fit "
                                     "their dense half (and any refit a frame waits for whole); the others hand over "
                                     "their track test alone, so that the track flags, whose age costs most, come "
                                     "oftener (1: every refit)", low=1, high=100)
    refit_wait_ms: float = setting(-1.0, "moving_objects: how long a frame may wait for the background refit of "
                                   "its own observation before it takes the newest refit done. -1 (auto): as long as "
                                   "the camera's rate leaves before the next frame, for the whole refit when it fits "
                                   "in that time (the masks of the offline tools), else for its track half when that "
                                   "fits (at 10 Hz on two cores: its own track flags, the dense mask a frame old); at "
                                   "30 Hz there is no time, and decisions are a frame or more old); 0: never waits, "
                                   "the lowest latency (only the stream's "
                                   "first decisions, up to the first with a pair for the track test, always wait for "
                                   "their own)", low=-1.0, high=1000.0)
    opencv_threads: int = setting(0, "threads OpenCV's tracking, flow and fits may use, for the whole process while "
                                  "the pipeline runs (0: one when the refit runs on its background worker, so that "
                                  "the frame path and the refit each keep a core of their own; otherwise OpenCV's "
                                  "own choice, the CPUs the process may run on)", low=0, high=1024)

    # Every method's own settings (its module's SETTINGS: its stages' settings), by method name, in the order of
    # METHODS; the defaults of those not given. Read them with ``settings`` / ``settings_of``.
    methods: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        given = dict(self.methods)
        unknown = sorted(set(given) - set(METHODS))
        if unknown:
            raise ValueError(f"settings of unknown methods {unknown}; methods: {sorted(METHODS)}")
        object.__setattr__(self, "methods", tuple((name, given[name] if name in given else settings_class(name)())
                                                   for name in METHODS))

    @classmethod
    def of(cls, **values: Any) -> PipelineConfig:
        """A config from names: the pipeline's settings by name, a method's by its bare name for every method that
        has it (``PipelineConfig.of(refit="inline", object_fusion=False)``); see ``config_from_values``."""
        return config_from_values(values)

    @property
    def settings(self) -> Any:
        """The chosen method's own settings."""
        return self.settings_of(self.method)

    def settings_of(self, name: str) -> Any:
        """Method ``name``'s own settings (an instance of its module's SETTINGS)."""
        return dict(self.methods)[name]

    def refit_mode(self, live: bool) -> str:
        """background or inline: what refit stands for in a live stream (the node) or offline (tools)."""
        if self.refit != "auto":
            return self.refit
        return "background" if live else "inline"

    def opencv_thread_count(self) -> int:
        """The threads OpenCV gets while the pipeline runs (0: OpenCV's own choice), for a config whose refit
        is resolved (``refit_mode``). With a background refit OpenCV's parallel KLT and DIS on the frame path and
        the refit's own thread would contend for the same cores of a small CPU; one thread each is as fast at
        p95 on two cores and leaves the refit a core (docs/experiments.md)."""
        if self.opencv_threads > 0:
            return self.opencv_threads
        return 1 if self.refit == "background" else 0

    def dis_preset(self) -> str:
        """The DIS preset that flow_preset stands for (auto: by method)."""
        if self.flow_preset != "auto":
            return self.flow_preset
        return method_class(self.method).flow_preset

    def validate(self) -> None:
        """Raise ValueError naming the first setting of the wrong type or out of range."""
        check_all(self)
        for name, own in self.methods:
            if type(own) is not settings_class(name):
                raise ValueError(f"{name}'s settings must be a {settings_class(name).__name__}, got {own!r}")
            try:
                check_all(own)
            except ValueError as error:
                raise ValueError(f"{name}.{error}") from None


def settings_class(name: str) -> type:
    """Method ``name``'s settings dataclass (its module's ``SETTINGS``: its stages' settings)."""
    return importlib.import_module(METHODS[name]).SETTINGS


def method_settings() -> dict[str, list[Setting]]:
    """Each method's own settings, by method name."""
    return {name: settings_of(settings_class(name)) for name in METHODS}


def all_settings() -> list[Setting]:
    """Every setting of the node: its own, the pipeline's, then each method's as ``method.name`` (the node's
    parameters; nested by method in its YAML)."""
    nested = [dataclasses.replace(entry, name=f"{method}.{entry.name}")
              for method, entries in method_settings().items() for entry in entries]
    return settings_of(NodeSettings) + settings_of(PipelineConfig) + nested


def pipeline_settings() -> list[Setting]:
    """The settings a PipelineConfig takes: the pipeline's and each method's as ``method.name``."""
    node = {entry.name for entry in settings_of(NodeSettings)}
    return [entry for entry in all_settings() if entry.name not in node]


def bare_names() -> dict[str, list[str]]:
    """Each method setting's bare name (as the parameters were named before they were nested by method) -> its
    nested names: ``window_length`` -> ``moving_objects.window_length``, ``object_level.window_length``."""
    names: dict[str, list[str]] = {}
    for method, entries in method_settings().items():
        for entry in entries:
            names.setdefault(entry.name, []).append(f"{method}.{entry.name}")
    return names


def nested_values(values: dict[str, Any], warn: Callable[[str], None] | None = None) -> dict[str, Any]:
    """``values`` by name with every bare method-setting name replaced by its nested names (a nested name given
    too wins); ``warn`` is told of each bare name (deprecated in parameter files and ``--set``)."""
    bare = bare_names()
    out: dict[str, Any] = {}
    for name, value in values.items():
        if name in bare:
            if warn is not None:
                warn(f"parameter {name!r} is deprecated: name it {' / '.join(bare[name])}")
            out.update({nested: value for nested in bare[name]})
    out.update({name: value for name, value in values.items() if name not in bare})
    return out


def config_from_values(values: dict[str, Any], warn: Callable[[str], None] | None = None) -> PipelineConfig:
    """The PipelineConfig of ``values`` by name (``pipeline_settings``' names; bare method-setting names are
    taken for every method that has them, ``nested_values``); ValueError names an unknown one."""
    values = nested_values(values, warn)
    unknown = sorted(set(values) - {entry.name for entry in pipeline_settings()})
    if unknown:
        raise ValueError(f"unknown parameters {unknown}")
    shell = {name: value for name, value in values.items() if "." not in name}
    own: dict[str, dict[str, Any]] = {}
    for name, value in values.items():
        if "." in name:
            method, _, field_name = name.partition(".")
            own.setdefault(method, {})[field_name] = value
    methods = tuple((method, settings_class(method)(**fields)) for method, fields in own.items())
    return PipelineConfig(**shell, methods=methods)


def add_settings_arguments(parser: argparse.ArgumentParser, method: bool = True) -> None:
    """``--params FILE`` (the node's YAML), ``--set NAME=VALUE`` (repeatable) and, unless the tool fixes it,
    ``--method NAME`` (short for --set method=NAME); read by ``pipeline_config``."""
    if method:
        parser.add_argument("--method", choices=sorted(METHODS), default=None,
                            help="motion decision method (default: the file's, else the node's default)")
    parser.add_argument("--params", type=Path, metavar="FILE",
                        help="the node's parameter file (config/segmenter.yaml layout); node-only keys are ignored")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override one pipeline setting, e.g. --set method=epipolar_baseline (repeatable)")


def add_live_argument(parser: argparse.ArgumentParser) -> None:
    """``--live HZ``: run the pipeline as the node does (refit ``auto`` on its background worker) with the frames
    paced at a camera's rate, so that what is scored is what the node would publish at that rate."""
    parser.add_argument("--live", type=_rate, default=0.0, metavar="HZ",
                        help="score what the node would publish at a camera of HZ frames a second: the refit on "
                             "its background worker, frames paced (default 0: offline, each frame waits for its "
                             "own refit)")


def _rate(text: str) -> float:
    """argparse type: frames a second, >= 0."""
    value = float(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0 frames a second, got {text}")
    return value


def pipeline_config(args: argparse.Namespace) -> PipelineConfig:
    """The PipelineConfig of a tool's ``--params``, then ``--method``, then ``--set``.

    Raises:
        SettingsError: an unknown name, a value of the wrong type or out of range, an unreadable file.
    """
    try:
        return _pipeline_config(args)
    except (ValueError, TypeError, OSError, yaml.YAMLError) as error:
        raise SettingsError(str(error)) from None


def _pipeline_config(args: argparse.Namespace) -> PipelineConfig:
    warn = functools.partial(print, "moseg: warning:", file=sys.stderr)
    values = read_parameter_file(args.params) if getattr(args, "params", None) else {}
    node = {entry.name for entry in settings_of(NodeSettings)}
    values = nested_values({name: value for name, value in values.items() if name not in node}, warn)
    if getattr(args, "method", None):
        values["method"] = args.method
    schema = pipeline_settings()
    by_name = {entry.name: entry for entry in schema}
    # A bare name parses as its first method's setting (every method that has it declares the same type).
    aliases = [dataclasses.replace(by_name[nested[0]], name=bare) for bare, nested in bare_names().items()]
    values.update(nested_values(apply_overrides({}, getattr(args, "set", []), schema + aliases), warn))
    config = config_from_values(values)
    config.validate()
    return config


def parameters_yaml() -> str:
    """The node's parameter file with every setting at its default, nested by method, each under its description
    (``config/segmenter.yaml`` is this text: ``moseg params``)."""
    lines = ["# Parameters of the `segmenter` node, each at its default (`moseg params`: generated from the",
             "# settings' declarations). Use: ros2 run moseg_ros segmenter --ros-args --params-file THIS_FILE",
             "/**:", "  ros__parameters:"]
    method = None
    for entry in all_settings():
        owner, _, name = entry.name.rpartition(".")
        indent = "    " + ("  " if owner else "")
        if owner and owner != method:
            lines.append(f"    {owner}:")
            method = owner
        lines += [indent + "# " + line for line in textwrap.wrap(_described(entry), 116 - len(indent))]
        lines.append(f"{indent}{name}: {_yaml_value(entry.default)}")
    return "\n".join(lines) + "\n"


def _described(entry: Setting) -> str:
    """A setting's description with its choices or range."""
    if entry.choices:
        return f"{entry.description} ({' | '.join(entry.choices)})"
    if entry.low is not None:
        return f"{entry.description} ({_bound(entry.low)}..{_bound(entry.high)})"
    return entry.description


def _bound(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return value or '""'
    return repr(value)
