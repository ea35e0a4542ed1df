"""Folders of image files: the frames of a clip in their natural order, each decoded as the node decodes a
CompressedImage (Pillow, so that a truncated file is an error and not a half-grey frame)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from moseg_ros.io.frames import eight_bit
from moseg_ros.io.image import ImageDecodeError, decode_image_bytes

_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple[tuple[int, int | str], ...]:
    """Sort key of a file name that compares its runs of digits as numbers: 2.jpg before 10.jpg, frame_9
    before frame_10; names of zero-padded numbers keep their plain order."""
    return tuple((0, int(part)) if part.isdigit() else (1, part.lower()) for part in _DIGITS.split(name) if part)


def image_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """The files of ``folder`` whose suffix is one of ``suffixes`` (lower case, matched in any case), in natural
    order (``natural_key``), one per stem (a frame saved as 00042.jpg and 00042.png is one frame: the suffix
    earlier in ``suffixes`` is kept); hidden files (a leading dot: macOS's ._ companions) are left out. [] when the
    folder is absent."""
    if not folder.is_dir():
        return []
    files = (p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in suffixes)
    by_stem: dict[str, Path] = {}
    for path in sorted(files, key=lambda p: suffixes.index(p.suffix.lower())):
        by_stem.setdefault(path.stem, path)
    return sorted(by_stem.values(), key=lambda p: natural_key(p.name))


def frame_number(path: Path) -> int | None:
    """The last number in a file's stem (000042.png: 42, frame_7_left.png: 7), None when it has none."""
    numbers = _DIGITS.findall(path.stem)
    return int(numbers[-1]) if numbers else None


def read_frame(path: Path) -> np.ndarray:
    """The pipeline's frame from an image file: (H, W) uint8 grey or (H, W, 3) uint8 RGB (16-bit grey keeps its
    high byte, as the node does). Raises ImageDecodeError (a ValueError) for a file that cannot be read or
    decoded whole."""
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ImageDecodeError(f"cannot read {path}: {error.strerror or error}") from None
    return eight_bit(decode_image_bytes(data, str(path)))
