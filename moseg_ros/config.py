"""The pipeline's settings (``PipelineConfig``) and how tools and the node read every setting.

Each setting is declared once with ``setting(...)`` (moseg_ros/params.py); the node's parameter descriptors, the
check of ``config/segmenter.yaml``, the README's parameter table (checked by a test) and every tool's
``--params FILE`` / ``--set NAME=VALUE`` derive from these declarations.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from pathlib import Path

import yaml

from moseg_ros.core.baseline import BaselineConfig
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
    track_width: int = setting(1280, "moving_objects: KLT tracks run at this width (pixels)", low=64, high=4096)
    max_tracks: int = setting(2000, "moving_objects: points tracked per frame", low=50, high=20000)
    flow_preset: str = setting("auto", "DIS optical flow preset (auto: fast for epipolar_baseline, balanced for "
                               "moving_objects, medium for object_level)",
                               choices=FLOW_PRESETS)
    residual_threshold_px: float = setting(1.5, "epipolar_baseline: epipolar residual above which a pixel moves "
                                           "(working px)", low=0.1, high=50.0)
    min_region_area: int = setting(60, "smallest moving region kept (working pixels)", low=1, high=100000)
    min_persistence: int = setting(2, "epipolar_baseline: frames a moving region must persist before it is "
                                   "flagged", low=1, high=100)
    instance_min_fraction: float = setting(0.4, "with instances: share of an instance that must move to flag it "
                                           "(moving_objects: of its pixels in the regions the method would publish "
                                           "without instances, margin included; epipolar_baseline: of its reliable "
                                           "pixels)", low=0.01, high=1.0)
    instance_hold_fraction: float = setting(0.1, "moving_objects with instances: an instance flagged the frame "
                                            "before stays flagged while this share of it lies in those regions "
                                            "(hysteresis, each instance followed by its overlap: a car passing the "
                                            "image's corner keeps its decision as its evidence drops out; at or "
                                            "above instance_min_fraction: none)", low=0.0, high=1.0)
    instance_unknown_regions: bool = setting(True, "moving_objects with instances: also publish the method's own "
                                             "regions that lie mostly outside every instance (movers the instance "
                                             "source does not know), with ids from 2**30 up")
    window_length: int = setting(8, "frames in the sliding window (moving_objects, object_level)", low=3, high=60)
    refit_interval: int = setting(4, "object_level: frames between refits of the motion models", low=1, high=60)
    ground_contact: bool = setting(True, "object_level: objects standing on the ground plane are moving when "
                                   "their foot slides over it")
    object_fusion: bool = setting(True, "moving_objects without instances: the paper's fused object-level decision "
                                  "on the method's own regions (epipolar and quadratic flow models per region over "
                                  "the window, ORK affinities, co-regularized clustering): a region moves when it "
                                  "lies outside the background's cluster or the depth tests flagged it; with a "
                                  "background refit on a worker of its own, whose newest decision a frame applies "
                                  "(frontend/fusion.py). Off: every region the method finds moves")
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

    def baseline(self) -> BaselineConfig:
        """The epipolar baseline's settings."""
        return replace(BaselineConfig(), residual_threshold_px=self.residual_threshold_px)

    def validate(self) -> None:
        """Raise ValueError naming the first setting of the wrong type or out of range."""
        check_all(self)


def all_settings() -> list[Setting]:
    """Every setting of the node: its own, then the pipeline's."""
    return settings_of(NodeSettings) + settings_of(PipelineConfig)


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
    except (ValueError, OSError, yaml.YAMLError) as error:
        raise SettingsError(str(error)) from None


def _pipeline_config(args: argparse.Namespace) -> PipelineConfig:
    schema = settings_of(PipelineConfig)
    names = {entry.name for entry in schema}
    values = read_parameter_file(args.params) if getattr(args, "params", None) else {}
    unknown = set(values) - names - {entry.name for entry in settings_of(NodeSettings)}
    if unknown:
        raise ValueError(f"{args.params}: unknown parameters {sorted(unknown)}")
    values = {name: value for name, value in values.items() if name in names}
    if getattr(args, "method", None):
        values["method"] = args.method
    values = apply_overrides(values, getattr(args, "set", []), schema)
    config = PipelineConfig(**values)
    config.validate()
    return config
