"""What the evaluations report beside their figures: strict JSON, with a figure that has no value (NaN: nothing to
count) as null, and the clips they skipped with the reason."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any


def without_nan(value: Any) -> Any:
    """``value`` (nested dicts, lists and tuples of JSON values) with every non-finite float replaced by None."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: without_nan(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [without_nan(item) for item in value]
    return value


def write_json(path: Path, report: dict[str, Any]) -> None:
    """Write ``report`` to ``path`` as strict JSON (``without_nan``), indented, with a final newline."""
    path.write_text(json.dumps(without_nan(report), indent=2, allow_nan=False) + "\n")


class ClipSkipped(Exception):
    """A clip with nothing to score; its message says why."""


def print_skipped(skipped: dict[str, str]) -> None:
    """One line per reason: the clips (``skipped``: clip -> reason) skipped for it."""
    by_reason: dict[str, list[str]] = {}
    for clip, reason in skipped.items():
        by_reason.setdefault(reason, []).append(clip)
    for reason, clips in by_reason.items():
        print(f"skipped ({reason}): {', '.join(clips)}")
