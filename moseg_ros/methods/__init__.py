"""Motion decision methods, one module each, behind one small interface (``Method`` in methods/base.py).

``METHODS`` maps a method's name (the node's ``method`` parameter) to the class that implements it, as
``module:Class``; ``method_class`` imports only the chosen one, so that one method's imports never slow down or
break another (as the ``moseg`` command's registry does for tools). A method is a small stateful segmenter:
``reset()`` forgets the stream, ``step(frame)`` takes one frame and returns instance labels, the ids that move,
and a status.
"""

from __future__ import annotations

import importlib

METHODS: dict[str, str] = {
    "moving_objects": "moseg_ros.methods.moving_objects:MovingObjects",
    "epipolar_baseline": "moseg_ros.methods.epipolar_baseline:EpipolarBaseline",
    "object_level": "moseg_ros.methods.object_level:ObjectLevel",
}
DEFAULT_METHOD = "moving_objects"


def method_class(name: str) -> type:
    """The class (a ``methods.base.Method``) of the method registered as ``name`` (KeyError for an unknown one)."""
    module, _, cls = METHODS[name].partition(":")
    return getattr(importlib.import_module(module), cls)
