"""Motion decision methods, one module each, behind one small interface (``Method`` in methods/base.py).

Every module of this package but ``base`` is a method: its name is the method's name (the node's ``method``
parameter) and its ``METHOD`` the class that implements it, so a new method is one new file. ``METHODS`` maps each
name to its module, found without importing it; ``method_class`` imports only the chosen one, so that one method's
imports never slow down or break another (as the ``moseg`` command's registry does for tools). A method is a small
stateful segmenter: ``reset()`` forgets the stream, ``step(frame)`` takes one frame and returns instance labels,
the ids that move, and a status.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Iterable

NOT_METHODS = ("base",)


def discover(paths: Iterable[str], package: str = __name__) -> dict[str, str]:
    """Method name -> module name of every module in the package folders ``paths`` but ``NOT_METHODS``."""
    names = sorted(info.name for info in pkgutil.iter_modules(list(paths)) if info.name not in NOT_METHODS)
    return {name: f"{package}.{name}" for name in names}


METHODS: dict[str, str] = discover(__path__)
DEFAULT_METHOD = "moving_objects"


def method_class(name: str, methods: dict[str, str] = METHODS) -> type:
    """The class (a ``methods.base.Method``) of the method ``name`` of ``methods`` (KeyError for an unknown one)."""
    return importlib.import_module(methods[name]).METHOD
