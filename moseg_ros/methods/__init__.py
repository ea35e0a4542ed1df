"""Motion decision methods, one module each, behind one small interface (``Method`` in methods/base.py).

``METHODS`` maps a method's name (the node's ``method`` parameter) to its class. A method is a small stateful
segmenter: ``reset()`` forgets the stream, ``step(frame)`` takes one frame at the working resolution and
returns instance labels, the ids that move, and a status.
"""

from __future__ import annotations

from moseg_ros.methods.base import Decision, FrameInput, Method, Status
from moseg_ros.methods.epipolar_baseline import EpipolarBaseline
from moseg_ros.methods.moving_objects import MovingObjects
from moseg_ros.methods.object_level import ObjectLevel

METHODS: dict[str, type[Method]] = {cls.name: cls for cls in (MovingObjects, EpipolarBaseline, ObjectLevel)}
DEFAULT_METHOD = MovingObjects.name

__all__ = ["DEFAULT_METHOD", "METHODS", "Decision", "FrameInput", "Method", "Status"]
