"""One schema of every setting: default, range or choices, and description, declared once.

Settings are dataclass fields declared with ``setting(...)``: the pipeline's in ``config.PipelineConfig``,
the node's own (QoS, queue, diagnostics) in ``NodeSettings`` below. Everything else derives from them (see
moseg_ros/config.py): the node's parameter descriptors and validation, the check of ``config/segmenter.yaml``,
the README's parameter table (checked by a test), and every tool's ``--params FILE`` / ``--set NAME=VALUE``.
This module imports nothing of the package.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import yaml

QOS_CHOICES = ("sensor_data", "reliable", "best_effort")
OVERFLOW_CHOICES = ("carry", "drop")


class SettingsError(ValueError):
    """A tool's --params / --set could not be made into valid settings (the `moseg` command exits 2)."""


@dataclass(frozen=True)
class Setting:
    """What the schema knows of one setting."""

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()

    def check(self, value: Any) -> None:
        """Raise ValueError naming the setting when ``value`` has the wrong type or is out of range."""
        kind = type(self.default)
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if type(value) is not kind:
            raise ValueError(f"{self.name} must be a {kind.__name__}, got {value!r}")
        if self.choices and value not in self.choices:
            raise ValueError(f"{self.name} {value!r} is not one of {list(self.choices)}")
        if self.low is not None and not self.low <= value <= self.high:
            raise ValueError(f"{self.name} {value} must be within {self.low}..{self.high}")

    def parse(self, text: str) -> Any:
        """The value of ``text`` (from ``--set``) in this setting's type."""
        kind = type(self.default)
        if kind is bool:
            if text.lower() not in ("true", "false"):
                raise ValueError(f"{self.name} must be true or false, got {text!r}")
            return text.lower() == "true"
        try:
            return kind(text)
        except ValueError:
            raise ValueError(f"{self.name} must be a {kind.__name__}, got {text!r}") from None


def setting(default: Any, description: str, *, low: float | None = None, high: float | None = None,
            choices: Sequence[str] = ()) -> Any:
    """A dataclass field that is also an entry of the schema."""
    meta = {"description": description, "low": low, "high": high, "choices": tuple(choices)}
    return dataclasses.field(default=default, metadata={"setting": meta})


def settings_of(cls: type) -> list[Setting]:
    """The schema entries of a dataclass's ``setting(...)`` fields, in declaration order."""
    return [Setting(f.name, f.default, **f.metadata["setting"]) for f in dataclasses.fields(cls)
            if "setting" in f.metadata]


def check_all(instance: Any) -> None:
    """Check every schema field of a dataclass instance; raise ValueError naming the first bad one."""
    for entry in settings_of(type(instance)):
        entry.check(getattr(instance, entry.name))


@dataclass(frozen=True)
class NodeSettings:
    """The node's own settings (transport, queue, diagnostics); the method's are in PipelineConfig."""

    image_qos: str = setting("sensor_data", "QoS of the image subscription", choices=QOS_CHOICES)
    qos_depth: int = setting(5, "history depth of the input subscriptions", low=1, high=100)
    compressed_input: bool = setting(False, "subscribe `image` as sensor_msgs/CompressedImage")
    use_instances: bool = setting(False, "pair each image with an upstream instance-id image on `instances`")
    instances_timeout_s: float = setting(0.2, "how long a frame waits for its instance image", low=0.0, high=5.0)
    max_pixels: int = setting(16_777_216, "largest image accepted, in pixels (raw: declared size; compressed: "
                              "its header's, read before decoding): a decompression bomb is refused cheaply",
                              low=1, high=2**31 - 1)
    queue_size: int = setting(1, "frames waiting for the worker; the oldest leaves the queue on overflow (1: "
                              "the newest frame wins, the lowest latency; more only buffers bursts)", low=1, high=100)
    overflow: str = setting("carry", "what a frame that leaves the queue unprocessed gets: `carry` publishes the "
                            "newest masks under its own header at once (counted `carried`: as old as the newest "
                            "processed frame), `drop` publishes nothing for it (counted `dropped`)",
                            choices=OVERFLOW_CHOICES)
    max_wait_ms: float = setting(0.0, "a frame that waited longer than this for the busy worker leaves the queue "
                                 "unprocessed as on overflow (carried when the newest masks fit it, else processed; "
                                 "with `overflow` drop, dropped): its mask would come late. 0: only frames that came "
                                 "while the worker was free are processed, the lowest latency; raise it to buffer "
                                 "bursts with `queue_size`", low=0.0, high=60_000.0)
    diagnostics_period_s: float = setting(1.0, "period of /diagnostics", low=0.1, high=60.0)
    warn_throttle_s: float = setting(5.0, "minimum time between repeated warnings of one kind", low=0.0,
                                     high=600.0)


def read_parameter_file(path: Path) -> dict[str, Any]:
    """The ``ros__parameters`` of a node's YAML file (``segmenter:`` or ``/**:`` as the top key), nested ones by
    their dotted names (``moving_objects: {window_length: 8}`` -> ``moving_objects.window_length``)."""
    data = yaml.safe_load(Path(path).read_text()) or {}
    for node in data.values():
        if isinstance(node, dict) and isinstance(node.get("ros__parameters"), dict):
            return flattened(node["ros__parameters"])
    raise ValueError(f"{path}: no `<node>: ros__parameters:` section")


def flattened(parameters: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested parameters as ROS names them: ``{"a": {"b": 1}}`` -> ``{"a.b": 1}``."""
    out: dict[str, Any] = {}
    for name, value in parameters.items():
        if isinstance(value, dict):
            out.update(flattened(value, f"{prefix}{name}."))
        else:
            out[f"{prefix}{name}"] = value
    return out


def apply_overrides(values: dict[str, Any], overrides: Iterable[str], schema: list[Setting]) -> dict[str, Any]:
    """``values`` with every ``NAME=VALUE`` of ``overrides`` parsed in its setting's type."""
    by_name = {entry.name: entry for entry in schema}
    out = dict(values)
    for item in overrides:
        name, sep, text = item.partition("=")
        if not sep or name not in by_name:
            raise ValueError(f"--set {item!r}: expected NAME=VALUE with NAME one of {sorted(by_name)}")
        out[name] = by_name[name].parse(text)
    return out
