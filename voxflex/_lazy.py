"""Lazy public names of a package: ``import voxflex.x`` loads none of its stages until a name is used.

>>> __getattr__, __dir__, __all__ = lazy(__name__, {"material": "voxflex.deform.materials.constitutive"})  # doctest: +SKIP
"""

from __future__ import annotations

import importlib
import sys

__all__ = ["lazy"]


def lazy(package: str, names: dict[str, str]):
    """``(__getattr__, __dir__, __all__)`` for ``package`` whose public ``names`` live in the given modules.

    A name is imported on first use and then cached in the package's namespace.
    """

    def __getattr__(name: str):
        if name in names:
            value = getattr(importlib.import_module(names[name]), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module '{package}' has no attribute '{name}'")

    def __dir__():
        return sorted(names)

    return __getattr__, __dir__, list(names)
