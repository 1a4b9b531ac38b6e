"""Module attributes that load their submodule on first use (PEP 562).

Packages use it so that importing the numpy-only layers (signal chain,
simulator) never pulls in GTSAM or scikit-learn through an ``__init__``.
"""

from __future__ import annotations

import importlib
import sys
from typing import Callable, Mapping


def lazy_getattr(package: str, names: Mapping[str, str]) -> Callable[[str], object]:
    """A module ``__getattr__`` resolving ``names[attr]`` (a submodule of
    ``package``) on first access. It also gives the package a ``__dir__``
    that lists the lazy names beside the loaded ones, so ``dir(package)``
    and tab completion show them before their first use."""
    module = sys.modules.get(package)
    if module is not None:
        module.__dir__ = lambda: sorted(set(vars(module)) | set(names))

    def __getattr__(name: str) -> object:
        if name in names:
            return getattr(importlib.import_module(f".{names[name]}", package), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
